"""The streaming tracker computes the implied headings only where the pose filter uses them (large maps)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import fingerloc as fl
import fingerloc.pipeline.tracker as tracker_module
from fingerloc.map.heading import HeadingModel


@pytest.fixture(scope="module")
def rooms(rooms_log):
    """The rooms map with a heading model (its own calibration found none worth keeping)."""
    run = fl.read_run(rooms_log)
    pm = fl.make_map(run)
    assert pm.calibration is not None
    return run, replace(pm, calibration=replace(pm.calibration, heading=HeadingModel(kappa=8.0, intercept=0.5)))


def _live(pm, run, budget, seed=3):
    tr = pm.tracker(filter="pose", seed=seed)
    tr.heading_budget = budget
    start = pm.runs[0]["n_mapping"]
    return tr, [tr.step(s, odometry=s.pose, stamp=s.timestamp) for s in run.scans[start:]]


def test_offline_and_streaming_use_the_same_heading_places(rooms, monkeypatch):
    run, pm = rooms
    monkeypatch.setattr(tracker_module, "HEADING_ALL_MAX", 0)  # the rule of large maps on the small one
    offline_tr = pm.tracker(filter="pose", seed=3)
    assert offline_tr.heading_budget == (tracker_module.HEADING_NEAR, tracker_module.HEADING_TOP)
    monkeypatch.setattr(fl.PlaceMap, "tracker", _with_budget(fl.PlaceMap.tracker, (1, 1)))
    offline = pm.track(run, filter="pose", seed=3, observe="all", odometry_error=0.0)
    _, live = _live(pm, run, (1, 1))
    assert [a.place for a in live] == [a.place for a in offline.answers]
    np.testing.assert_array_equal(np.array([a.pose for a in live]), np.array([a.pose for a in offline.answers]))
    # with every place's heading the particles weigh otherwise: the rule is in force
    _, every = _live(pm, run, None)
    assert any(a.pose != b.pose for a, b in zip(every, live, strict=True))


def _with_budget(method, budget):
    def tracker(self, **kw):
        tr = method(self, **kw)
        tr.heading_budget = budget
        return tr

    return tracker


def test_heading_places_are_the_places_near_the_particles_and_the_best_rows(rooms, monkeypatch):
    run, pm = rooms
    monkeypatch.setattr(tracker_module, "HEADING_ALL_MAX", 0)
    tr = pm.tracker(filter="pose", seed=1)
    n = len(pm.labels)
    tr.heading_budget = (n, 2)
    start = pm.runs[0]["n_mapping"]
    for s in run.scans[start : start + 5]:
        tr.step(s, odometry=s.pose)
    row = np.linspace(0.0, -5.0, n)[::-1].copy()  # the last two columns rank first
    got = tr.heading_places(row)
    pf = tr.pose_filter
    d = np.hypot(*(pf.particles_[:, None, :2] - pf.centres[None, :, :]).transpose(2, 0, 1))
    within = np.flatnonzero((d <= pf.radius + tracker_module.HEADING_REACH_M).any(axis=0))
    assert set(within.tolist()) <= set(got.tolist())  # a budget of every place: all the near ones
    assert {n - 1, n - 2} <= set(got.tolist())
    tr.heading_budget = (1, 0)
    one = tr.heading_places(row.copy())
    assert one.size == 1 and one[0] in got
    tr.heading_budget = None
    assert tr.heading_places(row.copy()) is None
