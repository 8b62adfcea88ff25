"""Column profiles, headings between views and the aligned-profile term ``AP``, on images made here."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.panorama import load_tour_links
from fingerloc.features.vision import (
    column_profile,
    observation_from_views,
    profile_correlation,
    profile_rotation_deg,
)
from fingerloc.io.jsonl import observation_from_record, observation_to_record
from fingerloc.model import PlaceModel
from fingerloc.observation import Observation
from fingerloc.sensors import Panorama
from fingerloc.terms import ProfileTerm

from ._cli import run_cli
from .features_world import paint_panorama

ROOMS = (
    {},
    {"wall_cols": (100, 200, 520, 650), "patches": ((20, 60, 300.0), (300, 360, 60.0), (560, 600, 180.0))},
    {"wall_cols": (30, 330, 400, 500), "patches": ((150, 250, 240.0), (420, 470, 20.0), (600, 640, 100.0))},
)


def _room(room: int, shift: int, seed: int, h: int = 120) -> np.ndarray:
    """A painted room (720 columns, 0.5 deg each), rolled by ``shift`` columns, uint8."""
    band, *_ = paint_panorama(seed=seed, h=h, **ROOMS[room])
    return (np.roll(band, shift, axis=1) * 255).round().astype(np.uint8)


def _diff(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


@pytest.mark.parametrize("shift", [0, 37, 200, 531])
def test_profile_heading_of_a_rolled_view(shift):
    a = Panorama(_room(0, 0, seed=1))
    b = Panorama(_room(0, shift, seed=2))  # other noise, rolled: bearing x in a is at x - shift / 2 deg in b
    h, peak = profile_rotation_deg(column_profile(a), column_profile(b))
    assert _diff(h, -shift * 0.5) < 2.0
    assert peak > 0.8


def test_profile_follows_bearings_not_columns():
    img = _room(1, 0, seed=3)
    cw = column_profile(Panorama(img))
    # the same view stored counter-clockwise (columns mirrored)
    ccw = column_profile(Panorama(img[:, ::-1].copy(), clockwise=False))
    assert np.allclose(cw, ccw, atol=1e-6)
    shifted = column_profile(Panorama(img, bearing_offset=np.deg2rad(25.0)))  # the robot turned by -25 deg
    assert _diff(profile_rotation_deg(cw, shifted)[0], 25.0) < 1.0


def test_profile_is_standardised_and_checked():
    p = column_profile(Panorama(_room(2, 0, seed=0)), columns=36, strips=2)
    assert p.shape == (36, 10)
    assert np.allclose(p.mean(axis=0), 0.0, atol=1e-9)
    assert np.allclose(p.std(axis=0)[p.std(axis=0) > 0], 1.0)
    flat = column_profile(Panorama(np.full((20, 72, 3), 128, dtype=np.uint8)))
    assert np.all(flat == 0.0)
    with pytest.raises(InvalidParameterError, match="columns"):
        column_profile(Panorama(_room(0, 0, 0)), columns=2)
    with pytest.raises(InvalidParameterError, match="one shape"):
        profile_correlation(p, p[:, :4])
    c = profile_correlation(p, np.roll(p, 5, axis=0))
    assert int(np.argmax(c)) == 5 and c[5] == pytest.approx(1.0)


def test_observation_profile_round_trip_and_rotation():
    prof = column_profile(Panorama(_room(1, 0, seed=0)))
    o = observation_from_views(panorama=Panorama(_room(1, 0, seed=0)), appearance=True, profile=True)
    assert o.profile is not None and o.profile.shape == (36, 20)  # 36 sectors of 10 deg x 4 strips x 5 channels
    assert np.array_equal(o.profile, np.round(prof, 2))  # stored at two decimals
    rec = json.loads(json.dumps(observation_to_record(o)))
    back = observation_from_record(rec)
    assert back.profile is not None and np.allclose(back.profile, o.profile, atol=1e-3)
    r = o.rotated(np.deg2rad(20.0))  # two rows of 10 deg
    assert np.array_equal(r.profile, np.roll(o.profile, 2, axis=0))
    assert observation_from_views(panorama=Panorama(_room(1, 0, seed=0))).profile is None
    with pytest.raises(InvalidParameterError, match="profile"):
        Observation(profile=np.ones(5))
    with pytest.raises(InvalidParameterError, match="finite"):
        Observation(profile=np.full((8, 2), np.nan))


def _views(rooms_shifts, seed0=0):
    """Observations with only a profile and an appearance descriptor (no feature extraction: fast)."""
    from fingerloc.features.vision import appearance_descriptor

    out = []
    for k, (r, s) in enumerate(rooms_shifts):
        pano = Panorama(_room(r, s, seed=seed0 + k, h=60))
        out.append(Observation(profile=column_profile(pano), appearance=appearance_descriptor(pano), label=f"room{r}"))
    return out


def test_profile_term_recognises_a_turned_room_and_gives_its_heading():
    train = _views([(0, 0), (0, 90), (1, 0), (1, 300), (2, 50), (2, 0)])
    groups = [train[0:2], train[2:4], train[4:6]]
    term = ProfileTerm().fit(groups)
    assert term.lambda_ > 1.0 and term.unknown_cost_ is not None
    queries = _views([(0, 411), (1, 123), (2, 600)], seed0=50)
    ll = term.log_likelihood(queries)
    assert list(np.argmax(ll, axis=1)) == [0, 1, 2]
    h, view = term.heading_at(queries[1], 1)
    ref_shift = (0, 300)[view]
    # bearing x in the query is at x + heading in the reference: columns (shift) clockwise, 0.5 deg each
    assert _diff(h, (123 - ref_shift) * 0.5) < 2.5
    # no profile: the term says nothing, and gives no heading
    bare = Observation()
    assert np.all(term.log_likelihood([bare]) == 0.0)
    assert term.heading_at(bare, 0) == (None, -1)
    again = ProfileTerm.from_state(term.to_state(), groups)
    assert np.allclose(again.log_likelihood(queries), ll)
    with pytest.raises(InvalidParameterError, match="malformed"):
        ProfileTerm.from_state({"lambda": -1}, groups)


def test_place_model_takes_headings_from_profiles():
    train = _views([(0, 0), (0, 90), (1, 0), (1, 300)])
    model = PlaceModel(terms=("A", "AP"), cyclic=True).fit(train)
    (q,) = _views([(1, 100)], seed0=77)
    h, ref = model.headings_with_reference([q])
    assert model.predict([q])[0] == "room1"
    # PlaceModel's convention: bearing in the stored view = bearing in the query - h
    shift = (0, 300)[int(ref[0])]
    assert _diff(-h[0], (100 - shift) * 0.5) < 2.5


def test_tour_links_give_the_heading_from_the_arrows(tmp_path):
    ts = """
