"""The real-panorama development benchmark's parts, on a tiny synthetic tour made at test time."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.distance import jensenshannon

from fingerloc.errors import DataFormatError
from fingerloc.experiments.panorama import (
    PANORAMA_METHODS,
    CampusPhoto,
    feature_heading_deg,
    fingerprint_heading_deg,
    hsv_histogram,
    image_rotation_deg,
    jeffrey_divergence,
    load_edge_labels,
    load_tour_layout,
    places_by_position,
    run_edge_bench,
    run_panorama_bench,
)
from fingerloc.features.vision import observation_from_views
from fingerloc.observation import Observation
from fingerloc.sensors import Panorama

from ._cli import run_cli
from .features_world import paint_panorama

AREA_TS = """
import type {{ Area }} from '../../types/tour'
export const roomA: Area = {{
  id: 'room-a',
  buildingBlock: 'x',
  floorLevel: 1,
  photos: [
{a}
  ]
}}
export const roomB: Area = {{
  id: 'room-b',
  buildingBlock: 'x',
  floorLevel: 2,
  photos: [
{b}
  ]
}}
"""


def _photo_entry(pid: str, rel: str) -> str:
    return (
        f"    {{\n      id: '{pid}',\n      imageUrl: '/360_photos_compressed/{rel}',\n      startingAngle: 0\n    }},"
    )


def _room_image(room: int, shift: int, seed: int) -> np.ndarray:
    """A 2:1 equirectangular image whose middle band is a painted room, rolled by ``shift`` columns."""
    kw = (
        {}
        if room == 0
        else {"wall_cols": (100, 200, 520, 650), "patches": ((20, 60, 300.0), (300, 360, 60.0), (560, 600, 180.0))}
    )
    band, *_ = paint_panorama(seed=seed, h=180, **kw)
    img = np.full((360, 720, 3), 0.85)
    img[90:270] = band
    return (np.roll(img, shift, axis=1) * 255).round().astype(np.uint8)


@pytest.fixture
def tour(tmp_path):
    photos = tmp_path / "photos"
    (photos / "a").mkdir(parents=True)
    (photos / "b").mkdir(parents=True)
    a_entries, b_entries = [], []
    for k in range(3):
        Image.fromarray(_room_image(0, 40 * k, seed=k)).save(photos / "a" / f"a{k}.png")
        a_entries.append(_photo_entry(f"a-{k}", f"a/a{k}.png"))
        Image.fromarray(_room_image(1, 90 * k, seed=10 + k)).save(photos / "b" / f"b{k}.png")
        b_entries.append(_photo_entry(f"b-{k}", f"b/b{k}.png"))
    blocks = tmp_path / "data" / "blocks"
    blocks.mkdir(parents=True)
    (blocks / "x.ts").write_text(AREA_TS.format(a="\n".join(a_entries), b="\n".join(b_entries)))
    minimap = tmp_path / "data" / "minimap"
    minimap.mkdir()
    pos = {"a-0": (0.1, 0.1), "a-1": (0.11, 0.1), "a-2": (0.5, 0.5), "b-0": (0.1, 0.1), "b-1": (0.1, 0.12)}
    lines = [f"  '{k}': {{ x: {x}, y: {y} }}," for k, (x, y) in pos.items()] + ["  'b-2': { x: null, y: null },"]
    (minimap / "minimapLocations.ts").write_text("export const M = {\n" + "\n".join(lines) + "\n}\n")
    return photos, blocks


def test_layout_and_places(tour):
    _, blocks = tour
    photos = load_tour_layout(blocks)
    assert [p.photo_id for p in photos] == ["a-0", "a-1", "a-2", "b-0", "b-1", "b-2"]
    assert [p.area for p in photos] == ["room-a"] * 3 + ["room-b"] * 3
    assert photos[0].file == "a/a0.png" and photos[3].floor == "x-2"
    assert photos[5].position is None
    # a-0 and a-1 share a place; a-2 is far; floor 2 is apart from floor 1 at the same position
    assert places_by_position(photos, spacing=0.03) == ["x-1#0", "x-1#0", "x-1#1", "x-2#0", "x-2#0", None]


def test_layout_errors(tmp_path):
    with pytest.raises(DataFormatError, match="not a folder"):
        load_tour_layout(tmp_path / "missing")
    (tmp_path / "empty.ts").write_text("export const x = 1\n")
    with pytest.raises(DataFormatError, match="no area with photos"):
        load_tour_layout(tmp_path)


def test_jeffrey_divergence_is_twice_the_squared_jensen_shannon_distance():
    rng = np.random.default_rng(0)
    h = rng.random((3, 8))
    h /= h.sum(axis=1, keepdims=True)
    k = rng.random((2, 8))
    k[0, :3] = 0.0
    k /= k.sum(axis=1, keepdims=True)
    d = jeffrey_divergence(h, k)
    for i in range(3):
        for j in range(2):
            assert d[i, j] == pytest.approx(2.0 * jensenshannon(h[i], k[j]) ** 2)


def test_hsv_histogram_is_rotation_invariant_and_normalised():
    img = _room_image(0, 0, seed=1)
    a = hsv_histogram(img)
    assert a.shape == (96,)
    assert [a[i * 32 : (i + 1) * 32].sum() for i in range(3)] == pytest.approx([1.0, 1.0, 1.0])
    assert np.array_equal(a, hsv_histogram(np.roll(img, 77, axis=1)))


@pytest.mark.parametrize("shift", [0, 37, 200, 611])
def test_image_rotation_and_fingerprint_heading_agree_on_a_rotated_panorama(shift):
    img, *_ = paint_panorama(seed=4)
    a = Panorama(img.astype(np.float32))
    b = Panorama(np.roll(img, shift, axis=1).astype(np.float32))
    expected = (-shift * 360.0 / 720) % 360.0  # a feature at bearing x in a is at x + expected in b
    heading, peak = image_rotation_deg(a, b, columns=720)
    assert heading == pytest.approx(expected) and peak == pytest.approx(1.0)
    oa, ob = observation_from_views(panorama=a), observation_from_views(panorama=b)
    fp = fingerprint_heading_deg(oa, ob)
    assert fp is not None and abs((fp - expected + 180.0) % 360.0 - 180.0) < 1.0
    hf = feature_heading_deg(oa, ob)
    assert hf is not None and abs((hf - expected + 180.0) % 360.0 - 180.0) < 1.0


def test_feature_heading_pairs_patches_of_one_hue_only():
    """Two patches of different hue never pair: the heading follows the same-hue patch."""
    a = Observation.from_degrees({"CP": [(10.0, 0.0), (200.0, 120.0)]})
    b = Observation.from_degrees({"CP": [(50.0, 0.0), (300.0, 120.0)]})
    # red moved +40 deg, green +100 deg: both count, each alone; the best single shift is one of them
    assert feature_heading_deg(a, b) in (pytest.approx(40.0), pytest.approx(100.0))
    c = Observation.from_degrees({"CP": [(50.0, 0.0)]})
    assert feature_heading_deg(a, c) == pytest.approx(40.0)
    assert feature_heading_deg(Observation.from_degrees({"VE": [1.0]}), c) is None


def test_edge_bench_counts_matches(tour, tmp_path):
    photos, _ = tour
    # room 0 has wall edges at columns 60, 250, 430, 610 of 720 (column degrees = col / 2)
    labels = {
        "tolerance_deg": 2.0,
        "photos": [{"file": "a/a0.png", "range_deg": [0, 360], "column_deg": [30.0, 125.0, 215.0, 305.0, 90.0]}],
    }
    path = tmp_path / "labels.json"
    path.write_text(json.dumps(labels))
    res = run_edge_bench(path, photos, edge_params={})
    row = res["photos"][0]
    assert row["true"] == 5 and row["matched"] == 4  # the label at 90 deg marks no edge
    assert res["recall"] == pytest.approx(4 / 5)
    assert res["precision"] == pytest.approx(4 / row["found"])


def test_edge_labels_checked(tmp_path):
    path = tmp_path / "labels.json"
    path.write_text(
        json.dumps({"tolerance_deg": 3, "photos": [{"file": "x", "range_deg": [0, 90], "column_deg": [120]}]})
    )
    with pytest.raises(DataFormatError, match="expected"):
        load_edge_labels(path)


def test_the_fixture_of_hand_labels_is_well_formed():
    data = load_edge_labels("tests/data/campus_edges.json")
    files = [p["file"] for p in data["photos"]]
    assert len(files) >= 10 and len(set(files)) == len(files)
    assert sum(len(p["column_deg"]) for p in data["photos"]) >= 80


def test_panorama_bench_end_to_end(tour, tmp_path):
    photos, blocks = tour
    cache = tmp_path / "cache.jsonl"
    res = run_panorama_bench(photos, blocks, cache=cache, width=360)
    assert res["photos"] == 6
    area = res["places"]["area"]
    assert area["n_places"] == 2 and area["n_queries"] == 6
    assert set(area["methods"]) == set(PANORAMA_METHODS)
    # two very different rooms: the appearance term and the baseline never confuse them
    assert area["methods"]["A"]["top1"] == 1.0
    assert area["methods"]["hsv-baseline"]["top1"] == 1.0
    assert res["places"]["position"]["n_queries"] == 4  # the pairs a-0/a-1 and b-0/b-1
    # the rolled copies of a room are the same view: every pair of one room verifies, the heading is the roll
    assert area["methods"]["K"]["top1"] == 1.0 and area["retrieval"]["top1_all"] == 1.0
    assert res["keypoints"]["model"] in ("upright", "general")
    cal = area["methods"]["A+K"]["calibration"]
    assert cal["accuracy"] == 1.0 and cal["wrong"] == 0 and 0.0 <= cal["ece"] <= 1.0 - cal["mean_confidence"] + 1e-9
    kp = res["heading_links"]  # the tour defines no arrows: no linked pair
    assert kp["keypoints, all links"]["pairs"] == 0
    # same room, rolled images: the oracle finds the roll exactly
    first = res["heading"]["pairs"][0]
    assert first["oracle_deg"] == pytest.approx((-40 * 360 / 720) % 360.0, abs=1.0)
    # the cache is reused: a second run reads it and gives the same figures
    before = cache.read_text()
    again = run_panorama_bench(photos, blocks, cache=cache, width=360)
    assert cache.read_text() == before
    assert again["places"] == res["places"]


def test_bench_commands(tour, tmp_path, capsys):
    photos, blocks = tour
    out = tmp_path / "res.json"
    code, stdout, err = run_cli(capsys, "bench", "panorama", photos, "--areas", blocks, "--width", 360, "--json", out)
    assert code == 0, err
    assert "hsv-baseline" in stdout and json.loads(out.read_text())["photos"] == 6
    code, _, err = run_cli(capsys, "bench", "panorama", photos, "--areas", blocks, "--spacing", "-1")
    assert code == 2 and "--spacing must be a positive number" in err
    code, _, err = run_cli(capsys, "bench", "panorama", tmp_path / "nowhere", "--areas", blocks)
    assert code == 2 and "not a folder of photos" in err
    code, _, err = run_cli(
        capsys, "bench", "panorama", photos, "--areas", blocks, "--cache", tmp_path / "no" / "c.jsonl"
    )
    assert code == 2 and "--cache: no folder" in err
    bad = tmp_path / "bad-cache.jsonl"
    bad.write_text(
        '{"band": [0.25, 0.75], "width": 360, "edges": {"nms_deg": 3.0, "max_edges": 12}, "version": 6, "keypoints": {}}\n'
        "not json\n"
    )
    code, _, err = run_cli(capsys, "bench", "panorama", photos, "--areas", blocks, "--width", 360, "--cache", bad)
    assert code == 2 and "bad-cache.jsonl:2" in err and "not a feature cache" in err


def test_the_same_bench_from_a_labels_csv(tour, tmp_path, capsys):
    photos, blocks = tour
    by_areas = run_panorama_bench(photos, blocks, width=360)
    csv = tmp_path / "labels.csv"
    rows = ["file,place,x,y"] + [f"{r}/{r}{k}.png,room-{r},{k * 10.0},{100.0 * (r == 'b')}" for r in "ab" for k in range(3)]
    csv.write_text("\n".join(rows) + "\n")
    by_csv = run_panorama_bench(photos, labels=csv, width=360, spacing=15.0)
    assert by_csv["places"]["area"]["methods"] == by_areas["places"]["area"]["methods"]
    pos = by_csv["places"]["position"]  # centres 15 apart: photos 0 and 1 of each room share one, photo 2 its own
    assert pos["n_places"] == 4 and pos["n_queries"] == 4
    out = tmp_path / "res.json"
    code, stdout, err = run_cli(
        capsys, "bench", "panorama", photos, "--labels", csv, "--width", 360, "--preset", "panorama", "--json", out
    )
    assert code == 0, err
    pre = json.loads(out.read_text())["preset"]["area"]
    assert pre["n_queries"] == 6 and pre["top1"] == 1.0 and pre["calibration"]["wrong"] == 0
    assert "preset panorama by area: top-1 1.000" in stdout
    # the same models give the single terms and the sum without its tempering factor
    var = pre["variants"]
    assert var["preset"]["top1"] == pre["top1"] and {"A", "K"} <= set(var) and "AP" not in var and "Fp" not in var
    assert pre["temper"]["median"] == 1.0 and "untempered" not in var  # the preset does not temper
    assert "same models, A: top-1" in stdout
    code, _, err = run_cli(capsys, "bench", "panorama", photos, "--labels", csv, "--areas", blocks)
    assert code == 2 and "one of them" in err


def test_preset_only_with_other_weights_and_a_tempered_model(tour, tmp_path, capsys):
    photos, _ = tour
    csv = tmp_path / "labels.csv"
    csv.write_text("file,place\n" + "".join(f"{r}/{r}{k}.png,room-{r}\n" for r in "ab" for k in range(3)))
    out = tmp_path / "res.json"
    # only the PlaceModel answers, with the preset's weights replaced
    code, stdout, err = run_cli(capsys, "bench", "panorama", photos, "--labels", csv, "--width", 360, "--preset",
                                "panorama", "--preset-only", "--weights", "Fp=0,A=1,AP=1,K=1", "--json", out)  # fmt: skip
    assert code == 0, err
    res = json.loads(out.read_text())
    assert res["places"] == {} and res["photos"] == 6
    assert res["preset"]["area"]["options"]["weights"] == {"Fp": 0.0, "A": 1.0, "AP": 1.0, "K": 1.0}
    assert "AP" in res["preset"]["area"]["variants"] and "leave-one-out top-1" not in stdout
    code, _, err = run_cli(capsys, "bench", "panorama", photos, "--labels", csv, "--weights", "A=1")
    assert code == 2 and "go with --preset" in err
    # tempered models: the same answers with and without the factor
    from fingerloc.experiments.panorama import extract_features, load_labels_csv
    from fingerloc.experiments.panorama_model import run_preset_loo

    rows = load_labels_csv(csv)
    obs = [f.observation for f in extract_features(photos, rows, width=360)]
    tempered = run_preset_loo(obs, [r.area for r in rows], overrides={"temper": True})
    assert tempered["options"]["temper"] is True and tempered["temper"]["median"] != 1.0
    assert tempered["variants"]["untempered"]["top1"] == tempered["top1"]


def test_calibration_against_a_hand_count():
    from fingerloc.experiments.panorama import calibration

    # four queries, two places: confidences 0.9 (right), 0.9 (wrong), 0.6 (right), 0.6 (right)
    p = np.array([[0.9, 0.1], [0.1, 0.9], [0.6, 0.4], [0.4, 0.6]])
    truth = np.array([0, 0, 0, 1])
    cal = calibration(np.log(p), truth)
    # bin [0.9, 1.0): accuracy 0.5, confidence 0.9; bin [0.6, 0.7): accuracy 1.0, confidence 0.6
    assert cal["ece"] == pytest.approx(0.5 * 0.4 + 0.5 * 0.4)
    assert cal["accuracy"] == 0.75 and cal["wrong"] == 1 and cal["wrong_above_0.9"] == 0.0
    assert cal["mean_confidence"] == pytest.approx(0.75)
    assert cal["wrong_above_0.99"] == 0.0
    # a fifth query answered wrong at 0.995: one of the two wrong answers above 0.9 and above 0.99
    loud = calibration(np.log(np.vstack([p, [0.005, 0.995]])), np.append(truth, 0))
    assert loud["wrong"] == 2 and loud["wrong_above_0.9"] == 0.5 and loud["wrong_above_0.99"] == 0.5


def test_tempering_fit_on_the_other_queries_softens_an_overconfident_sum():
    from fingerloc.experiments.panorama import _loo_tempered, calibration

    rng = np.random.default_rng(0)
    n, places = 200, 5
    truth = rng.integers(0, places, n)
    ll = rng.normal(size=(n, places)) * 3.0
    ll[np.arange(n), truth] += 2.0  # right about half the time, with huge margins
    loud = 10.0 * ll
    tempered = _loo_tempered(loud, truth)
    assert calibration(tempered, truth)["ece"] < 0.5 * calibration(loud, truth)["ece"]
    assert np.array_equal(np.argmax(tempered, axis=1), np.argmax(loud, axis=1))  # the ranking is kept


def test_campus_photo_is_plain_data():
    p = CampusPhoto("id", "f.webp", "area", "x-1", None)
    assert p.position is None and p.floor == "x-1"


def test_features_command_records_appearance_and_source(tour, tmp_path, capsys):
    from fingerloc.io.jsonl import read_observations

    photos, _ = tour
    out = tmp_path / "obs.jsonl"
    img = photos / "a" / "a0.png"
    code, _, err = run_cli(capsys, "features", img, "--place", "a", "--json", out)
    assert code == 0, err
    (obs,) = read_observations(out)
    assert obs.source == str(img) and obs.label == "a"
    assert obs.appearance is not None and obs.appearance.size > 50
    assert obs.ve.size <= 12  # a full 2:1 photo keeps only its strongest edges


def test_weighted_fusion_silences_a_loud_useless_term():
    """A term of pure noise at 100x the scale drowns a plain sum; fitted weights keep the good term."""
    from fingerloc.experiments.panorama import _loo_weighted_sum

    rng = np.random.default_rng(0)
    n, p = 30, 5
    truth = rng.integers(0, p, n)
    good = -rng.random((n, p))
    good[np.arange(n), truth] += 1.0  # the right place always wins
    noise = 100.0 * rng.standard_normal((n, p))
    plain = good + noise
    fused = _loo_weighted_sum([good, noise], truth)

    def top1(s):
        return float(np.mean(np.argmax(s, axis=1) == truth))

    assert top1(good) == 1.0
    assert top1(plain) < 0.5
    assert top1(fused) >= 0.95


def test_heading_closure_against_triples_counted_by_hand():
    from fingerloc.experiments.panorama import heading_closure

    yaw = np.array([0.0, 30.0, 100.0, 250.0, 10.0])  # each photo's heading; h_ab = yaw_b - yaw_a
    h = yaw[None, :] - yaw[:, None]
    h[0, 2] += 3.0  # one pair off by 3 deg (and its reverse)
    h[2, 0] -= 3.0
    inl = np.full((5, 5), 20)
    inl[3, 4] = inl[4, 3] = 2  # too few inliers: triples through this pair are left out
    labels = ["r", "r", "r", "r", None]
    got = heading_closure(inl, h, labels)
    # triples of photos 0-3: (0,1,2) and (0,2,3) hold the bad pair (3 deg), (0,1,3) and (1,2,3) close exactly
    assert got["triples"] == 4 and got["median_deg"] == pytest.approx(1.5) and got["within_2_deg"] == 0.5
    assert heading_closure(inl, h, ["r", "r", "s", "s", "s"])["triples"] == 0
