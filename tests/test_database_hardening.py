"""The place database never loses anything, and crafted files are refused on load."""

from __future__ import annotations

import json
import os
import sqlite3
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from fingerloc.errors import DatabaseError
from fingerloc.map.database import load_model, read_graph_edges

from ._cli import run_cli as run

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _places_file(path, labels, *, poses=False, offset=0):
    lines = []
    for k, lab in enumerate(labels):
        for j in range(3):
            ve = [(10 + 37 * (k + offset) + 40 * i + 2 * j) % 360 for i in range(5)]
            rec = {"place": lab, "features": {"VE": ve, "c": [ve[0] + 5, ve[2] + 7]}}
            if poses:
                rec["pose"] = [2.0 * k + 0.1 * j, 0.0, 0.0]
            lines.append(json.dumps(rec))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.fixture
def learned(tmp_path, capsys):
    data = _places_file(tmp_path / "train.jsonl", ["a", "b", "c"], poses=True)
    db = tmp_path / "p.sqlite"
    code, _, err = run(capsys, "learn", data, "--db", db, "--preset", "paper")  # the paper's mixtures: every table has rows
    assert code == 0, err
    return data, db


def test_two_concurrent_learns_lose_nothing(tmp_path):
    db = tmp_path / "p.sqlite"
    files = [
        _places_file(tmp_path / f"w{w}.jsonl", [f"w{w}-{i}" for i in range(8)], offset=9 * w) for w in range(2)
    ]
    env = {**os.environ, "PYTHONPATH": SRC}
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", "from fingerloc.cli import main; main()", "learn", str(f), "--db", str(db)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        for f in files
    ]
    for p in procs:
        _, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
    places = set(load_model(db).places_)
    assert places == {f"w{w}-{i}" for w in range(2) for i in range(8)}


def test_learn_through_a_symlink_keeps_the_link_and_mode(tmp_path, capsys):
    data = _places_file(tmp_path / "d.jsonl", ["a", "b"])
    real = tmp_path / "store" / "real.sqlite"
    real.parent.mkdir()
    link = tmp_path / "link.sqlite"
    link.symlink_to(real)
    old = os.umask(0o022)
    try:
        code, _, err = run(capsys, "learn", data, "--db", link)
    finally:
        os.umask(old)
    assert code == 0, err
    assert link.is_symlink() and real.is_file()
    assert stat.S_IMODE(real.stat().st_mode) == 0o644
    real.chmod(0o640)
    code, _, err = run(capsys, "learn", _places_file(tmp_path / "e.jsonl", ["c"]), "--db", link)
    assert code == 0, err
    assert link.is_symlink() and stat.S_IMODE(real.stat().st_mode) == 0o640
    assert set(load_model(link).places_) == {"a", "b", "c"}


def test_stale_temporary_files_are_removed(tmp_path, capsys):
    data = _places_file(tmp_path / "d.jsonl", ["a", "b"])
    db = tmp_path / "p.sqlite"
    stale = [tmp_path / "p.sqlite.abc123.tmp", tmp_path / "p.sqlite.abc123.tmp-journal"]
    for f in stale:
        f.write_bytes(b"junk")
    other = tmp_path / "q.sqlite.x.tmp"
    other.write_bytes(b"not ours")
    assert run(capsys, "learn", data, "--db", db)[0] == 0
    assert not any(f.exists() for f in stale) and other.exists()


def test_hot_journal_is_left_to_sqlite(tmp_path, learned):
    _, db = learned
    places = set(load_model(db).places_)
    # a foreign writer dies mid-transaction: its rollback journal stays next to the file
    code = (
        "import sqlite3, os, sys\n"
        f"con = sqlite3.connect({str(db)!r}, isolation_level=None)\n"
        "con.execute('PRAGMA journal_mode=DELETE')\n"
        "con.execute('PRAGMA cache_size=1')\n"
        "con.execute('BEGIN')\n"
        "con.execute(\"UPDATE places SET label = label || '-x'\")\n"
        "con.execute('CREATE TABLE junk(x)')\n"
        "con.executemany('INSERT INTO junk VALUES (?)', [(b'0' * 4000,)] * 200)\n"
        "os._exit(0)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    journal = Path(str(db) + "-journal")
    if not journal.exists():
        pytest.skip("SQLite kept the transaction in memory: no hot journal to test")
    assert set(load_model(db).places_) == places


def test_directory_at_db(tmp_path, capsys):
    d = tmp_path / "adir"
    d.mkdir()
    for args in (("places", "--db", d), ("localize", _places_file(tmp_path / "x.jsonl", ["a"]), "--db", d)):
        code, _, err = run(capsys, *args)
        assert code == 2 and "is a directory" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "extra",
    [
        ["--seed", "-1", "--filter", "pose"],
        ["--filter", "pose", "--radius", "-3"],
        ["--scale", "0"],
    ],
)
def test_failed_track_leaves_the_database_byte_identical(tmp_path, capsys, learned, extra):
    data, db = learned
    before = db.read_bytes()
    code, _, err = run(capsys, "track", data, "--db", db, "--graph-from", data, *extra)
    assert code == 2, err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1
    assert db.read_bytes() == before


