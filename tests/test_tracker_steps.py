"""The streaming tracker: implied headings only where the pose filter uses them (large maps), the pose of the answered mode."""

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


def test_the_pose_is_the_mode_of_the_answered_place_and_the_covariance_its_error_under_the_whole_belief():
    from fingerloc.pipeline.tracker import _pose_estimate

    rng = np.random.default_rng(4)
    here = np.column_stack([rng.normal(1.0, 0.2, 300), rng.normal(2.0, 0.2, 300), rng.normal(0.3, 0.05, 300)])
    there = np.column_stack([rng.normal(9.0, 0.2, 200), rng.normal(2.0, 0.2, 200), rng.normal(-2.0, 0.05, 200)])
    parts = np.vstack([here, there])
    lw = np.log(rng.uniform(0.5, 1.5, parts.shape[0]))
    w = np.exp(lw) / np.exp(lw).sum()
    (x, y, th), cov = _pose_estimate(parts, lw, centre=(1.5, 2.0), reach=2.0)
    wh = w[:300] / w[:300].sum()
    np.testing.assert_allclose([x, y], wh @ here[:, :2], atol=1e-12)
    assert abs(th - np.arctan2(wh @ np.sin(here[:, 2]), wh @ np.cos(here[:, 2]))) < 1e-12
    d = parts - np.array([x, y, th])
    d[:, 2] = (d[:, 2] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(np.array(cov), (d * w[:, None]).T @ d, atol=1e-12)
    assert cov[0][0] > 10.0  # the other mode, 8 m away, is in the covariance
    (xa, ya, _), _ = _pose_estimate(parts, lw)  # without a place: every particle's mean, between the two
    np.testing.assert_allclose([xa, ya], w @ parts[:, :2], atol=1e-12)
    (xn, _, _), _ = _pose_estimate(parts, lw, centre=(50.0, 50.0), reach=2.0)  # nothing near: every particle
    assert xn == xa


def test_a_steps_row_and_headings_are_those_of_many_observations(rooms):
    """The tracker's per-step likelihood row and implied headings (one observation: one model call over every
    place, the lookups kept across steps) equal the rows of ``posterior_columns`` and ``implied_headings`` over
    many observations at once (the map's calibration and offline ``track``), at every place and on a subset."""
    from fingerloc.features.laser import observation_from_scan
    from fingerloc.pipeline.calibration import implied_headings, posterior_columns

    run, pm = rooms
    tr = pm.tracker(filter="pose", seed=0)
    n = len(pm.labels)
    rng = np.random.default_rng(4)
    scans = run.scans[pm.runs[0]["n_mapping"] :: 7]
    many = [observation_from_scan(s, **tr.features) for s in scans]
    rows = posterior_columns(pm.model, many, n, pm.labels)
    every = implied_headings(pm.model, many, pm.labels)
    for i, obs in enumerate(many):
        np.testing.assert_array_equal(tr.columns.posterior([obs]), rows[i : i + 1])
        np.testing.assert_array_equal(tr.columns.headings([obs])[0], every[i])
        cols = rng.choice(n, size=max(1, n // 3), replace=False)
        want = implied_headings(pm.model, [obs, many[(i + 1) % len(many)]], pm.labels, cols)[0]
        np.testing.assert_array_equal(tr.columns.headings([obs], cols)[0], want)
        assert np.isfinite(want).any()
