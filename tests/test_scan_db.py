"""The scan map in the place database (schema version 4) and on the library path: map -> database -> track.

``tests/data/v3_rooms.sqlite`` is ``fingerloc map`` of the rooms log of
``tests/_logs.py`` written by fingerloc's schema version 3 (before the scan map).
"""

from __future__ import annotations

import dataclasses
import json
import sqlite3
import zlib
from pathlib import Path

import numpy as np
import pytest

from fingerloc.config import Config
from fingerloc.errors import DatabaseError
from fingerloc.map.database import SCHEMA_VERSION, read_map_info, save_model
from fingerloc.map.scan_map import ScanMap
from fingerloc.pipeline.mapping import make_map, run_end_points
from fingerloc.pipeline.placemap import load_map
from fingerloc.pipeline.readers import read_run

from ._cli import run_cli as run

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def scan_map():
    rng = np.random.default_rng(3)
    walls = np.vstack([np.column_stack([np.linspace(0, 9, 300), np.full(300, y)]) for y in (0.0, 4.0)])
    return ScanMap.from_points(walls + rng.normal(0, 0.02, walls.shape), resolution=0.07, sigma=0.15, floor=0.1, clip=0.8)


def _with_scan_map(tmp_path: Path, sm: ScanMap) -> Path:
    """The v3 rooms map saved again (version 4) with ``sm`` as its scan map."""
    lm = load_map(DATA / "v3_rooms.sqlite")
    info = read_map_info(DATA / "v3_rooms.sqlite")
    info.scan_map = sm
    db = tmp_path / "s.sqlite"
    save_model(lm.model, db, graph_edges=lm.graph.edges(), info=info)
    return db


def test_scan_map_round_trip_is_exact(tmp_path, scan_map):
    db = _with_scan_map(tmp_path, scan_map)
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone() == (str(SCHEMA_VERSION),)
        assert SCHEMA_VERSION == 5
        (blob,) = con.execute("SELECT cells FROM scan_map").fetchone()
    assert len(blob) < 8 * scan_map.cells.shape[0]  # smaller than int32 pairs
    sm = load_map(db).scan_map
    assert isinstance(sm, ScanMap) and sm is not scan_map
    assert sm.cells.tobytes() == scan_map.cells.tobytes() and sm.cells.shape == scan_map.cells.shape
    assert sm.shape == scan_map.shape and sm.origin.tobytes() == scan_map.origin.tobytes()
    assert (sm.resolution, sm.sigma, sm.floor, sm.clip) == (scan_map.resolution, 0.15, 0.1, 0.8)
    rng = np.random.default_rng(5)
    poses = np.column_stack([rng.uniform(-1, 10, 200), rng.uniform(-1, 5, 200), rng.uniform(-np.pi, np.pi, 200)])
    pts = rng.uniform(-4, 4, (60, 2))
    a, b = scan_map.log_likelihood(poses, pts), sm.log_likelihood(poses, pts)
    assert a.tobytes() == b.tobytes() and np.ptp(a) > 0.1
    assert load_map(db, scan=False).scan_map is None
    lm = load_map(db)
    assert lm.tracker().scan_map is lm.scan_map and lm.tracker(scan=False).scan_map is None


@pytest.mark.parametrize("name", ["v3_rooms", "v2_laser"])
def test_older_databases_load_without_scan_evidence(name):
    lm = load_map(DATA / f"{name}.sqlite")
    assert lm.scan_map is None and read_map_info(DATA / f"{name}.sqlite").scan_map is None
    assert lm.calibration is not None and lm.calibration.scan_gamma == 0
    tr = dataclasses.replace(lm, calibration=dataclasses.replace(lm.calibration, scan_gamma=3.0)).tracker()
    f = tr.pose_filter
    assert tr.scan_map is None and not tr.uses_scan  # a stored gamma alone does nothing
    assert f is not None and f.scan_map is None and f.scan_gamma == 0


def _corrupt(db: Path, sql: str, *args: object) -> None:
    with sqlite3.connect(db) as con:
        con.execute(sql, args)


