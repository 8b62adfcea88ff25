"""Local features of panoramas (OpenCV SIFT on the sphere) and the term ``K``, on rooms rendered here."""

from __future__ import annotations

import json
import math
import sqlite3

import numpy as np
import pytest
from PIL import Image

from fingerloc.errors import DatabaseError, DataFormatError, InvalidParameterError
from fingerloc.features.keypoints import (
    KEYPOINT_VERSION,
    KeypointParams,
    Keypoints,
    band_elevations,
    decode_keypoints,
    encode_keypoints,
    extract_keypoints,
    match_descriptors,
    match_keypoints,
)
from fingerloc.features.sphere import ransac_pose
from fingerloc.io.jsonl import observation_from_record, observation_to_record
from fingerloc.map._records import decode_observation, encode_observation
from fingerloc.model import PlaceModel
from fingerloc.observation import Observation
from fingerloc.sensors import Panorama
from fingerloc.terms import KeypointTerm
from fingerloc.terms.keypoints import Vocabulary, choose_model

from ._cli import run_cli
from ._panoramas import render_room, wall_textures


def _heading_error(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


@pytest.fixture(scope="module")
def rooms() -> list[np.ndarray]:
    return [wall_textures(seed) for seed in (1, 2, 3)]


@pytest.fixture(scope="module")
def views(rooms) -> dict[str, Keypoints]:
    tex = rooms[0]
    a = render_room(tex, (2.0, 1.5, 1.4), 0.0)
    rolled = Panorama(np.roll(np.asarray(a.image), 333, axis=1), meta=a.meta)
    dark = Panorama(np.clip(np.asarray(a.image) * 0.3, 0, 1), meta=a.meta)
    return {
        "a": extract_keypoints(a),
        "rolled": extract_keypoints(rolled),
        "dark": extract_keypoints(dark),
        "moved": extract_keypoints(render_room(tex, (3.2, 2.3, 1.4), 30.0)),
        "tilted": extract_keypoints(render_room(tex, (3.2, 2.3, 1.4), 30.0, tilt_deg=3.0)),
        "other": extract_keypoints(render_room(rooms[1], (2.0, 1.5, 1.4), 0.0)),
    }


def test_keypoints_have_positions_on_the_sphere_and_sift_descriptors(views):
    a = views["a"]
    assert 500 <= len(a) <= KeypointParams().n_keypoints and a.dim == 128 and a.desc.dtype == np.uint8
    assert np.abs(np.rad2deg(a.elevation)).max() <= 45.0 and np.rad2deg(a.elevation).std() > 10
    assert np.allclose(np.linalg.norm(a.vectors(), axis=1), 1.0)
    assert np.allclose(np.linalg.norm(a.unit_descriptors(), axis=1), 1.0, atol=1e-5)
    # spread over the whole circle, the seam included (the band is padded with its other end)
    deg = np.sort(np.mod(np.rad2deg(a.bearing), 360.0))
    assert np.diff(np.concatenate([deg, [deg[0] + 360.0]])).max() < 8.0


def test_a_rolled_copy_matches_with_the_roll_as_heading(views):
    a, rolled = views["a"], views["rolled"]
    m = match_keypoints(a, rolled)
    assert len(m) > 0.6 * len(a)
    roll = 333 / 1024 * 360.0  # columns run clockwise: the content turns by -roll degrees of bearing
    d = np.mod(np.rad2deg(rolled.bearing[m[:, 1]] - a.bearing[m[:, 0]]), 360.0)
    assert np.mean(np.array([_heading_error(x, -roll) for x in d]) < 0.1) > 0.9
    assert np.mean(np.abs(np.rad2deg(a.elevation[m[:, 0]] - rolled.elevation[m[:, 1]])) < 0.1) > 0.9
    fit = ransac_pose(a.vectors()[m[:, 0]], rolled.vectors()[m[:, 1]])
    assert fit is not None and fit.n_inliers > 0.9 * len(m)
    assert _heading_error(math.degrees(fit.heading), -roll) < 0.05
    assert len(match_keypoints(a, views["other"])) < 0.05 * len(m)


def test_a_dark_exposure_still_matches(views):
    assert len(match_keypoints(views["a"], views["dark"])) > 0.4 * len(views["a"])


def test_two_spots_of_one_room_give_the_heading_from_the_verified_rotation(views):
    """The second spot is 1.5 m away, turned by 30 deg: a feature at bearing x is at x - 30 there."""
    a, b, t = views["a"], views["moved"], views["tilted"]
    m = match_keypoints(a, b)
    fit = ransac_pose(a.vectors()[m[:, 0]], b.vectors()[m[:, 1]], model="upright", threshold=0.01)
    assert fit is not None and fit.n_inliers > 0.8 * len(m) > 100
    assert _heading_error(math.degrees(fit.heading), -30.0) < 0.5
    # a camera tilted by 3 deg: the level model loses most matches, the general one keeps them and finds the tilt
    m = match_keypoints(a, t)
    up = ransac_pose(a.vectors()[m[:, 0]], t.vectors()[m[:, 1]], model="upright", threshold=0.01)
    gen = ransac_pose(a.vectors()[m[:, 0]], t.vectors()[m[:, 1]], model="general", threshold=0.01)
    assert up is not None and gen is not None and up.n_inliers < 0.5 * gen.n_inliers
    assert abs(math.degrees(gen.tilt) - 3.0) < 0.3 and _heading_error(math.degrees(gen.heading), -30.0) < 0.5


def test_match_descriptors_is_mutual_with_the_ratio_test_on_both_sides():
    """Against the rule written out with loops."""
    rng = np.random.default_rng(0)
    for _ in range(5):
        a = rng.random((40, 8)).astype(np.float32) ** 3
        b = np.concatenate([a[:15] + 0.05 * rng.random((15, 8)), rng.random((30, 8)) ** 3]).astype(np.float32)
        a /= np.linalg.norm(a, axis=1, keepdims=True)
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        d = np.linalg.norm(a[:, None] - b[None], axis=2)
        want = []
        for i in range(len(a)):
            j = int(np.argmin(d[i]))
            if int(np.argmin(d[:, j])) != i:
                continue
            second_row = np.sort(d[i])[1]
            second_col = np.sort(d[:, j])[1]
            if d[i, j] < 0.8 * second_row and d[i, j] < 0.8 * second_col:
                want.append((i, j))
        got = match_descriptors(a, b, ratio=0.8)
        assert [tuple(r) for r in got] == want and len(want) >= 10


def _matches_by_numpy(ua, ub, ratio):
    """The mutual ratio test by whole-matrix numpy operations (argmax / max with the best masked out)."""
    s = ua @ ub.T
    rows, cols = np.arange(s.shape[0]), np.arange(s.shape[1])
    j = np.argmax(s, axis=1)
    i_back = np.argmax(s, axis=0)
    best = s[rows, j].copy()
    masked = s.copy()
    masked[rows, j] = -4.0
    sa = masked.max(axis=1) if s.shape[1] > 1 else np.full(s.shape[0], -4.0)
    masked = s.copy()
    masked[i_back, cols] = -4.0
    sb = (masked.max(axis=0) if s.shape[0] > 1 else np.full(s.shape[1], -4.0))[j]
    d1 = np.maximum(2 - 2 * best, 0)
    r2 = np.float32(ratio * ratio)
    ok = (i_back[j] == rows) & (d1 < r2 * np.maximum(2 - 2 * sa, 0)) & (d1 < r2 * np.maximum(2 - 2 * sb, 0))
    i = np.flatnonzero(ok)
    return np.stack([i, j[i]], axis=1)


@pytest.mark.parametrize("shape", [(400, 350), (1, 30), (30, 1), (1, 1), (2, 2)])
def test_match_descriptors_agrees_with_whole_matrix_numpy_on_rootsift_sized_sets(shape):
    rng = np.random.default_rng(shape[0] * 1000 + shape[1])
    na, nb = shape
    a = rng.random((na, 128)).astype(np.float32) ** 4
    b = np.concatenate([a[: nb // 3] + 0.02 * rng.random((nb // 3, 128)), rng.random((nb - nb // 3, 128)) ** 4])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = (b / np.linalg.norm(b, axis=1, keepdims=True)).astype(np.float32)
    for ratio in (0.8, 0.95):
        got = match_descriptors(a, b, ratio=ratio)
        want = _matches_by_numpy(a, b, ratio)
        assert got.dtype == np.int64 and got.shape[1] == 2
        assert np.array_equal(got, want)
    if na > 100:
        assert len(want) >= nb // 4


def test_encoding_round_trips_and_old_keypoints_are_refused(views):
    a = views["a"]
    rec = json.loads(json.dumps(encode_keypoints(a)))
    assert rec["version"] == KEYPOINT_VERSION and decode_keypoints(rec) == a  # positions already on the grid
    obs = Observation(keypoints=a, label="x", profile=np.ones((8, 2)))
    assert observation_from_record(json.loads(json.dumps(observation_to_record(obs)))) == obs
    data = encode_observation(obs)
    assert data[0] == 4 and decode_observation(data, label="x") == obs
    for cut in (1, 7, len(data) // 2):
        with pytest.raises(DatabaseError, match="corrupt"):
            decode_observation(data[:-cut])
    turned = obs.rotated(np.deg2rad(30.0))
    assert turned.keypoints is not None
    assert np.allclose(np.rad2deg(turned.keypoints.bearing - a.bearing) % 360.0, 30.0)
    # the former detector's keypoints (no version; codec 3): one message, run features again
    old = {k: v for k, v in rec.items() if k != "version"}
    with pytest.raises(DataFormatError, match="run `fingerloc features` again"):
        decode_keypoints(old)
    with pytest.raises(DatabaseError, match="run `fingerloc features` again"):
        decode_observation(bytes([3]) + data[1:])
    for bad in ({"version": 2, "n": 2, "dim": 3, "pos": "AAAA", "desc": "AAAA"}, {"version": 2, "n": 1}, [1, 2]):
        with pytest.raises(DataFormatError, match="keypoints"):
            decode_keypoints(bad)
    with pytest.raises(DataFormatError, match="version 7"):
        decode_keypoints({**rec, "version": 7})
    with pytest.raises(InvalidParameterError, match="elevations"):
        Keypoints(np.zeros(1), np.full(1, 2.0), np.ones(1), np.zeros((1, 4), dtype=np.uint8))


def test_bands_parameters_and_flat_images():
    flat = Panorama(np.zeros((40, 200, 3), dtype=np.uint8))
    assert len(extract_keypoints(flat)) == 0
    assert band_elevations(flat) == pytest.approx((math.radians(36.0), -math.radians(36.0)))
    assert band_elevations(Panorama(np.zeros((10, 200, 3)), meta={"elevation_deg": (30, -10)})) == pytest.approx(
        (math.radians(30), math.radians(-10))
    )
    with pytest.raises(InvalidParameterError, match="elevation_deg"):
        band_elevations(Panorama(np.zeros((10, 200, 3)), meta={"elevation_deg": (-10, 30)}))
    with pytest.raises(DataFormatError, match="too small"):
        extract_keypoints(Panorama(np.zeros((2, 8, 3), dtype=np.uint8)))
    with pytest.raises(InvalidParameterError, match="n_keypoints"):
        KeypointParams(n_keypoints=0)
    with pytest.raises(InvalidParameterError, match="unknown keypoint parameter"):
        extract_keypoints(flat, bogus=1)


def _room_obs(rooms, r: int, spot: int, *, tilt: float = 0.0) -> Observation:
    spots = [(2.0, 1.5, 1.4, 0.0), (3.5, 2.4, 1.4, 40.0), (2.8, 1.0, 1.4, -70.0), (4.2, 1.8, 1.4, 120.0)]
    x, y, z, h = spots[spot]
    pano = render_room(rooms[r], (x, y, z), h, width=640, tilt_deg=tilt if spot % 2 else -tilt)
    return Observation(keypoints=extract_keypoints(pano, width=640), label=f"room{r}", source=f"r{r}s{spot}")


@pytest.fixture(scope="module")
def room_views(rooms) -> dict[str, list[Observation]]:
    return {
        "train": [_room_obs(rooms, r, s) for r in range(3) for s in (0, 1, 2)],
        "query": [_room_obs(rooms, r, 3) for r in range(3)],
        "tilted": [_room_obs(rooms, r, s, tilt=2.5) for r in range(2) for s in (0, 1, 2)],
    }


def test_keypoint_term_recognises_rooms_gives_headings_and_keeps_its_state(room_views):
    train, queries = room_views["train"], room_views["query"]
    groups = [train[0:3], train[3:6], train[6:9]]
    term = KeypointTerm().fit(groups)
    assert term.model_ == "upright" and term.tilt_deg_ is not None and term.tilt_deg_ < 0.5
    assert term.lambda_ > 0 and term.unknown_cost_ is not None
    ll = term.log_likelihood(queries)
    assert list(np.argmax(ll, axis=1)) == [0, 1, 2]
    # the query's camera is turned by 120 deg; the training spots by 0, 40 and -70 deg
    for r, q in enumerate(queries):
        h, view, inliers = term.heading_at(q, r)
        assert h is not None and inliers >= term.min_inliers
        want = (120.0 - (0.0, 40.0, -70.0)[view]) % 360.0  # bearing in the view = bearing in the query + heading
        assert _heading_error(h, want) < 1.0
    assert term.heading_at(Observation(), 0) == (None, -1, 0)
    assert np.all(term.log_likelihood([Observation()]) == 0.0)
    again = KeypointTerm.from_state(json.loads(json.dumps(term.to_state())), groups)
    assert again.model_ == term.model_ and np.allclose(again.log_likelihood(queries), ll)
    with pytest.raises(InvalidParameterError, match="malformed"):
        KeypointTerm.from_state({"lambda": -1}, groups)
    with pytest.raises(InvalidParameterError, match="ratio"):
        KeypointTerm(ratio=0).fit(groups)
    with pytest.raises(InvalidParameterError, match="model"):
        KeypointTerm(model="affine").fit(groups)
    model = PlaceModel(terms=("K",)).fit(train)
    assert list(model.predict(queries)) == ["room0", "room1", "room2"]
    h, ref, src = model.heading_sources(queries)
    assert src == ["keypoints"] * 3 and np.all(ref >= 0) and np.all(np.isfinite(h))


def test_the_shortlist_adds_the_views_nearest_by_appearance(room_views):
    from dataclasses import replace

    rng = np.random.default_rng(3)
    train = [replace(o, appearance=rng.random(6)) for o in room_views["train"]]
    groups = [train[0:3], train[3:6], train[6:9]]
    term = KeypointTerm(shortlist=0, shortlist_appearance=2).fit(groups)
    apps = np.stack([o.appearance for o in train])
    for q in room_views["query"]:
        a = rng.random(6)
        want = np.sort(np.argsort(np.abs(apps - a).sum(axis=1))[:3])
        assert np.array_equal(term.candidates(q.keypoints, a), want)  # type: ignore[arg-type]
        assert term.candidates(q.keypoints).size == len(train)  # type: ignore[arg-type]  # no descriptor: every view
    both = KeypointTerm(shortlist=2, shortlist_appearance=2).fit(groups)
    q = room_views["query"][1]
    a = apps[7] + 0.01
    got = set(both.candidates(q.keypoints, a).tolist())  # type: ignore[arg-type]
    assert {7} <= got and got >= set(both.candidates(q.keypoints).tolist()) and len(got) <= 6  # type: ignore[arg-type]


def test_tilted_training_views_choose_the_general_model(room_views):
    tilted = room_views["tilted"]
    model, tilt = choose_model([[o.keypoints for o in tilted[0:3]], [o.keypoints for o in tilted[3:6]]])  # type: ignore[misc]
    assert model == "general" and tilt is not None and 3.0 < tilt < 7.0
    level = room_views["train"]
    assert choose_model([[o.keypoints for o in level[0:3]]])[0] == "upright"  # type: ignore[misc]


def test_the_shortlist_keeps_the_right_views(room_views):
    train, queries = room_views["train"], room_views["query"]
    groups = [train[0:3], train[3:6], train[6:9]]
    full = KeypointTerm(shortlist=0, shortlist_appearance=0).fit(groups)
    short = KeypointTerm(shortlist=3, shortlist_appearance=0).fit(groups)
    assert short.candidates(queries[0].keypoints).size == 4  # type: ignore[arg-type]
    assert list(np.argmax(short.log_likelihood(queries), axis=1)) == [0, 1, 2]
    assert list(np.argmax(full.log_likelihood(queries), axis=1)) == [0, 1, 2]
    for r, q in enumerate(queries):  # the shortlist holds a view of the right room
        assert np.any(short.candidates(q.keypoints) // 3 == r)  # type: ignore[arg-type]
    vocab = Vocabulary([o.keypoints.unit_descriptors() for o in train], words=64)  # type: ignore[union-attr]
    same = [vocab.scores(o.keypoints.unit_descriptors())[k] for k, o in enumerate(train)]  # type: ignore[union-attr]
    assert np.allclose(same, 1.0, atol=1e-5) and vocab.words_.shape == (64, 128)


def test_features_learn_localize_with_keypoints(tmp_path, capsys, rooms):
    """Photos rendered here: ``features`` writes keypoints, ``learn`` stores them, ``localize`` uses K and its heading."""

    def photo(r: int, spot: tuple[float, float, float], heading: float, path) -> None:
        band = np.asarray(render_room(rooms[r], spot, heading, width=1024).image)
        full = np.full((512, 1024, 3), 0.5)
        full[128:384] = band
        Image.fromarray((full * 255).round().astype(np.uint8)).save(path)

    train = tmp_path / "train.jsonl"
    with train.open("w") as fh:
        for r in range(2):
            files = []
            for k, (spot, head) in enumerate((((2.0, 1.5, 1.4), 0.0), ((3.5, 2.4, 1.4), 40.0))):
                files.append(tmp_path / f"r{r}_{k}.png")
                photo(r, spot, head, files[-1])
            out = tmp_path / f"r{r}.jsonl"
            code, _, err = run_cli(capsys, "features", *files, "--place", f"room{r}", "--json", out)
            assert code == 0, err
            fh.write(out.read_text())
    first = json.loads(train.read_text().splitlines()[0])
    assert first["keypoints"]["n"] > 300 and first["keypoints"]["version"] == KEYPOINT_VERSION
    db = tmp_path / "places.sqlite"
    code, _, err = run_cli(capsys, "learn", train, "--db", db)
    assert code == 0, err
    with sqlite3.connect(db) as con:
        blobs = [row[0] for row in con.execute("SELECT data FROM observations")]
    assert blobs and all(b[0] == 4 for b in blobs)
    q = tmp_path / "q.png"
    photo(1, (2.8, 1.0, 1.4), -70.0, q)
    qj = tmp_path / "q.jsonl"
    assert run_cli(capsys, "features", q, "--json", qj)[0] == 0
    ans = tmp_path / "ans.json"
    code, _, err = run_cli(capsys, "localize", qj, "--db", db, "--json", ans)
    assert code == 0, err
    text = ans.read_text()
    recs = json.loads(text)["observations"] if text.lstrip().startswith("{") else [json.loads(x) for x in text.splitlines()]
    rec = recs[0]
    assert rec["best"] == "room1" and "K" in rec["terms"] and rec["heading_from"] == "keypoints"
    want = {"r1_0.png": -70.0, "r1_1.png": -110.0}[rec["heading_ref"].rsplit("/", 1)[-1]] % 360.0
    assert _heading_error(rec["heading_deg"], want) < 1.0
    rep = tmp_path / "report"
    code, _, err = run_cli(capsys, "localize", qj, "--db", db, "--report", rep)
    assert code == 0, err
    page = (rep / "photos" / "index.html").read_text()
    assert (rep / "photos" / "answer1.png").stat().st_size > 10_000
    assert "from the keypoints" in page and "<td>K</td>" in page and "photos/index.html" in (rep / "index.html").read_text()
    # a database whose keypoints come from the former detector: one line, run features again
    with sqlite3.connect(db) as con:
        for oid, data in con.execute("SELECT id, data FROM observations").fetchall():
            con.execute("UPDATE observations SET data = ? WHERE id = ?", (b"\x03" + data[1:], oid))
    code, _, err = run_cli(capsys, "localize", qj, "--db", db)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "fingerloc features` again" in err


def test_heading_is_check_pairs_refined_rotation_with_or_without_the_memo(room_views):
    from fingerloc.terms.keypoints import check_pair, clear_pair_cache

    train, queries = room_views["train"], room_views["query"]
    groups = [train[0:3], train[3:6], train[6:9]]
    term = KeypointTerm().fit(groups)
    for warm in (True, False):
        clear_pair_cache()
        for r, q in enumerate(queries):
            if warm:  # the likelihood verified the views first (their fits kept): only the refinement runs
                term.log_likelihood([q])
            h, view, _ = term.heading_at(q, r)
            ref = groups[r][view].keypoints
            c = check_pair(q.keypoints.unit_descriptors(), q.keypoints.vectors(), ref.unit_descriptors(), ref.vectors(),
                           model=term.model_, threshold_deg=term.threshold_deg)  # fmt: skip
            assert h == pytest.approx(float(np.mod(np.degrees(c.heading), 360.0)), abs=1e-9)
