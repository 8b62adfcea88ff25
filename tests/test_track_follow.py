"""``fingerloc track - --follow``: a log piped in gives, step for step, the answers of ``track LOG --json``; each
answer is out before the next line is read; trajectories out (TUM, KITTI, ``map --tum``); one-line errors."""

from __future__ import annotations

import gzip
import io
import json
import os
import select
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fingerloc.io.trajectory import read_kitti, read_tum

from ._cli import run_cli
from ._doors import rooms_log_with_doors


@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    """A map of the first loop (the pose filter's tuning skipped for speed; heading model and scan evidence on), and
    the second loop as its own (held-out) log."""
    import fingerloc as fl

    d = tmp_path_factory.mktemp("follow")
    full = rooms_log_with_doors(d / "rooms-corrected.log")
    pm = fl.make_map(fl.read_run(full), fl.Config().with_(calibration={"tune": False, "scan_gamma": 1.0}))
    assert pm.calibration.heading is not None and pm.scan_map is not None
    pm.save(d / "rooms.sqlite")
    text = full.read_text().splitlines()
    body = [ln for ln in text if ln.startswith(("FLASER", "ODOM"))]
    held = d / "held-corrected.log"
    held.write_text("\n".join(text[:2] + body[len(body) // 2 :]) + "\n")
    return d / "rooms.sqlite", held


def _stdin(monkeypatch, data: bytes) -> None:
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BufferedReader(io.BytesIO(data))))


@pytest.mark.parametrize("odometry", [[], ["--odometry-error", "0"]], ids=["simulated-odometry", "exact-odometry"])
def test_a_piped_log_gives_the_answers_of_track_step_for_step(mapped, tmp_path, capsys, monkeypatch, odometry):
    db, held = mapped
    common = ["--db", db, "--filter", "pose", "--seed", "3", *odometry]
    code, _, err = run_cli(capsys, "track", held, *common, "--json", tmp_path / "off.json", "-q")
    assert code == 0, err
    off = json.loads((tmp_path / "off.json").read_text())["steps"]
    _stdin(monkeypatch, gzip.compress(held.read_bytes()))  # as zcat LOG.gz | ..., the gzip stream itself
    code, out, err = run_cli(capsys, "track", "-", *common, "--follow", "--json", tmp_path / "on.json")
    assert code == 0, err
    lines = [json.loads(ln) for ln in out.splitlines()]
    on = json.loads((tmp_path / "on.json").read_text())["steps"]
    assert len(off) == len(on) == len(lines) == 15
    assert [s["best"] for s in on] == [s["best"] for s in off]
    for a, b, c in zip(off, on, lines, strict=True):
        for key in (
            "observed",
            "best",
            "probability",
            "entropy_bits",
            "true",
            "stamp",
            "pose",
            "covariance",
            "posterior",
        ):
            assert a[key] == b[key] == c[key], key
    assert lines[0]["name"] == "stdin:3 FLASER"


def test_trajectories_of_track_and_map(mapped, tmp_path, capsys):
    db, held = mapped
    code, _, err = run_cli(capsys, "track", held, "--db", db, "--filter", "pose", "-q", "--tum", tmp_path / "e.tum",
                           "--kitti", tmp_path / "e.kitti", "--json", tmp_path / "t.json")  # fmt: skip
    assert code == 0, err
    steps = json.loads((tmp_path / "t.json").read_text())["steps"]
    stamps, poses = read_tum(tmp_path / "e.tum")
    np.testing.assert_array_equal(stamps, [s["stamp"] for s in steps])
    np.testing.assert_allclose(poses[:, :2], [s["pose"][:2] for s in steps], rtol=0, atol=1e-12)
    np.testing.assert_allclose(read_kitti(tmp_path / "e.kitti")[:, :2], poses[:, :2], atol=1e-12)
    code, _, err = run_cli(capsys, "map", held, "--db", tmp_path / "m.sqlite", "--tum", tmp_path / "ref.tum",
                           "--no-calibration")  # fmt: skip
    assert code == 0, err
    t_ref, p_ref = read_tum(tmp_path / "ref.tum")
    assert t_ref.size == 15 and p_ref[0, 0] == pytest.approx(1.1)  # the run's own first pose
    assert "wrote 15 poses" in err


def test_track_options_that_do_not_go_with_a_stream(mapped, tmp_path, capsys, monkeypatch):
    db, held = mapped
    for args, msg in [
        (["--map"], "error: --map does not go with standard input ('-')"),
        (["--filter", "places", "--tum", tmp_path / "x.tum"], "error: --tum needs the pose filter (--filter pose)"),
        (["--kind", "bag"], "error: --kind with standard input ('-') must be auto, carmen or jsonl"),
    ]:
        _stdin(monkeypatch, held.read_bytes())
        code, out, err = run_cli(capsys, "track", "-", "--db", db, *args)
        assert code == 2 and out == "" and err.strip().splitlines()[-1].startswith(msg), err
    code, _, err = run_cli(capsys, "track", held, "--db", db, "--idle-timeout", "3")
    assert code == 2 and "--idle-timeout goes with --follow" in err
    assert not (tmp_path / "x.tum").exists()


def test_a_bad_line_in_the_stream(mapped, tmp_path, capsys, monkeypatch):
    db, held = mapped
    text = held.read_text().splitlines()
    text.insert(4, "FLASER 181 1 2 3")
    data = ("\n".join(text) + "\n").encode()
    common = ["--db", db, "--filter", "pose", "--odometry-error", "0"]
    _stdin(monkeypatch, data)
    code, out, err = run_cli(capsys, "track", "-", *common, "--tum", tmp_path / "e.tum")
    assert code == 2 and err.strip().splitlines()[-1] == "error: stdin:5: FLASER line has 5 fields, expected 192"
    assert len(out.splitlines()) == 1 and not (tmp_path / "e.tum").exists()  # the step before the bad line
    _stdin(monkeypatch, data)
    code, out, err = run_cli(capsys, "track", "-", *common, "--skip-bad")
    assert code == 0 and len(out.splitlines()) == 15
    assert "warning: stdin:5: FLASER line has 5 fields, expected 192" in err.splitlines()
    assert "1 bad line(s) skipped" in err


def test_each_answer_is_printed_before_the_next_line_is_read(mapped, tmp_path):
    """The real command in a child process, fed through a pipe one line at a time: the answer to each scan line
    must come out while the next line has not been written yet."""
    db, held = mapped
    exe = Path(sys.executable).with_name("fingerloc")
    proc = subprocess.Popen([str(exe), "track", "-", "--db", str(db), "--filter", "pose", "--odometry-error", "0"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0)  # fmt: skip
    got = []
    try:
        for line in held.read_text().splitlines(keepends=True):
            proc.stdin.write(line.encode())
            proc.stdin.flush()
            if not line.startswith("FLASER"):
                continue
            deadline = time.monotonic() + 60.0
            buf = b""
            while not buf.endswith(b"\n"):
                ready, _, _ = select.select([proc.stdout], [], [], max(0.0, deadline - time.monotonic()))
                assert ready, f"no answer to {line[:30]!r} within 60 s"
                chunk = os.read(proc.stdout.fileno(), 65536)
                assert chunk, proc.stderr.read().decode()[-2000:]
                buf += chunk
            got += [json.loads(x) for x in buf.decode().splitlines()]
            assert len(got) == sum(1 for _ in got)  # one answer per scan line so far, none ahead
        proc.stdin.close()
        assert proc.wait(timeout=60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert len(got) == 15 and [g["step"] for g in got] == list(range(15))


def test_the_stream_stepper_decides_truth_and_observation_per_item(mapped):
    import fingerloc as fl
    from fingerloc.io.stream import StreamItem
    from fingerloc.observation import Observation
    from fingerloc.pipeline.follow import StreamStepper

    db, _ = mapped
    pm = fl.load_map(db)
    calls = []

    class Recorder:
        def step(self, item, **kw):
            calls.append(kw)

    centre = tuple(pm.positions[1])
    on_place = (centre[0] + 0.3, centre[1], 0.0)
    off_place = (centre[0] + 3.0, centre[1] + 3.0, 0.0)
    obs = Observation.from_degrees({"VE": [10.0]})
    items = [
        StreamItem(1, "a", observation=obs.with_label(pm.labels[2]), pose=off_place),  # a label wins
        StreamItem(2, "b", observation=obs, pose=on_place),
        StreamItem(3, "c", observation=obs, pose=off_place),
        StreamItem(4, "d", observation=obs, odometry=(1.0, 2.0, 0.5)),  # no pose: observes, moves by odometry
    ]
    for mode in ("queries", "all"):
        calls.clear()
        stepper = StreamStepper(pm, Recorder(), observe=mode)
        for it in items:
            stepper.step(it)
        assert [c["truth"] for c in calls] == [pm.labels[2], pm.labels[1], None, None]
        assert [c["observe"] for c in calls] == [True, True, mode == "all", True]
        assert calls[3]["odometry"] == (1.0, 2.0, 0.5) and calls[1]["odometry"] == on_place
        assert [c["name"] for c in calls] == ["a", "b", "c", "d"]
