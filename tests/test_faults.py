"""Faults of the system, each one line and nothing half-written: a full disk, a file-size limit, a read-only
file system, a name too long, a closed pipe, SIGINT.

The command runs in a subprocess with the fault made real: ``RLIMIT_FSIZE``
(``ulimit -f``), ``/dev/full`` as standard output, a pipe closed by its
reader, a small tmpfs (when this process may mount one), SIGINT while an
output is being written. Each must end in one ``error:`` line (exit 2, or 130
for SIGINT), leave every existing file byte-identical and no temporary file.
"""

from __future__ import annotations

import errno
import json
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ._cli import run_cli as run

SRC = str(Path(__file__).resolve().parents[1] / "src")
CMD = [sys.executable, "-c", "from fingerloc.cli import main; main()"]


def _places_file(path, labels, *, repeat=3):
    lines = []
    for k, lab in enumerate(labels):
        for j in range(repeat):
            ve = [(10 + 37 * k + 40 * i + 2 * j) % 360 for i in range(5)]
            lines.append(json.dumps({"place": lab, "features": {"VE": ve, "c": [ve[0] + 5, ve[2] + 7]}}))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _fsize(limit: int):
    def setup() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return setup


def _cli(*args, fsize=None, stdout=subprocess.PIPE, timeout=120):
    env = {**os.environ, "PYTHONPATH": SRC}
    return subprocess.run([*CMD, *map(str, args)], env=env, stdout=stdout, stderr=subprocess.PIPE, timeout=timeout,
                          preexec_fn=_fsize(fsize) if fsize else None)  # fmt: skip


def _one_error(p, code=2):
    lines = p.stderr.decode().strip().splitlines()
    assert p.returncode == code and len(lines) == 1 and lines[0].startswith("error: "), p.stderr.decode()
    return lines[0]


def _no_tmp(folder: Path) -> None:
    assert not [f.name for f in folder.iterdir() if f.name.endswith((".tmp", ".tmp-journal"))]


@pytest.fixture(scope="module")
def learned(tmp_path_factory):
    d = tmp_path_factory.mktemp("faults")
    data = _places_file(d / "train.jsonl", ["a", "b", "c"])
    db = d / "p.sqlite"
    p = _cli("learn", data, "--db", db, "--no-calibration")
    assert p.returncode == 0, p.stderr.decode()
    return data, db


def test_a_file_size_limit_while_learning_leaves_the_database_whole(learned, tmp_path):
    _data, src = learned
    db = tmp_path / "p.sqlite"
    db.write_bytes(src.read_bytes())
    before = db.read_bytes()
    more = _places_file(tmp_path / "more.jsonl", [f"m{i}" for i in range(30)])
    line = _one_error(_cli("learn", more, "--db", db, fsize=len(before) // 2))
    assert "cannot write" in line and ("full" in line or "too large" in line)
    assert db.read_bytes() == before
    _no_tmp(tmp_path)


def test_a_file_size_limit_on_a_json_output_is_one_line(learned, tmp_path):
    data, db = learned
    out = tmp_path / "out.json"
    out.write_text("old\n")
    line = _one_error(_cli("localize", data, "--db", db, "--json", out, "-q", fsize=200))
    assert "too large" in line and out.read_text() == "old\n"
    _no_tmp(tmp_path)


def test_standard_output_on_a_full_device_is_one_line(learned):
    _, db = learned
    with open("/dev/full", "wb") as full:
        p = _cli("places", "--db", db, stdout=full)
    assert "no space left" in _one_error(p)


def test_a_closed_pipe_is_one_line(tmp_path):
    data = _places_file(tmp_path / "many.jsonl", [f"p{i}" for i in range(400)], repeat=5)
    env = {**os.environ, "PYTHONPATH": SRC}
    proc = subprocess.Popen([*CMD, "fingerprint", str(data), "--json"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)  # fmt: skip
    assert proc.stdout is not None and proc.stdout.read(10)
    proc.stdout.close()  # the reader goes away (``| head -c 10``)
    err = proc.stderr.read().decode() if proc.stderr else ""
    code = proc.wait(timeout=120)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "broken pipe" in lines[0], err


def test_sigint_while_an_output_is_written_keeps_nothing(learned, tmp_path):
    _, db = learned
    queries = _places_file(tmp_path / "q.jsonl", [f"q{i}" for i in range(4000)], repeat=3)
    out = tmp_path / "out.json"
    env = {**os.environ, "PYTHONPATH": SRC}
    proc = subprocess.Popen([*CMD, "localize", str(queries), "--db", str(db), "--json", str(out), "-q"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    deadline = time.monotonic() + 120
    while not [f for f in tmp_path.iterdir() if f.name.startswith("out.json.")] and time.monotonic() < deadline:
        if proc.poll() is not None:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    lines = err.decode().strip().splitlines()
    assert proc.returncode == 130 and len(lines) == 1 and "interrupted" in lines[0], err.decode()
    assert not out.exists()
    _no_tmp(tmp_path)


def test_a_full_tmpfs_while_learning_leaves_nothing(tmp_path, learned):
    disk = tmp_path / "small"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=48k", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here (not root)")
    try:
        _, src = learned
        db = disk / "p.sqlite"
        db.write_bytes(src.read_bytes())
        before = db.read_bytes()
        more = _places_file(tmp_path / "more.jsonl", [f"m{i}" for i in range(60)])
        line = _one_error(_cli("learn", more, "--db", db))
        assert "no space left" in line
        assert db.read_bytes() == before
        _no_tmp(disk)
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def test_a_name_too_long_is_refused_first_and_a_long_one_works(learned, tmp_path, capsys):
    data, db = learned
    long_ok = tmp_path / ("x" * 248 + ".json")  # its temporary file's name must still fit
    code, _, err = run(capsys, "localize", data, "--db", db, "--json", long_ok, "-q")
    assert code == 0 and long_ok.is_file(), err
    too_long = tmp_path / ("y" * 300 + ".json")
    code, out, err = run(capsys, "localize", data, "--db", db, "--json", too_long, "-q")
    assert code == 2 and out == "" and "--json" in err and "too long" in err and len(err.strip().splitlines()) == 1


def test_a_read_only_file_system_at_the_rename_is_one_line(learned, tmp_path, capsys, monkeypatch):
    _data, src = learned
    db = tmp_path / "p.sqlite"
    db.write_bytes(src.read_bytes())
    before = db.read_bytes()
    real = os.replace

    def read_only(a, b, *args, **kw):
        if str(b) == str(db):
            raise OSError(errno.EROFS, "Read-only file system", str(b))
        return real(a, b, *args, **kw)

    monkeypatch.setattr(os, "replace", read_only)
    more = _places_file(tmp_path / "more.jsonl", ["z"])
    code, _, err = run(capsys, "learn", more, "--db", db)
    lines = err.strip().splitlines()
    assert code == 2 and lines[-1].startswith("error: ") and "read-only file system" in lines[-1], err
    assert db.read_bytes() == before
    _no_tmp(tmp_path)
