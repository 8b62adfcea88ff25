"""Local features of panoramas and the term ``K`` (issue 14), on synthetic images made here."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest
from PIL import Image

from fingerloc.errors import DatabaseError, DataFormatError, FingerlocError, InvalidParameterError
from fingerloc.features.keypoints import (
    KeypointParams,
    Keypoints,
    decode_keypoints,
    encode_keypoints,
    extract_keypoints,
    grey_band,
    match_keypoints,
)
from fingerloc.io.jsonl import observation_from_record, observation_to_record
from fingerloc.map._records import decode_observation, encode_observation
from fingerloc.model import PlaceModel
from fingerloc.observation import Observation
from fingerloc.sensors import Panorama
from fingerloc.terms import KeypointTerm
from fingerloc.terms.keypoints import match_counts

from ._cli import run_cli


def _texture(seed: int, h: int = 360, w: int = 1440) -> np.ndarray:
    """A random blob texture (band of a panorama), float in [0, 1], wrapping around the columns."""
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    img = np.zeros((h, w))
    for s in (2.0, 4.0, 8.0):
        img += ndimage.gaussian_filter(rng.normal(size=(h, w)), s, mode=("nearest", "wrap")) * s
    img = (img - img.min()) / (img.max() - img.min())
    return np.repeat(img[:, :, None], 3, axis=2)


def _noisy(img: np.ndarray, shift: int, seed: int, sd: float = 0.02, gain: float = 1.0) -> Panorama:
    rng = np.random.default_rng(seed)
    out = np.clip(np.roll(img, shift, axis=1) * gain + rng.normal(0, sd, img.shape), 0, 1)
    return Panorama((out * 255).round().astype(np.uint8))


@pytest.fixture(scope="module")
def views() -> dict[str, Keypoints]:
    a = _texture(1, 180, 720)
    b = _texture(2, 180, 720)
    return {  # at 720 columns (2 px per degree) to keep the tests fast
        "a": extract_keypoints(_noisy(a, 0, 10), width=720),
        "a_rolled": extract_keypoints(_noisy(a, 333, 11), width=720),
        "a_dark": extract_keypoints(_noisy(a, 0, 12, gain=0.25, sd=0.005), width=720),
        "b": extract_keypoints(_noisy(b, 0, 13), width=720),
    }


def test_a_rolled_noisy_copy_matches_at_many_keypoints_an_unrelated_texture_few(views):
    a, rolled, other = views["a"], views["a_rolled"], views["b"]
    assert 250 <= len(a) <= KeypointParams().n_keypoints and a.dim == 128 and a.desc.dtype == np.uint8
    m = match_keypoints(a, rolled)
    assert len(m) > 0.5 * len(a)
    # the matches agree on the roll: 333 columns of 720 = 166.5 deg, bearings decreasing with the column
    d = np.rad2deg(a.bearing[m[:, 0]] - rolled.bearing[m[:, 1]]) % 360.0
    assert np.mean(np.abs(d - 166.5) < 0.6) > 0.9
    assert np.mean(np.abs(a.elevation[m[:, 0]] - rolled.elevation[m[:, 1]]) <= 0.012) > 0.95  # within 2 rows of 180
    assert len(match_keypoints(a, other)) < 0.1 * len(m)


def test_dark_exposure_still_matches(views):
    assert len(match_keypoints(views["a"], views["a_dark"])) > 0.4 * len(views["a"])


def test_keypoints_spread_over_the_circle(views):
    a = views["a"]
    sectors = np.floor(np.mod(np.rad2deg(a.bearing), 360.0) / 10.0).astype(int)
    counts = np.bincount(sectors, minlength=36)
    assert counts.max() <= int(np.ceil(2 * KeypointParams().n_keypoints / 36))
    assert (counts > 0).sum() >= 30


def _brute_force_count(q: Keypoints, r: Keypoints, ratio: float, max_elev: float) -> int:
    """The matching rule written out with loops (the oracle of ``match_counts``)."""
    uq, ur = q.unit_descriptors().astype(np.float64), r.unit_descriptors().astype(np.float64)

    def dist(i: int, j: int) -> float:
        return float(np.sqrt(max(2.0 - 2.0 * float(uq[i] @ ur[j]), 0.0)))

    n = 0
    for i in range(len(q)):
        cands = sorted((dist(i, j), j) for j in range(len(r)))
        d1, j = cands[0]
        d2 = cands[1][0] if len(cands) > 1 else np.inf
        back = min((dist(k, j), k) for k in range(len(q)))[1]
        n += int(back == i and d1 < ratio * d2 and abs(q.elevation[i] - r.elevation[j]) <= max_elev)
    return n


def _random_keypoints(rng: np.random.Generator, n: int, dim: int = 16) -> Keypoints:
    return Keypoints(
        bearing=rng.uniform(-np.pi, np.pi, n),
        elevation=rng.uniform(0, 1, n),
        scale=np.ones(n),
        desc=rng.integers(0, 256, (n, dim)).astype(np.uint8),
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_match_counts_agree_with_brute_force(seed):
    rng = np.random.default_rng(seed)
    q = _random_keypoints(rng, 40)
    refs = [_random_keypoints(rng, int(n)) for n in rng.integers(1, 50, 40)]  # more than one block of views
    # a near copy of the query among them, so that there are matches to count
    copy = q.desc.astype(np.int64) + rng.integers(-3, 4, q.desc.shape)
    refs[5] = Keypoints(q.bearing, q.elevation + rng.normal(0, 0.01, 40), q.scale, np.clip(copy, 0, 255).astype(np.uint8))
    for ratio, elev in ((0.8, 0.1), (0.95, 0.3), (1.0, 1.0)):
        got = match_counts(q, refs, ratio=ratio, max_elevation=elev)
        want = [max(_brute_force_count(q, r, ratio, elev), _brute_force_count(r, q, ratio, elev)) for r in refs]
        assert list(got) == want
        assert [len(match_keypoints(q, r, ratio=ratio, max_elevation=elev)) for r in refs] == [
            _brute_force_count(q, r, ratio, elev) for r in refs
        ]
    assert got[5] > 30


def test_encoding_round_trips_bit_for_bit(views):
    a = views["a"]
    rec = json.loads(json.dumps(encode_keypoints(a)))
    assert decode_keypoints(rec) == a  # extraction already puts positions on the stored grid
    assert len(rec["desc"]) < 4 * len(a) * 128 / 3 + 8
    obs = Observation(keypoints=a, label="x")
    back = observation_from_record(json.loads(json.dumps(observation_to_record(obs))))
    assert back == obs
    rec2 = decode_observation(encode_observation(obs), label="x")
    assert rec2 == obs and rec2.keypoints == a
    turned = obs.rotated(np.deg2rad(30.0))
    assert turned.keypoints is not None and np.allclose(
        np.rad2deg(turned.keypoints.bearing - a.bearing) % 360.0, 30.0
    )
    for bad in ({"n": 2, "dim": 3, "pos": "AAAA", "desc": "AAAA"}, {"n": 1}, {"n": 1, "dim": 1, "pos": "!!", "desc": ""}):
        with pytest.raises(DataFormatError, match="keypoints"):
            decode_keypoints(bad)
    with pytest.raises(DataFormatError, match="keypoints"):
        observation_from_record({"features": {}, "keypoints": [1, 2]})
    with pytest.raises(InvalidParameterError, match="keypoints"):
        Observation(keypoints=np.zeros((3, 4)))  # type: ignore[arg-type]


def test_records_with_profile_and_keypoints_and_truncated_ones(views):
    obs = Observation(keypoints=views["b"], profile=np.ones((8, 2)), appearance=np.ones(3), pose=(1.0, 2.0, 0.5))
    data = encode_observation(obs)
    assert data[0] == 3
    assert decode_observation(data) == obs
    assert encode_observation(Observation(profile=np.ones((8, 2))))[0] == 2  # older versions stay as they were
    assert encode_observation(Observation())[0] == 1
    for cut in (1, 7, len(data) // 2):
        with pytest.raises(DatabaseError, match="corrupt"):
            decode_observation(data[:-cut])


def test_grey_band_any_size_and_bad_input():
    img = _texture(3, 90, 360)
    assert grey_band(img, 360).shape == (90, 360)
    small = grey_band(img, 1440)
    assert small.shape == (360, 1440) and 0 <= small.min() and small.max() <= 1
    big = np.repeat(np.repeat(img, 8, axis=0), 8, axis=1)  # 2880 columns
    assert grey_band(big, 1440).shape == (360, 1440)
    assert not np.any(grey_band(np.zeros((40, 200, 3)), 1440))  # flat: no contrast, no keypoints
    assert len(extract_keypoints(Panorama(np.zeros((40, 200, 3), dtype=np.uint8)))) == 0
    with pytest.raises(DataFormatError, match="too small"):
        grey_band(np.zeros((2, 8, 3)), 1440)
    with pytest.raises(InvalidParameterError, match="n_keypoints"):
        KeypointParams(n_keypoints=0)
    with pytest.raises(InvalidParameterError, match="unknown keypoint parameter"):
        extract_keypoints(Panorama(np.zeros((40, 200, 3), dtype=np.uint8)), bogus=1)


def _obs(img: np.ndarray, shift: int, seed: int, label: str) -> Observation:
    return Observation(keypoints=extract_keypoints(_noisy(img, shift, seed), width=480), label=label)


def test_keypoint_term_recognises_rooms_and_says_nothing_without_keypoints():
    rooms = [_texture(20 + r, 120, 480) for r in range(3)]
    train = [_obs(rooms[r], s, 100 + 10 * r + k, f"room{r}") for r in range(3) for k, s in enumerate((0, 150))]
    groups = [train[0:2], train[2:4], train[4:6]]
    term = KeypointTerm().fit(groups)
    assert term.lambda_ > 0 and term.unknown_cost_ is not None
    queries = [_obs(rooms[r], 77 * (r + 1), 500 + r, f"room{r}") for r in range(3)]
    ll = term.log_likelihood(queries)
    assert list(np.argmax(ll, axis=1)) == [0, 1, 2]
    assert np.all(term.log_likelihood([Observation()]) == 0.0)
    assert np.all(term.unknown_log_likelihood([Observation()]) == 0.0)
    again = KeypointTerm.from_state(term.to_state(), groups)
    assert np.allclose(again.log_likelihood(queries), ll)
    with pytest.raises(InvalidParameterError, match="malformed"):
        KeypointTerm.from_state({"lambda": -1}, groups)
    with pytest.raises(InvalidParameterError, match="ratio"):
        KeypointTerm(ratio=0).fit(groups)
    model = PlaceModel(terms=("K",)).fit(train)
    assert list(model.predict(queries)) == ["room0", "room1", "room2"]


def test_features_learn_localize_with_keypoints(tmp_path, capsys):
    """Photos made here: ``features`` writes keypoints, ``learn`` stores them, ``localize`` uses K (panorama preset)."""
    rooms = [_texture(40 + r, 180, 720) for r in range(2)]

    def photo(r: int, shift: int, seed: int, path) -> None:
        full = np.full((360, 720, 3), 0.5)
        full[90:270] = np.asarray(_noisy(rooms[r], shift, seed).image)
        Image.fromarray((full * 255).round().astype(np.uint8)).save(path)

    train = tmp_path / "train.jsonl"
    with train.open("w") as fh:
        for r in range(2):
            files = []
            for k, sh in enumerate((0, 300)):
                files.append(tmp_path / f"r{r}_{k}.png")
                photo(r, sh, 10 * r + k, files[-1])
            out = tmp_path / f"r{r}.jsonl"
            code, _, err = run_cli(capsys, "features", *files, "--place", f"room{r}", "--json", out)
            assert code == 0, err
            fh.write(out.read_text())
    first = json.loads(train.read_text().splitlines()[0])
    assert first["keypoints"]["n"] > 50 and first["keypoints"]["dim"] == 128
    db = tmp_path / "places.sqlite"
    code, _, err = run_cli(capsys, "learn", train, "--db", db)
    assert code == 0, err
    with sqlite3.connect(db) as con:
        blobs = [row[0] for row in con.execute("SELECT data FROM observations")]
    assert blobs and all(b[0] == 3 for b in blobs)
    q = tmp_path / "q.png"
    photo(1, 123, 99, q)
    qj = tmp_path / "q.jsonl"
    assert run_cli(capsys, "features", q, "--json", qj)[0] == 0
    ans = tmp_path / "ans.json"
    code, _, err = run_cli(capsys, "localize", qj, "--db", db, "--json", ans)
    assert code == 0, err
    text = ans.read_text()
    recs = json.loads(text)["observations"] if text.lstrip().startswith("{") else [json.loads(x) for x in text.splitlines()]
    assert recs[0]["best"] == "room1" and "K" in recs[0]["terms"]


def test_bad_image_gives_one_line_error(tmp_path, capsys):
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"not a jpeg")
    code, _, err = run_cli(capsys, "features", bad, "--json", tmp_path / "o.jsonl")
    assert code != 0 and "bad.jpg" in err and len(err.strip().splitlines()) == 1
    assert issubclass(DataFormatError, FingerlocError)
