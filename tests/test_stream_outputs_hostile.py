"""Hostile input and faults on the streaming and trajectory surfaces: ``track -`` / ``--follow`` (a closed
standard input, a FIFO, a line without end, no ``--filter``), ``--tum`` / ``--kitti`` (devices, FIFOs, a fault
while writing: nothing written, nothing left), ``map --places fingerprints`` on degenerate runs, ``features
--labels`` with a bad CSV, ``bench loops`` on a log without a true match."""

from __future__ import annotations

import errno
import io
import os
import sys
import threading
from pathlib import Path

import pytest

import fingerloc.io.stream as stream
from fingerloc.atomic import OutputGroup
from fingerloc.errors import DataFormatError, InvalidParameterError
from fingerloc.io.labels import read_labels
from fingerloc.io.trajectory import TrajectoryWriter

from ._cli import run_cli
from ._doors import rooms_log_with_doors


@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    """A map made from poses (the pose filter's tuning skipped for speed) and its log."""
    import fingerloc as fl

    d = tmp_path_factory.mktemp("streams")
    log = rooms_log_with_doors(d / "rooms-corrected.log")
    fl.make_map(fl.read_run(log), fl.Config().with_(calibration={"tune": False})).save(d / "rooms.sqlite")
    return d / "rooms.sqlite", log


def _one_error(code: int, err: str) -> str:
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) >= 1 and lines[-1].startswith("error: "), err
    return lines[-1]


def _no_tmp(folder: Path) -> None:
    assert not [f.name for f in folder.iterdir() if f.name.endswith(".tmp")]


# -- streams ------------------------------------------------------------------------------------------


def test_a_closed_standard_input_is_one_error(monkeypatch):
    monkeypatch.setattr(sys, "stdin", None)  # as after `<&-`
    with pytest.raises(InvalidParameterError, match=r"standard input .* is closed"):
        stream.open_lines("-")


def test_a_line_without_end_is_refused_with_bounded_memory(monkeypatch, tmp_path):
    monkeypatch.setattr(stream, "MAX_LINE_BYTES", 1000)
    fh = io.BufferedReader(io.BytesIO(b"FLASER 1 2 3\n" + b"\0" * 50_000))
    with pytest.raises(DataFormatError, match="line 2 is longer than 1,000 bytes"):
        list(stream.open_lines("-", stdin=fh))
    grown = tmp_path / "grown.log"
    grown.write_bytes(b"x" * 5000)
    with pytest.raises(DataFormatError, match="line 1 is longer than 1,000 bytes"):
        list(stream.follow_lines(grown, poll_s=0.01, idle_timeout_s=5.0))


def test_following_a_fifo_ends_when_its_writer_closes(tmp_path):
    fifo = tmp_path / "log.fifo"
    os.mkfifo(fifo)

    def feed() -> None:
        with open(fifo, "wb") as fh:
            fh.write(b"a\nb\nc\n")

    got: list[tuple[int, str]] = []
    writer = threading.Thread(target=feed, daemon=True)
    reader = threading.Thread(target=lambda: got.extend(stream.open_lines(fifo, follow=True)), daemon=True)
    writer.start()
    reader.start()
    reader.join(timeout=20)
    assert not reader.is_alive(), "following a FIFO did not end when its writer closed it"
    assert got == [(1, "a\n"), (2, "b\n"), (3, "c\n")]


def test_a_stream_without_filter_picks_one_and_a_bad_line_is_one_error(mapped, capsys, monkeypatch):
    db, log = mapped
    head = b"".join(log.read_bytes().splitlines(keepends=True)[:24])
    bad = head + b"FLASER many 1 2\n"
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BufferedReader(io.BytesIO(bad))))
    code, out, err = run_cli(capsys, "track", "-", "--db", db, "--skip-bad")
    assert code == 0, err
    assert "filter: pose" in err and "1 bad line(s) skipped" in err and len(out.splitlines()) >= 5
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BufferedReader(io.BytesIO(bad))))
    code, _, err = run_cli(capsys, "track", "-", "--db", db, "-q")
    assert "beam count must be an integer" in _one_error(code, err)


# -- trajectories -------------------------------------------------------------------------------------


def test_a_trajectory_writer_refuses_a_fifo_and_a_device(tmp_path):
    fifo = tmp_path / "t.fifo"
    os.mkfifo(fifo)
    with pytest.raises(InvalidParameterError, match="FIFO"):
        TrajectoryWriter(fifo, "tum")
    with pytest.raises(InvalidParameterError, match="character device"):
        TrajectoryWriter("/dev/full", "kitti")
    assert fifo.is_fifo()
    _no_tmp(tmp_path)


def test_a_trajectory_in_a_failed_output_group_is_not_written(tmp_path):
    out = tmp_path / "t.kitti"
    out.write_text("old\n")
    with pytest.raises(RuntimeError), OutputGroup():
        with TrajectoryWriter(out, "kitti") as w:
            w.add((1.0, 2.0, 0.5))
        raise RuntimeError("a later output failed")
    assert out.read_text() == "old\n"
    _no_tmp(tmp_path)


