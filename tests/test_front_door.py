"""The library's front door gives what the command line gives: read_run, make_map, save / load_map, localize, track.

The command line parses options and calls these functions; a Python user
calling them with the same run and seed gets the same summaries. The fast
test runs on the synthetic rooms log; the slow one on a shared CARMEN log
(``pytest -m slow``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fingerloc as fl

from ._cli import run_cli

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "carmen"


def _cli_and_library(log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, object]:
    db, loc, trk = tmp_path / "cli.sqlite", tmp_path / "loc.json", tmp_path / "trk.json"
    for args in (("map", log, "--db", db), ("localize", log, "--db", db, "--json", loc, "-q"),
                 ("track", log, "--db", db, "--filter", "pose", "--json", trk, "-q")):  # fmt: skip
        code, _, err = run_cli(capsys, *args)
        assert code == 0, err
    run = fl.read_run(log)
    pm = fl.make_map(run)
    pm.save(tmp_path / "lib.sqlite")
    back = fl.load_map(tmp_path / "lib.sqlite")
    return {
        "cli_localize": json.loads(loc.read_text())["summary"],
        "cli_track": json.loads(trk.read_text())["summary"],
        "cli_steps": json.loads(trk.read_text())["steps"],
        "localize": back.localize(run).summary,
        "track": back.track(run, filter="pose"),
        "fresh_track": pm.track(run, filter="pose").summary,
        "db_bytes": ((tmp_path / "cli.sqlite").read_bytes(), (tmp_path / "lib.sqlite").read_bytes()),
    }


def test_the_front_door_gives_the_command_line_figures(rooms_log, tmp_path, capsys):
    out = _cli_and_library(rooms_log, tmp_path, capsys)
    assert out["localize"] == out["cli_localize"] and out["localize"]["top1"] is not None
    tr = out["track"]
    assert isinstance(tr, fl.TrackResult)
    assert tr.summary == out["cli_track"] == out["fresh_track"]
    assert tr.summary["filter"] == "pose" and tr.summary["filtered"]["labelled"] > 0
    assert [a.place for a in tr.answers] == [s["best"] for s in out["cli_steps"]]
    assert out["db_bytes"][0] == out["db_bytes"][1]  # the same database, byte for byte


def test_track_is_the_streaming_tracker_one_step_at_a_time(rooms_log):
    """Offline ``track`` = a loop of ``Tracker.step`` on the raw scans (same seed): the same answers and poses."""
    run = fl.read_run(rooms_log)
    pm = fl.make_map(run)
    offline = pm.track(run, filter="pose", seed=3, odometry_error=0.0)
    tracker = pm.tracker(filter="pose", seed=3)
    start = pm.runs[0]["n_mapping"]
    queried = {a.name for a in offline.answers if a.observed}
    live = [
        tracker.step(s, odometry=s.pose, stamp=s.timestamp, observe=name in queried, name=name)
        for s, name in zip(run.scans[start:], run.names[start:], strict=True)
    ]
    assert [a.place for a in live] == [a.place for a in offline.answers]
    np.testing.assert_array_equal(np.array([a.pose for a in live]), np.array([a.pose for a in offline.answers]))
    np.testing.assert_array_equal(np.vstack([a.log_posterior for a in live]), offline.result.log_posterior)
    a = live[-1]
    assert a.stamp == run.scans[-1].timestamp and a.pose is not None and len(a.covariance) == 3
    assert a.posterior[0][0] == a.place and a.latency_s > 0
    rec = a.to_json()
    assert {"step", "name", "observed", "best", "probability", "entropy_bits", "true", "stamp", "pose"} <= set(rec)


def test_the_place_filter_tracks_without_poses(rooms_log):
    run = fl.read_run(rooms_log)
    pm = fl.make_map(run)
    tr = pm.tracker(filter="places")
    first = tr.step(run.scans[-1])
    assert first.pose is None and first.observed and 0 < first.probability <= 1
    assert tr.step().observed is False  # prediction only


@pytest.mark.slow
def test_the_front_door_on_a_shared_log(tmp_path, capsys):
    log = SHARED / "aces-corrected.log.gz"
    if not log.exists():
        pytest.skip(f"no shared log at {log}")
    out = _cli_and_library(log, tmp_path, capsys)
    assert out["localize"] == out["cli_localize"]
    assert out["track"].summary == out["cli_track"]
