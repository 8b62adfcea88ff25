"""The followed stream of ``track --follow``: one JSON line per step, written before the next line is read;
trajectories put in place at the end; bad lines; Ctrl-C keeps what was tracked."""

from __future__ import annotations

import io
import json
import threading

import numpy as np
import pytest

from fingerloc.cli._follow import follow_track
from fingerloc.errors import DataFormatError, InvalidParameterError
from fingerloc.io.trajectory import read_kitti, read_tum

from ._live import StandInTracker
from ._logs import rooms_path


def stepper(tracker):
    return lambda it: tracker.step(it.item, odometry=it.pose, stamp=it.stamp)


class Lines(io.StringIO):
    """An output stream that signals each complete line."""

    def __init__(self):
        super().__init__()
        self.lines: list[str] = []
        self.cond = threading.Condition()

    def write(self, s):
        with self.cond:
            self.lines += [ln for ln in s.splitlines() if ln]
            self.cond.notify_all()
        return len(s)


def test_every_step_is_one_json_line_and_the_trajectories_are_written(rooms_log, tmp_path):
    out = Lines()
    tracker = StandInTracker()
    res = follow_track(
        rooms_log, stepper(tracker), follow=False, tum=tmp_path / "e.tum", kitti=tmp_path / "e.kitti", out=out
    )
    n = len(rooms_path())
    assert len(res.answers) == len(out.lines) == n and res.ended == "end of input"
    recs = [json.loads(ln) for ln in out.lines]
    assert [r["best"] for r in recs] == [a.place for a in tracker.steps]
    assert [r["step"] for r in recs] == list(range(n))
    stamps, poses = read_tum(tmp_path / "e.tum")
    np.testing.assert_array_equal(stamps, [a.stamp for a in tracker.steps])
    np.testing.assert_allclose(poses[:, :2], [a.pose[:2] for a in tracker.steps], atol=1e-12)
    assert read_kitti(tmp_path / "e.kitti").shape == (n, 3)


def test_each_answer_is_out_before_the_next_line_is_written(rooms_log, tmp_path):
    lines = rooms_log.read_text().splitlines(keepends=True)
    path = tmp_path / "growing.log"
    path.write_text("")
    out = Lines()
    result = {}

    def track():
        result["res"] = follow_track(path, stepper(StandInTracker()), follow=True, idle_timeout=2.0, out=out)

    th = threading.Thread(target=track)
    th.start()
    seen = 0
    with open(path, "a") as fh:
        for ln in lines:
            fh.write(ln)
            fh.flush()
            if ln.startswith("FLASER"):
                seen += 1
                with out.cond:  # the answer to this line comes before the next line exists
                    assert out.cond.wait_for(lambda n=seen: len(out.lines) >= n, timeout=10.0), (
                        f"no answer to step {seen}"
                    )
    th.join(timeout=20.0)
    assert not th.is_alive() and len(result["res"].answers) == seen == len(rooms_path())


def test_a_bad_line_stops_the_stream_and_leaves_no_trajectory(rooms_log, tmp_path):
    text = rooms_log.read_text().splitlines()
    text.insert(5, "FLASER 3 1 2")
    bad = tmp_path / "bad.log"
    bad.write_text("\n".join(text) + "\n")
    (tmp_path / "e.tum").write_text("old\n")
    with pytest.raises(DataFormatError, match=r"bad\.log:6: FLASER line has 4 fields"):
        follow_track(bad, stepper(StandInTracker()), follow=False, tum=tmp_path / "e.tum", out=Lines())
    assert (tmp_path / "e.tum").read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.log", "e.tum"]
    warnings = []
    res = follow_track(bad, stepper(StandInTracker()), follow=False, skip_bad=True, warn=warnings.append, out=Lines())
    assert res.skipped == 1 and len(res.answers) == len(rooms_path())
    assert warnings == [f"warning: {bad}:6: FLASER line has 4 fields, expected 14"]


def test_interrupting_the_stream_keeps_what_was_tracked(rooms_log, tmp_path):
    class Interrupting(StandInTracker):
        def step(self, item=None, odometry=None, stamp=None):
            if len(self.steps) == 4:
                raise KeyboardInterrupt
            return super().step(item, odometry=odometry, stamp=stamp)

    res = follow_track(rooms_log, stepper(Interrupting()), follow=False, tum=tmp_path / "e.tum", out=Lines())
    assert res.ended == "interrupted" and len(res.answers) == 4
    assert read_tum(tmp_path / "e.tum")[0].size == 4


def test_outputs_are_checked_before_reading(tmp_path, rooms_log):
    with pytest.raises(InvalidParameterError, match="--tum"):
        follow_track(
            rooms_log, stepper(StandInTracker()), follow=False, tum=tmp_path / "missing" / "e.tum", out=Lines()
        )
    with pytest.raises(InvalidParameterError, match="--idle-timeout"):
        follow_track(rooms_log, stepper(StandInTracker()), idle_timeout=0.0, out=Lines())
