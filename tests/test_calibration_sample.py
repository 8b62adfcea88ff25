"""The calibration of a long mapping part on evenly spread stretches of it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.config import Config
from fingerloc.errors import InvalidParameterError
from fingerloc.map.driver import run_pose_filter
from fingerloc.map.filter import fit_likelihood_scale
from fingerloc.map.graph import PlaceGraph
from fingerloc.map.motion import wheel_odometry
from fingerloc.pipeline.calibrate import calibration_windows, tune_pose_filter
from fingerloc.pipeline.calibration import Calibration, HeldOut, held_out_calibration, held_out_rows, held_out_scores
from fingerloc.pipeline.filters import pose_filter_of, pose_tracking, transition_of


@given(st.integers(0, 5000), st.integers(2, 3000), st.integers(1, 9))
@settings(max_examples=200, deadline=None)
def test_stretches_cover_a_short_part_whole_and_a_long_one_evenly(n, max_steps, k):
    w = calibration_windows(n, max_steps, k)
    if n <= max_steps:
        assert w == [(0, n)]
        return
    kk = min(k, max_steps)
    length = max_steps // kk
    assert len(w) == kk
    assert all(b - a == length for a, b in w)
    assert all(0 <= a and b <= n for a, b in w)
    assert all(w[i][1] <= w[i + 1][0] for i in range(len(w) - 1))  # in order, never overlapping
    if kk > 1:
        assert w[0][0] == 0 and w[-1][1] == n
    assert calibration_windows(n, None, k) == [(0, n)]


def test_config_checks_the_sample_settings():
    assert Config().calibration.max_steps == 1000 and Config().calibration.windows == 4
    with pytest.raises(InvalidParameterError, match="max_steps"):
        Config().with_(calibration={"max_steps": 1})
    with pytest.raises(InvalidParameterError, match="windows"):
        Config().with_(calibration={"windows": 0})
    assert Config().with_(calibration={"max_steps": None}).calibration.max_steps is None


def _fit_score(points, y_all):
    """A nearest-mean recogniser over 2-D points: score = -squared distance to each training place's mean."""

    def fit_score(tr, y, te):
        means = np.stack([points[tr][y == j].mean(axis=0) for j in range(int(y.max()) + 1)])
        return -np.sum((points[te][:, None, :] - means[None]) ** 2, axis=2)

    return fit_score