export const a: Area = {
  id: 'area-1',
  photos: [
    { id: 'p1', imageUrl: '/360_photos_compressed/x/p1.webp', startingAngle: 100,
      directions: { forward: { connection: 'p2' } } },
    { id: 'p2', imageUrl: '/360_photos_compressed/x/p2.webp', startingAngle: 30,
      directions: { back: { connection: 'p1' }, left: { connection: 'p3' } } },
    { id: 'p3', imageUrl: '/360_photos_compressed/x/p3.webp',
      directions: { forward: { connection: 'p9' } } },
  ]
}
"""
    (tmp_path / "a.ts").write_text(ts)
    (link,) = load_tour_links(tmp_path)  # p2 -> p3 is one-way: no link
    assert (link.a, link.b, link.same_area) == ("x/p1.webp", "x/p2.webp", True)
    # arrow to p2 in p1 at viewer 100; arrow to p1 in p2 at 30 + 180 = 210: frames differ by 210 - 180 - 100
    assert link.heading_deg == pytest.approx((100 - 210 + 180) % 360)


def test_features_learn_localize_report_the_profile_heading(tmp_path, capsys):
    """Photos made here: ``features`` stores profiles, the panorama preset uses AP, ``localize`` gives heading_deg."""
    train = tmp_path / "train.jsonl"
    with train.open("w") as fh:
        for r, shifts in ((0, (0, 60)), (1, (0, 200)), (2, (0, 400))):
            files = []
            for k, sh in enumerate(shifts):
                full = np.full((180, 360, 3), 200, dtype=np.uint8)
                full[45:135] = np.asarray(Image.fromarray(_room(r, sh, seed=10 * r + k, h=90)).resize((360, 90)))
                files.append(tmp_path / f"r{r}_{k}.png")
                Image.fromarray(full).save(files[-1])
            out = tmp_path / f"r{r}.jsonl"
            code, _, err = run_cli(capsys, "features", *files, "--place", f"room{r}", "--json", out)
            assert code == 0, err
            fh.write(out.read_text())
    assert "profile" in json.loads(train.read_text().splitlines()[0])
    db = tmp_path / "places.sqlite"
    code, _, err = run_cli(capsys, "learn", train, "--db", db)
    assert code == 0, err
    q = tmp_path / "q.png"
    full = np.full((180, 360, 3), 200, dtype=np.uint8)
    full[45:135] = np.asarray(Image.fromarray(_room(1, 100, seed=99, h=90)).resize((360, 90)))
    Image.fromarray(full).save(q)
    qj = tmp_path / "q.jsonl"
    assert run_cli(capsys, "features", q, "--place", "room1", "--json", qj)[0] == 0
    ans = tmp_path / "ans.json"
    code, _, err = run_cli(capsys, "localize", qj, "--db", db, "--json", ans)
    assert code == 0, err
    text = ans.read_text()
    recs = json.loads(text)["observations"] if text.lstrip().startswith("{") else [json.loads(x) for x in text.splitlines()]
    rec = recs[0]
    assert rec["best"] == "room1" and "AP" in rec["terms"]
    ref_shift = 0 if rec["heading_ref"].endswith("r1_0.png") else 200
    assert _diff(rec["heading_deg"], (100 - ref_shift) * 0.5) < 3.0


def test_profile_hardly_depends_on_resolution_or_exposure():
    img = _room(2, 0, seed=4, h=120).astype(np.float64) / 255.0
    big = np.repeat(np.repeat(img, 2, axis=0), 2, axis=1)  # 1440 columns: block-averaged back to 720
    p = column_profile(Panorama(img))
    assert np.allclose(column_profile(Panorama(big)), p, atol=1e-6)
    # a darker exposure: log luminance and chromaticities barely move once standardised
    dark = column_profile(Panorama(img * 0.5))
    assert profile_correlation(p, dark)[0] > 0.95


def test_heading_link_errors_scores_the_profile_against_the_arrows(tmp_path):
    from fingerloc.experiments.panorama import CampusPhoto, TourLink, extract_features, heading_link_errors

    (tmp_path / "x").mkdir()
    for k, shift in enumerate((0, 40)):
        full = np.full((180, 360, 3), 200, dtype=np.uint8)
        full[45:135] = np.asarray(Image.fromarray(_room(1, 2 * shift, seed=k, h=90)).resize((360, 90)))
        Image.fromarray(full).save(tmp_path / "x" / f"p{k}.png")
    photos = [CampusPhoto(f"p{k}", f"x/p{k}.png", "area", "x-1", None) for k in range(2)]
    feats = extract_features(tmp_path, photos, width=360)
    # p1 is p0 turned: a feature at bearing x in p0 is at x - 40 deg in p1 (columns run clockwise)
    good = TourLink("x/p0.png", "x/p1.png", 320.0, True)
    wrong = TourLink("x/p0.png", "x/p1.png", 140.0, False)
    res = heading_link_errors([good, wrong], photos, feats)
    assert res["profile, same area"]["pairs"] == 1
    assert res["profile, same area"]["median_error_deg"] < 3.0
    assert res["profile, all links"]["pairs"] == 2 and res["profile, all links"]["within_30"] == 0.5
    assert res["pairs"][0]["truth_deg"] == 320.0


def test_old_72_sector_profiles_against_new_36_sector_query_say_so():
    """Places learned from the former 72-sector profiles, a query with today's 36: one error naming both."""
    old = [
        [Observation(profile=column_profile(Panorama(_room(r, 0, seed=s)), columns=72), label=f"room{r}") for s in (0, 1)]
        for r in (0, 1)
    ]
    term = ProfileTerm().fit(old)
    query = Observation(profile=column_profile(Panorama(_room(0, 40, seed=5))))
    with pytest.raises(InvalidParameterError, match="72 sectors in older versions, 36 now"):
        term.log_likelihood([query])
    assert term.log_likelihood([old[0][0]]).shape == (1, 2)  # old queries still work with old places
