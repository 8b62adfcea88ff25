"""One writer protocol for the place database: nothing a user had is lost, whatever runs at the same time.

The four ways a database used to lose data are tests here: ``learn`` into a
database made by ``map`` (its place positions), ``track --graph-from`` while a
``learn`` runs (the places that ``learn`` added), a database left in SQLite's
WAL mode by another program (every later open failed), and outputs that are
devices, FIFOs or symbolic link loops (replaced by a regular file).
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import stat
import threading
from pathlib import Path

import numpy as np
import pytest

from fingerloc.cli import main
from fingerloc.config import Config
from fingerloc.io.jsonl import write_observations
from fingerloc.map.database import load_model
from fingerloc.pipeline.mapping import make_map
from fingerloc.pipeline.placemap import load_map
from fingerloc.pipeline.readers import read_run

from ._cli import run_cli as run


def _places_file(path, labels, *, offset=0):
    lines = []
    for k, lab in enumerate(labels):
        for j in range(3):
            ve = [(10 + 37 * (k + offset) + 40 * i + 2 * j) % 360 for i in range(5)]
            lines.append(json.dumps({"place": lab, "features": {"VE": ve, "c": [ve[0] + 5, ve[2] + 7]}}))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def mapped(rooms_log, tmp_path_factory):
    """A database made by ``map`` of the rooms log (no calibration: fast), and its map."""
    d = tmp_path_factory.mktemp("mapped")
    pm = make_map(read_run(rooms_log), Config().with_(calibration={"enabled": False}))
    db = d / "m.sqlite"
    pm.save(db)
    return db, pm


def _copy(db: Path, tmp_path: Path) -> Path:
    out = tmp_path / db.name
    out.write_bytes(db.read_bytes())
    return out


# ---- 1. learn into a map keeps its positions, graph, calibration and scan map ------------------------


def test_learn_into_a_map_keeps_positions_graph_calibration_and_scan_map(mapped, tmp_path, capsys):
    src, pm = mapped
    db = _copy(src, tmp_path)
    before = load_map(db)
    n_before = len(before.labels)
    assert before.positions is not None and n_before >= 3
    # two new places, seen from poses 3 m beside places 0 and 1, and one more view of place 2
    views = []
    for k, lab in enumerate(("n0", "n1")):
        o = pm.training[k]
        x, y, th = o.pose
        views += [o.with_label(lab).__class__(**{**_fields(o), "label": lab, "pose": (x + 3.0 + 0.1 * j, y, th)})
                  for j in range(2)]  # fmt: skip
    views.append(pm.training[-1].rotated(0.2))
    extra = tmp_path / "extra.jsonl"
    write_observations(extra, views)
    code, _, err = run(capsys, "learn", extra, "--db", db)
    assert code == 0, err
    after = load_map(db)
    assert after.positions is not None, "the map's positions were lost"
    assert after.labels[:n_before] == before.labels
    assert np.array_equal(after.positions[:n_before], before.positions)
    new = {lab: after.positions[after.labels.index(lab)] for lab in ("n0", "n1")}
    x0, y0, _ = pm.training[0].pose
    assert new["n0"] == pytest.approx([x0 + 3.05, y0])  # the mean of its views' poses
    assert after.calibration is not None and after.calibration.n_train == before.calibration.n_train + 5
    assert after.scan_map is not None and after.scan_map.cells.shape[0] > before.scan_map.cells.shape[0]
    assert after.graph.edges().keys() >= before.graph.edges().keys()
    assert after.has_positions and after.tracker(filter="pose") is not None  # what track needs is there


def _fields(o):
    from dataclasses import fields

    return {f.name: getattr(o, f.name) for f in fields(o)}


def test_learn_new_places_without_poses_into_a_map_is_refused(mapped, tmp_path, capsys):
    src, _pm = mapped
    db = _copy(src, tmp_path)
    before = db.read_bytes()
    extra = _places_file(tmp_path / "no-pose.jsonl", ["elsewhere"])
    code, _, err = run(capsys, "learn", extra, "--db", db)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    assert "'elsewhere'" in lines[0] and "pose" in lines[0] and "new database" in lines[0]
    assert db.read_bytes() == before


def test_learn_laser_views_into_an_image_database_is_refused(tmp_path, capsys, mapped):
    _, pm = mapped
    db = tmp_path / "img.sqlite"
    pano = tmp_path / "pano.jsonl"
    recs = [{"place": p, "features": {"CP": [{"bearing": 10 * k + 40 * j, "hue": 30 * j} for j in range(3)]}}
            for k, p in enumerate(["a", "a", "b", "b"])]  # fmt: skip
    pano.write_text("\n".join(json.dumps(r) for r in recs) + "\n")
    assert run(capsys, "learn", pano, "--db", db, "--no-calibration")[0] == 0
    laser = tmp_path / "laser.jsonl"
    write_observations(laser, pm.training[:3])
    before = db.read_bytes()
    code, _, err = run(capsys, "learn", laser, "--db", db)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "laser" in err and "image" in err, err
    assert db.read_bytes() == before


# ---- 2. track --graph-from holds the lock: a concurrent learn waits and keeps its places --------------


def test_track_graph_from_and_a_concurrent_learn_keep_every_place(tmp_path, capsys, monkeypatch):
    data = _places_file(tmp_path / "train.jsonl", ["a", "b", "c"])
    more = _places_file(tmp_path / "more.jsonl", ["d", "e"], offset=5)
    db = tmp_path / "p.sqlite"
    assert run(capsys, "learn", data, "--db", db, "--no-calibration")[0] == 0
    import fingerloc.map.database as database
    from fingerloc.pipeline.placemap import PlaceMap

    real_track, real_info = PlaceMap.track, database.read_map_info
    threads: list[threading.Thread] = []
    moments = {"tracked": False, "fired": False}

    def learn_more() -> None:
        try:
            main(["learn", str(more), "--db", str(db)])
        except SystemExit:
            pass

    def another_writer() -> None:
        fd = os.open(f"{db}.lock", os.O_RDWR | os.O_CREAT)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            held = False
            fcntl.flock(fd, fcntl.LOCK_UN)
        except OSError as err:
            assert err.errno in (errno.EWOULDBLOCK, errno.EAGAIN)
            held = True
        finally:
            os.close(fd)
        if held:  # the writer waits for track's lock: let it wait in a thread
            t = threading.Thread(target=learn_more)
            t.start()
            threads.append(t)
        else:  # nothing stops it: it writes now
            learn_more()

    def track(*args, **kwargs):
        moments["tracked"] = True
        return real_track(*args, **kwargs)

    def read_map_info(*args, **kwargs):
        # once track has run, while it stores the graph (after it read the model again): another writer comes
        if moments["tracked"] and not moments["fired"] and threading.current_thread() is threading.main_thread():
            moments["fired"] = True
            another_writer()
        return real_info(*args, **kwargs)

    monkeypatch.setattr(PlaceMap, "track", track)
    monkeypatch.setattr(database, "read_map_info", read_map_info)
    code, _, err = run(capsys, "track", data, "--db", db, "--graph-from", data, "-q")
    for t in threads:
        t.join(timeout=120)
    assert code == 0, err
    assert moments["fired"], "the graph was stored without reading the database again"
    assert sorted(str(c) for c in load_model(db).classes_) == ["a", "b", "c", "d", "e"]


def test_a_held_lock_is_said_and_given_up_after_the_timeout(tmp_path, capsys):
    data = _places_file(tmp_path / "train.jsonl", ["a", "b"])
    db = tmp_path / "p.sqlite"
    assert run(capsys, "learn", data, "--db", db, "--no-calibration")[0] == 0
    before = db.read_bytes()
    fd = os.open(f"{db}.lock", os.O_RDWR)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        more = _places_file(tmp_path / "more.jsonl", ["c"])
        code, _, err = run(capsys, "learn", more, "--db", db, "--lock-timeout", "0.3")
    finally:
        os.close(fd)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 2, err
    assert lines[0].startswith("waiting for") and "--lock-timeout" in lines[0]
    assert lines[1].startswith("error: ") and "gave up" in lines[1] and "lock" in lines[1]
    assert db.read_bytes() == before
    code, _, err = run(capsys, "learn", more, "--db", db, "--lock-timeout", "nan")
    assert code == 2 and "--lock-timeout" in err


# ---- 3. a database in WAL mode with a -wal file left by another program ----------------------------


def _leave_wal(db: Path) -> None:
    """Switch ``db`` to WAL mode and commit a change into the -wal file without a checkpoint (a program that died)."""
    import subprocess
    import sys

    code = (
        "import sqlite3, os, sys\n"
        "con = sqlite3.connect(sys.argv[1], isolation_level=None)\n"
        "con.execute('PRAGMA journal_mode=WAL')\n"
        "con.execute(\"UPDATE meta SET value = value WHERE key = 'format'\")\n"  # a page in the WAL, the same rows
        "os._exit(0)\n"
    )
    subprocess.run([sys.executable, "-c", code, str(db)], check=True)


@pytest.mark.parametrize("command", ["learn", "map"])
def test_a_wal_file_left_by_another_program_is_settled_before_the_save(tmp_path, capsys, command, rooms_log):
    data = _places_file(tmp_path / "train.jsonl", ["a", "b"])
    db = tmp_path / "p.sqlite"
    assert run(capsys, "learn", data, "--db", db, "--no-calibration")[0] == 0
    _leave_wal(db)
    assert Path(f"{db}-wal").exists()
    if command == "learn":
        args = ["learn", _places_file(tmp_path / "more.jsonl", ["c"], offset=3), "--db", db]
    else:
        args = ["map", rooms_log, "--db", db, "--overwrite", "--no-calibration", "--no-heading", "--no-scan"]
    code, _, err = run(capsys, *args)
    assert code == 0, err
    assert not Path(f"{db}-wal").exists() and not Path(f"{db}-shm").exists()
    model = load_model(db)  # opens: not "database disk image is malformed"
    assert len(model.classes_) == (3 if command == "learn" else len(load_map(db).labels))
    code, _, err = run(capsys, "places", "--db", db)
    assert code == 0, err


# ---- 4. outputs that are not regular files --------------------------------------------------------


def test_a_fifo_output_is_refused_and_stays_a_fifo(tmp_path, capsys, mapped):
    src, _ = mapped
    db = _copy(src, tmp_path)
    data = _places_file(tmp_path / "q.jsonl", ["x"])
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    code, _out, err = run(capsys, "localize", data, "--db", db, "--json", fifo)
    assert code == 2 and err.startswith("error: --json: ") and "FIFO" in err and len(err.strip().splitlines()) == 1
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    code, _, err = run(capsys, "learn", data, "--db", fifo)
    assert code == 2 and "--db" in err and "FIFO" in err and stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_a_character_device_output_is_refused(tmp_path, capsys):
    dev = tmp_path / "null-like"
    try:
        os.mknod(dev, stat.S_IFCHR | 0o666, os.makedev(1, 3))  # what /dev/null is
    except (PermissionError, OSError):
        pytest.skip("cannot make a device node here")
    data = _places_file(tmp_path / "t.jsonl", ["a", "b"])
    code, _, err = run(capsys, "learn", data, "--db", dev)
    assert code == 2 and "character device" in err and len(err.strip().splitlines()) == 1
    assert stat.S_ISCHR(os.lstat(dev).st_mode)
    db = tmp_path / "p.sqlite"
    assert run(capsys, "learn", data, "--db", db, "--no-calibration")[0] == 0
    code, _, err = run(capsys, "localize", data, "--db", db, "--json", dev)
    assert code == 2 and "--json" in err and "character device" in err and stat.S_ISCHR(os.lstat(dev).st_mode)


def test_a_symbolic_link_loop_as_db_is_refused_and_stays_a_link(tmp_path, capsys):
    loop = tmp_path / "loop.sqlite"
    loop.symlink_to(loop.name)
    data = _places_file(tmp_path / "t.jsonl", ["a", "b"])
    code, _, err = run(capsys, "learn", data, "--db", loop)
    assert code == 2 and "symbolic link loop" in err and len(err.strip().splitlines()) == 1
    assert loop.is_symlink() and os.readlink(loop) == loop.name


def test_map_json_into_a_fifo_is_refused_before_the_work(tmp_path, capsys, rooms_log):
    fifo = tmp_path / "train.fifo"
    os.mkfifo(fifo)
    db = tmp_path / "m.sqlite"
    code, _, err = run(capsys, "map", rooms_log, "--db", db, "--json", fifo, "--no-calibration")
    assert code == 2 and "FIFO" in err and not db.exists() and stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_map_writes_the_database_and_its_outputs_together_or_none(tmp_path, capsys, rooms_log, monkeypatch):
    """A failure after the database's save (the --queries file cannot be written): nothing is replaced."""
    db, train, queries = tmp_path / "m.sqlite", tmp_path / "t.jsonl", tmp_path / "q.jsonl"
    db.write_bytes(b"old database")
    train.write_text("old training\n")
    import fingerloc.io.jsonl as jl

    real = jl.observation_to_record
    calls = {"n": 0}

    def failing(obs, **kw):
        calls["n"] += 1
        if calls["n"] > 12:  # in the queries, after the database and the 9 training views
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(obs, **kw)

    monkeypatch.setattr(jl, "observation_to_record", failing)
    code, _, err = run(capsys, "map", rooms_log, "--db", db, "--overwrite", "--json", train, "--queries", queries,
                       "--no-calibration", "--no-heading")  # fmt: skip
    assert code == 2 and err.strip().splitlines()[-1].startswith("error: ") and "no space left" in err.lower(), err
    assert db.read_bytes() == b"old database" and train.read_text() == "old training\n" and not queries.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_a_report_that_fails_halfway_leaves_the_old_report_and_database(tmp_path, capsys, rooms_log, monkeypatch):
    """``map --report`` out of space after some of the report's figures: the old report and database stay."""
    db, report = tmp_path / "m.sqlite", tmp_path / "report"
    db.write_bytes(b"old database")
    report.mkdir()
    (report / "index.html").write_text("old page")
    import fingerloc.reporting.pages as pages

    real = pages.draw_view_thumbnail
    calls = {"n": 0}

    def failing(*args, **kw):
        calls["n"] += 1
        if calls["n"] > 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(*args, **kw)

    monkeypatch.setattr(pages, "draw_view_thumbnail", failing)
    code, _, err = run(capsys, "map", rooms_log, "--db", db, "--overwrite", "--report", report, "--no-calibration",
                       "--no-heading")  # fmt: skip
    assert code == 2 and err.strip().splitlines()[-1].startswith("error: ") and "no space left" in err.lower(), err
    assert calls["n"] == 3
    assert db.read_bytes() == b"old database"
    assert (
        sorted(p.name for p in report.iterdir()) == ["index.html"] and (report / "index.html").read_text() == "old page"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.sqlite", "m.sqlite.lock", "report"]  # no temporary


def test_a_new_report_folder_is_written_whole_with_the_database(tmp_path, capsys, rooms_log):
    db, report = tmp_path / "m.sqlite", tmp_path / "report"
    code, _, err = run(capsys, "map", rooms_log, "--db", db, "--report", report, "--no-calibration", "--no-heading")
    assert code == 0, err
    assert (report / "index.html").is_file() and db.is_file()
    page = (report / "index.html").read_text()
    figures = [p for p in report.rglob("*.png")]
    assert figures and all(f'src="{p.relative_to(report).as_posix()}"' in page or p.parent != report for p in figures)
    assert not [p for p in tmp_path.rglob(".fingerloc-report-*")]