def test_scoring_a_sample_of_rows_gives_those_rows_of_the_full_scoring():
    rng = np.random.default_rng(4)
    n, n_places = 120, 6
    labels = np.repeat(np.arange(n_places), n // n_places)
    rng.shuffle(labels)
    points = rng.normal(size=(n, 2)) + labels[:, None] * 0.7
    fit = _fit_score(points, labels)
    fold = np.arange(n) % 2
    scored = rng.uniform(size=n) < 0.3
    full, _ = held_out_scores(fit, labels, fold, n_places)
    part, y_part = held_out_scores(fit, labels, fold, n_places, scored)
    pos_full, pos_part = held_out_rows(fold), held_out_rows(fold, scored)
    assert pos_part.size == int(scored.sum()) and np.all(scored[pos_part])
    where = {int(p): i for i, p in enumerate(pos_full.tolist())}
    np.testing.assert_array_equal(part, full[[where[int(p)] for p in pos_part.tolist()]])
    np.testing.assert_array_equal(y_part, labels[pos_part])
    h = held_out_calibration(fit, np.arange(n), labels, n_places, by_visits=False, scored=scored)
    assert h.index.tolist() == pos_part.tolist() and h.rows == int(scored.sum())
    assert h.beta == fit_likelihood_scale(part, y_part)
    with pytest.raises(InvalidParameterError, match="scored"):
        held_out_scores(fit, labels, fold, n_places, scored[:-1])


def _run_along(n_places=8, spacing=2.0):
    xs = np.linspace(0, (n_places - 1) * spacing, (n_places - 1) * 6 + 1)
    poses = np.column_stack([np.concatenate([xs, xs[::-1]]), np.zeros(2 * xs.size), np.concatenate([np.zeros(xs.size), np.full(xs.size, np.pi - 1e-9)])])
    centres = np.column_stack([np.arange(n_places) * spacing, np.zeros(n_places)])
    truth = np.argmin(np.abs(poses[:, :1] - centres[None, :, 0]), axis=1)
    rows = np.flatnonzero(np.abs(poses[:, 0] - centres[truth, 0]) < 0.6)
    rng = np.random.default_rng(7)
    scores = 0.8 * rng.standard_normal((rows.size, n_places))
    scores[np.arange(rows.size), truth[rows]] += 2.0
    g = PlaceGraph.from_sequence([str(i) for i in range(n_places)], [str(i) for i in truth[rows]])
    held = HeldOut(beta=1.0, rows=rows.size, scores=scores, labels=truth[rows], index=np.arange(rows.size))
    return poses, centres, rows, held, g


def test_tuning_on_stretches_pools_the_top1_of_separate_runs():
    poses, centres, rows, held, g = _run_along()
    cal = Calibration(radius=0.6, kidnap=0.02, metres_per_move=2.0)
    cfg = Config().with_(pose_filter={"n_particles": 200}, calibration={"outliers": (0.1,), "temper_m": (2.0,)})
    wins = [(0, 30), (45, 80)]
    chosen, tried = tune_pose_filter(cal, cfg, centres, g, held, rows, poses, odometry_error=1.0, seed=1, windows=wins)
    again, tried_b = tune_pose_filter(cal, cfg.with_(calibration={"share_draws": False}), centres, g, held, rows, poses,
                                      odometry_error=1.0, seed=1, windows=wins)  # fmt: skip
    assert (chosen, tried) == (again, tried_b)  # one record of draws a stretch: the same runs
    # the oracle: each pair's runs made here, one a stretch from a fresh filter, pooled by hand
    ll = np.full((poses.shape[0], centres.shape[0]), np.nan)
    ll[rows] = held.scores
    inc = np.vstack([np.zeros((1, 3)), wheel_odometry(poses, 1.0, random_state=3)])
    fitted = [t for t in tried]
    assert len(fitted) == 2  # rho 0.1 and the fitted reliability, one tempering
    for t in fitted:
        trial = replace(cal, outlier=t["outlier"], temper_metres=t["temper_metres"], scan_gamma=0.0)
        right = counted = 0
        for a, b in wins:
            f = pose_filter_of(centres, trial, cfg, seed=3)
            res = run_pose_filter(ll[a:b], inc[a:b], pose_tracking(f, transition_of(g, trial, cfg), trial, cfg))
            mine = (rows >= a) & (rows < b)
            right += int(np.sum(res.best[rows[mine] - a] == held.labels[mine]))
            counted += int(mine.sum())
        assert t["top1"] == right / counted
    whole, _ = tune_pose_filter(cal, cfg, centres, g, held, rows, poses, odometry_error=1.0, seed=1)
    one, _ = tune_pose_filter(cal, cfg, centres, g, held, rows, poses, odometry_error=1.0, seed=1, windows=[(0, poses.shape[0])])
    assert one == whole


def test_a_long_mapping_part_is_calibrated_on_its_stretches_end_to_end(tmp_path, monkeypatch):
    """``make_map`` with a mapping part beyond ``max_steps``: only the stretches' views are held out, and the map tracks."""
    import fingerloc as fl
    import fingerloc.pipeline.calibrate as calibrate_module

    from ._runs import walk, write_carmen

    run = fl.read_run(write_carmen(tmp_path / "walk-corrected.log", walk(passes=8)))  # 96 steps, 48 mapping
    seen = []
    real = calibrate_module.held_out_calibration

    def spy(fit_score, train_idx, labels, n_places, **kw):
        seen.append((np.asarray(train_idx).copy(), kw.get("scored")))
        return real(fit_score, train_idx, labels, n_places, **kw)

    monkeypatch.setattr(calibrate_module, "held_out_calibration", spy)
    whole = fl.make_map(run)
    sample = fl.make_map(run, Config().with_(calibration={"max_steps": 24, "windows": 2}))
    assert seen[0][1] is None  # 48 steps <= 1,000: all of it
    idx, scored = seen[1]
    assert scored is not None and 0 < scored.sum() < scored.size
    wins = calibration_windows(48, 24, 2)
    assert wins == [(0, 12), (36, 48)]
    inside = np.zeros(idx.size, dtype=bool)
    for a, b in wins:
        inside |= (idx >= a) & (idx < b)
    np.testing.assert_array_equal(scored, inside)
    assert 0 < sample.calibration.calibration_rows < whole.calibration.calibration_rows
    assert sample.calibration.place_filter_top1 is not None
    assert sample.track(run, filter="pose").summary["filtered"]["top1"] >= 0.9