@pytest.mark.parametrize("flag", ["--tum", "--kitti"])
def test_a_fault_while_writing_a_trajectory_leaves_every_output_as_it_was(mapped, tmp_path, capsys, monkeypatch, flag):
    db, log = mapped
    before = db.read_bytes()
    js, traj = tmp_path / "t.json", tmp_path / "t.traj"
    js.write_text("old json\n")

    def full(self, pose, stamp=None):
        raise OSError(errno.ENOSPC, "No space left on device", str(traj))

    monkeypatch.setattr(TrajectoryWriter, "add", full)
    code, _, err = run_cli(capsys, "track", log, "--db", db, "--filter", "pose", "-q", "--json", js, flag, traj)
    assert "no space left" in _one_error(code, err)
    assert js.read_text() == "old json\n" and not traj.exists() and db.read_bytes() == before
    _no_tmp(tmp_path)


@pytest.mark.parametrize("bad", ["fifo", "dir", "full"])
def test_a_bad_trajectory_target_is_refused_before_any_write(mapped, tmp_path, capsys, bad):
    db, log = mapped
    target = {"fifo": tmp_path / "t.fifo", "dir": tmp_path, "full": Path("/dev/full")}[bad]
    if bad == "fifo":
        os.mkfifo(target)
    js = tmp_path / "t.json"
    code, out, err = run_cli(capsys, "track", log, "--db", db, "--filter", "pose", "--json", js, "--kitti", target)
    assert "--kitti" in _one_error(code, err) and len(err.strip().splitlines()) == 1 and out == ""
    assert not js.exists()
    _no_tmp(tmp_path)


# -- maps from fingerprints, bench loops --------------------------------------------------------------


def _log(path: Path, lines: list[str]) -> Path:
    path.write_text("PARAM robot_front_laser_max 30 nohost 0\n" + "\n".join(lines) + "\n")
    return path


def test_map_from_fingerprints_refuses_a_run_without_returns_and_warns_on_a_stationary_one(tmp_path, capsys):
    nan = _log(tmp_path / "nan.log", [f"FLASER 5 nan nan nan nan nan {k} 0 0 0 0 0 {k}.0 h {k}.0" for k in range(8)])
    code, _, err = run_cli(capsys, "map", nan, "--db", tmp_path / "n.sqlite", "--places", "fingerprints")
    assert "nothing to map" in _one_error(code, err) and not (tmp_path / "n.sqlite").exists()
    ranges = " ".join(["2.0", "3.0", "2.5", "4.0", "1.5"] * 36 + ["2.0"])
    still = _log(tmp_path / "still.log", [f"FLASER 181 {ranges} 1 1 0 1 1 0 {k}.0 h {k}.0" for k in range(20)])
    code, _, err = run_cli(capsys, "map", still, "--db", tmp_path / "s.sqlite", "--places", "fingerprints",
                           "--tum", tmp_path / "s.tum")  # fmt: skip
    assert code == 0, err
    assert "warning: " in err and "stationary" in err and "1 place" in err
    assert len((tmp_path / "s.tum").read_text().splitlines()) == 20  # --tum is written here too


def test_bench_loops_warns_about_a_log_without_a_true_match(tmp_path, capsys):
    ranges = " ".join(["2.0", "3.0", "2.5", "4.0", "1.5"] * 36 + ["2.0"])
    straight = _log(tmp_path / "line.log", [f"FLASER 181 {ranges} {k} 0 0 {k} 0 0 {k}.0 h {k}.0" for k in range(12)])
    code, _, err = run_cli(capsys, "bench", "loops", straight, "--no-places", "-m", "baseline-histogram")
    assert code == 0, err
    assert "warning: line: no query has a true match" in err


# -- labels CSV ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (b"name,room\np.png,a\n", "must name the columns file and place"),
        (b"file,place\np.png,a\np.png,b\n", "listed twice"),
        (b"file,place\np.png,caf\xe9\n", "not UTF-8"),
        (b"file,place\np.png,a\x00b\n", "NUL"),
        (b"file,place\np.png," + b"x" * 200_000 + b"\n", "not a CSV row"),
        (b"", "empty"),
    ],
    ids=["missing-columns", "duplicate-rows", "latin-1", "nul-bytes", "huge-field", "empty"],
)
def test_a_bad_labels_csv_is_one_error_naming_the_line(tmp_path, content, needle):
    p = tmp_path / "labels.csv"
    p.write_bytes(content)
    with pytest.raises(DataFormatError, match=needle):
        read_labels(p)


def test_a_labels_csv_with_a_bom_reads_and_an_endless_one_is_refused(tmp_path, monkeypatch):
    p = tmp_path / "labels.csv"
    p.write_bytes(b"\xef\xbb\xbffile,place\r\na.png,hall\r\n")
    assert [(r.file, r.place) for r in read_labels(p)] == [("a.png", "hall")]
    import fingerloc.io.labels as labels

    monkeypatch.setattr(labels, "MAX_LABELS_BYTES", 4096)
    with pytest.raises(DataFormatError, match="larger than 4,096 bytes"):
        read_labels("/dev/zero")


def test_features_with_labels_that_miss_a_photo_is_one_error(tmp_path, capsys):
    from PIL import Image

    for name in ("p1.png", "p2.png"):
        Image.new("RGB", (64, 16), (90, 90, 90)).save(tmp_path / name)
    (tmp_path / "labels.csv").write_text("file,place\np1.png,a\n")
    out = tmp_path / "o.jsonl"
    code, _, err = run_cli(capsys, "features", tmp_path / "p1.png", tmp_path / "p2.png", "--labels",
                           tmp_path / "labels.csv", "--json", out)  # fmt: skip
    assert "no row names it" in _one_error(code, err) and not out.exists()