@pytest.mark.parametrize(
    "sql, args, words",
    [
        ("UPDATE scan_map SET cells = ?", (b"\x00not zlib at all",), "not zlib data"),
        ("UPDATE scan_map SET cells = ?", (zlib.compress(b"\xff" * 10),), "bitmap is not"),
        ("UPDATE scan_map SET n_cells = n_cells + 1", (), "occupied cells"),
        ("UPDATE scan_map SET encoding = ?", ("int32",), "unknown encoding"),
        ("UPDATE scan_map SET nx = ?", (10**9,), "grid of"),
        ("UPDATE scan_map SET sigma = ?", (-1.0,), "sigma"),
        ("UPDATE scan_map SET cells = ?", ("text",), "must be a blob"),
        ("UPDATE scan_map SET origin_x = ?", ("nan",), "finite numbers"),
    ],
)
def test_a_corrupt_scan_map_is_a_one_line_error(tmp_path, capsys, scan_map, sql, args, words):
    db = _with_scan_map(tmp_path, scan_map)
    _corrupt(db, sql, *args)
    with pytest.raises(DatabaseError, match="corrupt scan map") as info:
        load_map(db)
    assert words in str(info.value) and "\n" not in str(info.value)
    code, _, err = run(capsys, "places", "--db", db)
    assert code == 2 and err.startswith("error: ") and len(err.strip().splitlines()) == 1, err
    assert load_map(db, scan=False).scan_map is None  # the rest of the map still reads


def test_bits_beyond_the_grid_are_refused(tmp_path):
    sm = ScanMap(np.zeros(2), 0.1, (3, 3), np.array([[0, 0], [2, 2]]))
    db = _with_scan_map(tmp_path, sm)
    assert load_map(db).scan_map.cells.tolist() == [[0, 0], [2, 2]]
    _corrupt(db, "UPDATE scan_map SET cells = ?", zlib.compress(bytes([0b10000000, 0b11000000])))  # bit 9 of 9
    with pytest.raises(DatabaseError, match="beyond the grid"):
        load_map(db)


def _places_json(capsys, db):
    code, out, err = run(capsys, "places", "--db", db, "--json")
    assert code == 0, err
    return json.loads(out)


def test_map_stores_a_scan_map_and_track_uses_it(tmp_path, capsys, rooms_log):
    db = tmp_path / "m.sqlite"
    code, _, err = run(capsys, "map", rooms_log, "--db", db, "--no-calibration", "--no-heading")
    assert code == 0 and "scan map of" in err, err
    info = _places_json(capsys, db)["scan_map"]
    run_ = read_run(rooms_log)
    expected = ScanMap.from_scans(run_end_points(run_, np.arange(11)), run_.poses[:11])
    assert info["cells"] == expected.cells.shape[0] > 100 and info["resolution"] == pytest.approx(0.1)
    assert load_map(db).scan_map.cells.tobytes() == expected.cells.tobytes()

    def track(*flags, kind="pose"):
        out = tmp_path / "t.json"
        code, _, err = run(capsys, "track", rooms_log, "--db", db, "--filter", kind, "-q", "--json", out, *flags)
        assert code == 0, err
        return json.loads(out.read_text())

    on, off, stored = track("--scan-gamma", "3"), track("--scan-gamma", "3", "--no-scan"), track()
    assert on["summary"]["scan_gamma"] == 3.0 and off["summary"]["scan_gamma"] == 0.0
    assert stored["summary"]["scan_gamma"] == 0.0  # not tuned yet: the calibration's 0
    p_on = [s["probability"] for s in on["steps"]]
    assert p_on != [s["probability"] for s in off["steps"]]
    assert [s["probability"] for s in stored["steps"]] == [s["probability"] for s in off["steps"]]
    # the scan evidence is right here: it sharpens the filter at the true place
    obs = [s for s in on["steps"] if s["observed"]]
    assert all(s["best"] == s["true"] for s in obs)
    assert np.mean(p_on) > np.mean([s["probability"] for s in off["steps"]])
    assert "scan_gamma" not in track("--scan-gamma", "3", kind="places")["summary"]  # the place filter has none


