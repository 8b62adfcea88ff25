"""Place database schema version 3: compact binary records, the same model back, old files still read.

``tests/data/v2_laser.sqlite`` (``fingerloc map`` of the rooms log of
``tests/_logs.py``) and ``tests/data/v2_paper.sqlite`` (``PlaceModel(3,
costs=CostModel.feature_aware(), cyclic=True, unknown_prior=0.1)`` on
``tests._places.dataset()``) were written by fingerloc at commit a5df8c7
(schema version 2), then compacted with ``VACUUM`` (512-byte pages; same
content); ``v2_answers.json`` holds that fingerloc's answers from them
(``predict_log_proba`` and ``predict_unknown_proba`` on ``dataset(seed=7,
n=2)``, and the laser model's ``predict_log_proba`` and ``headings`` on the
log's scans).
"""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fingerloc import Observation
from fingerloc.config import Config
from fingerloc.errors import DatabaseError
from fingerloc.map._records import decode_observation, encode_observation
from fingerloc.map.database import SCHEMA_VERSION, load_model, save_model
from fingerloc.model import PlaceModel
from fingerloc.pipeline.placemap import load_map
from fingerloc.pipeline.readers import read_run

from ._observations import observations
from ._places import dataset

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def answers():
    return json.loads((DATA / "v2_answers.json").read_text())


def _same_observation(a: Observation, b: Observation, *, scan: bool = True, walls32: bool = False) -> bool:
    for k in ("ve", "cp", "cp_hue", "ex", "c", "b", "w", "w_length", "w_range"):
        x, y = getattr(a, k), getattr(b, k)
        if walls32 and k in ("w_length", "w_range"):
            x = x.astype(np.float32).astype(np.float64)
        if x.tobytes() != y.tobytes():
            return False
    for k in ("ranges", "range_bearings", "appearance", "profile") if scan else ("appearance", "profile"):
        x, y = getattr(a, k), getattr(b, k)
        if (x is None) != (y is None) or (x is not None and x.tobytes() != y.tobytes()):
            return False
    return (a.fov, a.pose, a.timestamp, a.label, a.source) == (b.fov, b.pose, b.timestamp, b.label, b.source)


def test_version_2_files_give_their_answers(tmp_path, rooms_log, answers):
    test, _ = dataset(seed=7, n=2)
    paper = load_model(DATA / "v2_paper.sqlite")
    assert paper.predict_log_proba(test).tolist() == answers["paper_log_proba"]
    assert paper.predict_unknown_proba(test).tolist() == answers["paper_unknown"]
    lm = load_map(DATA / "v2_laser.sqlite")
    q = read_run(rooms_log).observations(features={})
    assert lm.model.predict_log_proba(q).tolist() == answers["laser_log_proba"]
    np.testing.assert_array_equal(lm.model.headings(q), np.array(answers["laser_headings"], dtype=float))
    assert len(lm.content_hashes) == 9 and lm.preset is not None and lm.preset.name == "laser2d"


@pytest.mark.parametrize("name", ["v2_paper", "v2_laser"])
def test_version_2_model_saved_as_version_3_answers_alike(tmp_path, rooms_log, name):
    old = load_model(DATA / f"{name}.sqlite")
    save_model(old, tmp_path / "v3.sqlite")
    with sqlite3.connect(tmp_path / "v3.sqlite") as con:
        assert con.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone() == (str(SCHEMA_VERSION),)
        # v2 observations came back from 12-digit JSON: their fingerprints are kept, not recomputed
        assert con.execute("SELECT count(*) FROM fingerprints").fetchone()[0] > 0
    new = load_model(tmp_path / "v3.sqlite")
    q = dataset(seed=7, n=2)[0] if name == "v2_paper" else read_run(rooms_log).observations(features={})
    np.testing.assert_array_equal(new.predict_log_proba(q), old.predict_log_proba(q))
    np.testing.assert_array_equal(new.headings(q), old.headings(q))


def test_version_3_round_trip_is_exact(tmp_path, rooms_log):
    from fingerloc.pipeline.mapping import make_map

    run = read_run(rooms_log)
    pm = make_map(run, Config().with_(calibration={"enabled": False}))
    db = tmp_path / "m.sqlite"
    pm.save(db)
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT count(*) FROM fingerprints").fetchone() == (0,)  # every one recomputed exactly
        assert {r[0] for r in con.execute("SELECT encoding FROM range_descriptors")} <= {"|u1", "<u2"}
        assert con.execute("PRAGMA page_size").fetchone() == (1024,)
        assert con.execute("SELECT value FROM meta WHERE key = 'default_fov'").fetchone() is not None  # 180 deg scans
        assert all(len(h) == 32 for (h,) in con.execute("SELECT hash FROM content_hashes"))
    lm = load_map(db)
    m, m2 = pm.model, lm.model
    for a, b in zip(m.places_.values(), m2.places_.values(), strict=True):
        assert len(a.observations) == len(b.observations)
        for oa, ob in zip(a.observations, b.observations, strict=True):
            assert oa.ranges is None and ob.ranges is None  # the range term keeps counts, not scans
            assert _same_observation(oa, ob, scan=False, walls32=True)
    for ga, gb in zip(m.terms_["Fp"].fingerprints_, m2.terms_["Fp"].fingerprints_, strict=True):
        for fa, fb in zip(ga, gb, strict=True):
            assert fa.letters == fb.letters and fa.bearings.tobytes() == fb.bearings.tobytes()
    for da, db_ in zip(m.terms_["R"].descriptors_, m2.terms_["R"].descriptors_, strict=True):
        assert da.tobytes() == db_.tobytes()
    q = run.observations(features={})
    np.testing.assert_array_equal(m2.predict_log_proba(q), m.predict_log_proba(q))
    np.testing.assert_array_equal(m2.headings(q), m.headings(q))
    from fingerloc.map.database import observation_hash

    assert lm.content_hashes == {observation_hash(o) for o in pm.training} and len(lm.content_hashes) == 9
    # learning more into it (a new place) keeps the stored places' answers
    extra = [o.with_label("new") for o in q[:2]]
    m2.add_places(extra)
    m.add_places(extra)
    save_model(m2, tmp_path / "m2.sqlite")
    np.testing.assert_array_equal(load_model(tmp_path / "m2.sqlite").predict_log_proba(q), m.predict_log_proba(q))