def test_track_graph_from_with_huge_poses_changes_nothing(tmp_path, capsys, learned):
    data, db = learned
    before = db.read_bytes()
    recs = [json.loads(x) for x in data.read_text().splitlines()]
    for r in recs:
        r["pose"] = [1e308, -1e308, 0.0]
    huge = tmp_path / "huge.jsonl"
    huge.write_text("\n".join(json.dumps(r) for r in recs) + "\n")
    code, _, err = run(capsys, "track", data, "--db", db, "--graph-from", huge, "--filter", "pose")
    assert code == 2 and err.startswith("error: ") and len(err.strip().splitlines()) == 1, err
    assert "huge.jsonl:1" in err and "pose" in err
    assert db.read_bytes() == before


def test_track_graph_from_stores_the_graph_on_success(tmp_path, capsys, learned):
    data, db = learned
    code, _, err = run(capsys, "track", data, "--db", db, "--graph-from", data, "-q")
    assert code == 0, err
    assert read_graph_edges(db)


def _crafted(db: Path, sql: str, *params) -> None:
    with sqlite3.connect(db) as con:
        con.execute(sql, params)
    con.close()


CRAFTED = {
    "medoid out of range": ("UPDATE places SET medoid = 99", "medoid 99"),
    "medoid as text": ("UPDATE places SET medoid = 'x'", "medoid"),
    "observation of a missing place": ("UPDATE observations SET place_id = 77 WHERE id = 1", "place id 77"),
    "mixture of a missing place": ("UPDATE mixtures SET place_id = 55 WHERE rowid = 1", "place id 55"),
    "params as a list": ("UPDATE meta SET value = '[1, 2]' WHERE key = 'params'", "params"),
    "bearings as text": ("INSERT OR REPLACE INTO fingerprints VALUES (1, 'c', 'abc')", "float64 blob"),
    "no observation rows": ("DELETE FROM observations", "no observation"),
    "graph count as text": ("INSERT INTO graph_edges VALUES ('a', 'b', 'many')", "count"),
    "label as a blob": ("UPDATE places SET label = x'00ff' WHERE id = 0", "label"),
    "lambdas as a string": ("UPDATE meta SET value = '\"x\"' WHERE key = 'lambdas'", "lambdas"),
    "record not an observation": ("UPDATE observations SET data = x'01ff' WHERE id = 1", "corrupt observation"),
    "record of a wrong length": ("UPDATE observations SET data = CAST(data || x'00' AS BLOB) WHERE id = 1", "corrupt observation"),
    "record as text": ("UPDATE observations SET data = 'abc' WHERE id = 1", "corrupt observation"),
    "sigma of zero": ("UPDATE mixtures SET sigmas = zeroblob(8 * length(sigmas) / 8)", "mixture"),
}


@pytest.mark.parametrize("case", list(CRAFTED))
def test_crafted_databases_are_refused(tmp_path, capsys, learned, case):
    data, db = learned
    sql, needle = CRAFTED[case]
    if case == "graph count as text":
        _crafted(db, "DELETE FROM graph_edges")
    _crafted(db, sql)
    with pytest.raises(DatabaseError, match=needle):
        load_model(db)
        read_graph_edges(db)
    code, _, err = run(capsys, "localize", data, "--db", db)
    if case != "graph count as text":
        assert code == 2 and err.startswith("error: ") and len(err.strip().splitlines()) == 1, err


def test_track_carmen_log_against_a_json_lines_database(tmp_path, capsys, learned):
    from ._logs import rooms_path as _path
    from ._logs import write_log as _write_log

    _, db = learned
    log = _write_log(tmp_path / "rooms.log", _path())
    before = db.read_bytes()
    code, _, err = run(capsys, "track", log, "--db", db, "--filter", "pose")
    assert code == 2 and "the pose filter needs place positions and a calibration" in err and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "track", log, "--db", db)  # the filter the map allows: over places, every scan observes
    assert code == 0 and "filter: places (the map has no place positions" in err
    code, _, err = run(capsys, "track", log, "--db", db, "--map")
    assert code == 2 and "exists" in err
    assert db.read_bytes() == before