def test_map_no_scan_stores_none_and_learn_keeps_one(tmp_path, capsys, rooms_log):
    db = tmp_path / "n.sqlite"
    code, _, err = run(capsys, "map", rooms_log, "--db", db, "--no-calibration", "--no-heading", "--no-scan")
    assert code == 0 and "scan map" not in err, err
    assert _places_json(capsys, db)["scan_map"] is None
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT count(*) FROM scan_map").fetchone() == (0,)
    db2, views = tmp_path / "s.sqlite", tmp_path / "views.jsonl"
    code, _, err = run(capsys, "map", rooms_log, "--db", db2, "--no-calibration", "--no-heading", "--json", views)
    assert code == 0, err
    before = load_map(db2).scan_map.cells
    code, _, err = run(capsys, "learn", views, "--db", db2)  # rewrites the database: the scan map stays
    assert code == 0 and "already stored" in err, err
    assert load_map(db2).scan_map.cells.tobytes() == before.tobytes()


def test_run_end_points_of_scans_and_records(rooms_log):
    run_ = read_run(rooms_log)
    pts = run_end_points(run_, [0, 3])
    assert pts is not None and len(pts) == 2
    s = run_.scans[0]
    assert np.array_equal(run_end_points(run_, [0], stride=1)[0], s.points())
    assert pts[0].shape == (len(s.points()[::3]), 2)
    obs = run_.observations([0, 3], features={})
    records = dataclasses.replace(run_, scans=None, records=obs, names=run_.names[:2])
    got = run_end_points(records, stride=1)
    assert np.allclose(got[0], s.points())  # FLASER: no sensor offset
    bare = dataclasses.replace(
        records, records=[dataclasses.replace(o, ranges=None, range_bearings=None) for o in obs]
    )
    assert run_end_points(bare) is None


def test_make_map_passes_the_scan_inputs_to_the_tuning(monkeypatch, rooms_log):
    """make_map gives tune_pose_filter the held-out rows' end points, the folds and the two folds' scan maps."""
    import fingerloc.pipeline.calibrate as calibrate

    seen: dict[str, object] = {}

    def fake_tune(cal, config, centres, graph, held, train_idx, mapping_poses, **kw):
        seen.update(kw, held=held)
        return dataclasses.replace(cal, scan_gamma=2.5), []

    def fake_folds(points, poses, fold, *, guard=1.0, travel=None):
        seen["fold_args"] = (len(points), np.asarray(poses).shape, np.asarray(fold).copy(), np.asarray(travel))
        return (ScanMap.from_scans(points, poses), ScanMap.from_scans(points, poses))

    def fake_scan_folds(train_idx, labels):
        return np.arange(len(train_idx)) % 2

    monkeypatch.setattr(calibrate, "tune_pose_filter", fake_tune)
    monkeypatch.setattr(calibrate, "fold_scan_maps", fake_folds)
    monkeypatch.setattr(calibrate, "scan_folds", fake_scan_folds)
    run_ = read_run(rooms_log)
    pm = make_map(run_, Config().with_(calibration={"heading": False}))
    assert pm.scan_map is not None
    held = seen["held"]
    n_train = pm.split.n_train
    fold = np.arange(n_train) % 2
    assert seen["fold_args"][:2] == (n_train, (n_train, 3)) and seen["fold_args"][2].tolist() == fold.tolist()
    assert seen["scan_fold"].tolist() == fold.tolist()
    travel = seen["fold_args"][3]
    assert travel.shape == (n_train,) and np.all(np.diff(travel) >= 0) and travel[-1] > 40  # metres along the run
    assert len(seen["scan_points"]) == held.scores.shape[0] and len(seen["scan_maps"]) == 2
    rows = pm.split.train_idx[held.index]
    assert np.array_equal(seen["scan_points"][0], run_end_points(run_, rows[:1])[0])
    assert pm.calibration.scan_gamma == 2.5
    seen.clear()
    pm = make_map(run_, Config().with_(calibration={"heading": False, "scan": False}))
    assert pm.scan_map is None and "scan_maps" not in seen