@given(observations(), st.booleans(), st.booleans(), st.booleans())
def test_binary_records_round_trip(obs, scan, walls32, default):
    fov = obs.fov if default else None
    data = encode_observation(obs, scan=scan, walls32=walls32, default_fov=fov)
    back = decode_observation(data, label=obs.label, source=obs.source, default_fov=fov)
    assert _same_observation(obs, back, scan=scan, walls32=walls32)
    assert scan or back.ranges is None


def test_walls_at_a_class_edge_stay_exact(tmp_path):
    """A wall 1 ulp short of 3 m is "medium"; as float32 it would be 3.0, "long": it is stored as float64."""
    from fingerloc.fingerprint import make_fingerprint

    edge = np.nextafter(3.0, 0.0)
    assert np.float32(edge) == 3.0
    obs = [Observation(c=[0.5], w=[0.1, 1.0], w_length=[edge, 1.5], w_range=[2.0, 2.0], label="a"),
           Observation(c=[0.6], w=[1.0], w_length=[1.5], w_range=[2.0], label="a"),
           Observation(c=[2.5], ex=[1.0], label="b")]  # fmt: skip
    model = PlaceModel(terms=("Fp",), laser_letters=True, cyclic=True).fit(obs)
    save_model(model, tmp_path / "w.sqlite")
    back = load_model(tmp_path / "w.sqlite")
    first = back.places_["a"].observations[0]
    assert first.w_length.tobytes() == obs[0].w_length.tobytes()  # float64: exact
    assert back.places_["a"].observations[1].w_length[0] == np.float32(1.5)
    fp = make_fingerprint(first, laser_letters=True)
    assert fp.letters == make_fingerprint(obs[0], laser_letters=True).letters
    with sqlite3.connect(tmp_path / "w.sqlite") as con:
        assert con.execute("SELECT count(*) FROM fingerprints").fetchone() == (0,)


@pytest.mark.parametrize("data", [b"", b"\x02\x00" + bytes(9), b"\x01\x00" + bytes(8), b"\x01\x00\x01" + bytes(8),
                                  b"\x01\x40" + bytes(9), b"\x01\x44" + bytes(9), "text"])  # fmt: skip
def test_corrupt_binary_records_are_refused(data):
    with pytest.raises(DatabaseError, match="corrupt observation record"):
        decode_observation(data)


def test_crafted_range_encoding_is_refused(tmp_path):
    shutil.copyfile(DATA / "v2_laser.sqlite", tmp_path / "a.sqlite")
    model = load_model(tmp_path / "a.sqlite")
    save_model(model, tmp_path / "b.sqlite")
    with sqlite3.connect(tmp_path / "b.sqlite") as con:
        con.execute("UPDATE range_descriptors SET encoding = 'pickle'")
    with pytest.raises(DatabaseError, match="encoding 'pickle'"):
        load_model(tmp_path / "b.sqlite")


@pytest.mark.parametrize("decimals", [3, None])
def test_profiles_are_stored_exactly(decimals):
    """A column profile (panorama views) survives the binary record bit for bit, in thousandths or in float64."""
    rng = np.random.default_rng(3)
    prof = rng.normal(size=(72, 20))
    if decimals is not None:  # as read from JSON Lines: whole thousandths, stored as int16
        prof = np.round(prof, decimals)
    obs = Observation.from_degrees({"VE": [10.0, 200.0]}, profile=prof, appearance=[0.5, 0.25])
    data = encode_observation(obs)
    back = decode_observation(data)
    assert back.profile is not None and np.array_equal(back.profile, obs.profile)
    assert back == obs
    assert data[0] == 2 and len(data) < (2 if decimals else 8) * prof.size + 200
    with pytest.raises(DatabaseError):
        decode_observation(data[:-1])  # one byte short
    bad = bytearray(data)
    bad[2 + 9] = 7  # the profile's encoding byte
    with pytest.raises(DatabaseError):
        decode_observation(bytes(bad))


def test_panorama_model_with_profiles_loads_with_the_same_answers(tmp_path):
    rng = np.random.default_rng(0)
    obs = [
        Observation.from_degrees(
            {"VE": list(rng.uniform(0, 360, 6))},
            label=f"p{p}",
            profile=np.round(rng.normal(size=(72, 5)), 3),
            appearance=rng.uniform(0, 1, 10),
        )
        for p in range(3)
        for _ in range(3)
    ]
    model = PlaceModel(terms=("Fp", "A", "AP"), cyclic=True).fit(obs, [o.label for o in obs])
    save_model(model, tmp_path / "p.sqlite")
    again = load_model(tmp_path / "p.sqlite")
    assert np.array_equal(model.predict_log_proba(obs), again.predict_log_proba(obs))
    assert np.array_equal(model.headings_with_reference(obs, [o.label for o in obs])[0],
                          again.headings_with_reference(obs, [o.label for o in obs])[0])  # fmt: skip
