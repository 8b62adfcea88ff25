"""The observation's heading in the pose filter: HeadingModel, its fit, the filter's use of it."""

import math

import numpy as np
import pytest
from scipy.special import i0e, logsumexp

from fingerloc.angles import wrap
from fingerloc.errors import InvalidParameterError
from fingerloc.map.driver import run_pose_filter
from fingerloc.map.heading import HeadingModel, fit_heading_model
from fingerloc.map.motion import odometry_increments
from fingerloc.map.pose_filter import PoseFilter
from fingerloc.pipeline.calibration import Calibration

from ._paths import polyline, sensor_scores, truth_places

GRID = np.array([(x, y) for x in range(0, 14, 2) for y in range(0, 14, 2)], dtype=float)
CORRIDOR = np.array([(2.0 * k, 0.0) for k in range(20)])


def _mean_heading(f):
    return math.atan2(float(np.sin(f.particles_[:, 2]).mean()), float(np.cos(f.particles_[:, 2]).mean()))


def test_heading_model_is_a_density_and_its_fit_recovers_it():
    hm = HeadingModel(kappa=40.0, intercept=1.0, slope=1.0, reverse=0.2, cap=0.9)
    grid = np.linspace(-math.pi, math.pi, 4000, endpoint=False)
    for x in (0.0, -2.0, -10.0):
        # 2 pi f integrates to 2 pi: the mean factor over the circle is 1
        assert np.mean(np.exp(hm.log_factor(grid, x))) == pytest.approx(1.0, abs=1e-6)
        assert float(hm.log_mean_tempered(1.0, x)) == 0.0
        assert float(hm.log_mean_tempered(0.5, x)) < 0.0  # Jensen
    assert float(hm.peak_share(0.0)) > float(hm.peak_share(-3.0))
    rng = np.random.default_rng(0)
    n = 3000
    x = rng.uniform(-6.0, 0.0, n)
    right = rng.uniform(size=n) < hm.peak_share(x)
    flip = rng.uniform(size=n) < hm.reverse
    delta = np.where(right, wrap(np.where(flip, math.pi, 0.0) + rng.vonmises(0.0, hm.kappa, n)), rng.uniform(-math.pi, math.pi, n))
    fit = fit_heading_model(delta, x, cap=0.9)
    assert fit is not None
    assert fit.kappa == pytest.approx(40.0, rel=0.2)
    assert fit.reverse == pytest.approx(0.2, abs=0.05)
    assert fit.slope == pytest.approx(1.0, abs=0.4)
    assert fit_heading_model(delta[:5]) is None  # too few errors: no heading evidence
    s = hm.sample(np.zeros(n), rng, x)
    assert np.all(np.abs(s) <= math.pi)


def test_bad_heading_inputs_are_refused():
    with pytest.raises(InvalidParameterError):
        HeadingModel(kappa=0.0)
    with pytest.raises(InvalidParameterError):
        HeadingModel(reverse=1.5)
    with pytest.raises(InvalidParameterError):
        PoseFilter(GRID, 1.0, heading="yes")  # type: ignore[arg-type]
    f = PoseFilter(GRID, 1.0, n_particles=50, heading=HeadingModel())
    with pytest.raises(InvalidParameterError):
        f.update(np.zeros(GRID.shape[0]), headings=np.zeros(3))
    with pytest.raises(InvalidParameterError):
        f.update(np.zeros(GRID.shape[0]), headings=np.full(GRID.shape[0], np.inf))
    assert Calibration().heading is None  # off by default
    on = Calibration.from_json({"heading_kappa": 30.0, "heading_intercept": 2.0, "heading_cap": 0.9}).heading
    assert on == HeadingModel(30.0, 2.0, 0.0, 0.0, 0.9)


def test_without_a_heading_model_headings_change_nothing():
    path = polyline([(0, 0), (12, 0), (12, 6)], 0.5)
    truth = truth_places(path, GRID)
    ll = sensor_scores(truth, GRID.shape[0], 2.0, 0)
    hd = np.where(np.isnan(ll), np.nan, 0.3)
    a = run_pose_filter(ll, odometry_increments(path), PoseFilter(GRID, 1.0, n_particles=300, random_state=1), temper=(2.0, math.pi))
    b = run_pose_filter(ll, odometry_increments(path), PoseFilter(GRID, 1.0, n_particles=300, random_state=1), temper=(2.0, math.pi), headings=hd)
    assert np.array_equal(a.log_posterior, b.log_posterior)


def test_one_update_weighs_particles_by_the_heading_by_hand():
    hm = HeadingModel(kappa=20.0, intercept=0.0, slope=0.0, cap=0.8)
    centres = np.array([[0.0, 0.0], [10.0, 0.0]])
    f = PoseFilter(centres, 1.0, n_particles=10, kidnap=0.0, outlier=0.0, heading=hm, random_state=0)
    f.particles_ = np.array([[0.0, 0.0, 0.0]] * 5 + [[0.0, 0.0, math.pi]] * 5)
    f.log_weights_ = np.full(10, -math.log(10))
    row = np.array([0.0, -50.0])
    # both halves at place 0: the place posterior stays place 0, the particles facing the implied heading win
    f.update(row, 1.0, headings=np.array([0.0, np.nan]))
    share = float(np.mean(np.abs(f.particles_[:, 2]) < 1.0))
    g = 0.8 * 0.5
    x0 = math.exp(float(hm.log_factor(0.0, row[0] - logsumexp(row))))
    xpi = math.exp(float(hm.log_factor(math.pi, row[0] - logsumexp(row))))
    assert x0 == pytest.approx(g / float(i0e(20.0)) + (1 - g))  # 2 pi vM(0) = 1 / i0e(kappa)
    assert share == pytest.approx(x0 / (x0 + xpi), abs=0.1 + 1e-9)
    assert share >= 0.8


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_heading_evidence_corrects_an_odometry_heading_drift(seed):
    """The odometry turns 0.04 rad (2.3 deg) too much every 0.5 m; the sensor barely knows the place.

    Without the heading evidence the particles follow the drifting odometry
    off the route (none right in the second half); with the heading the
    view implies at the true place (3 deg of noise) they keep the true
    heading and the place.
    """
    rng = np.random.default_rng(seed)
    path = polyline([(0, 0), (12, 0), (12, 12), (0, 12), (0, 2)], 0.5)
    truth = truth_places(path, GRID)
    q = truth >= 0
    inc = odometry_increments(path)
    inc[:, 2] += 0.04
    ll = sensor_scores(truth, GRID.shape[0], 0.5, seed)
    hd = np.full(ll.shape, np.nan)
    hd[q, truth[q]] = wrap(path[q, 2] + math.radians(3) * rng.standard_normal(int(q.sum())))
    half = np.arange(truth.size) >= truth.size // 2
    top1, err = {}, {}
    for use in (False, True):
        hm = HeadingModel(kappa=200.0, intercept=3.0, cap=0.9) if use else None
        f = PoseFilter(GRID, 1.0, n_particles=500, kidnap=0.001, start=path[:1], heading=hm, random_state=seed)
        res = run_pose_filter(ll, inc, f, temper=(2.0, math.pi), headings=hd)
        top1[use] = float(np.mean(res.best[q & half] == truth[q & half]))
        err[use] = abs(float(wrap(_mean_heading(f) - path[-1, 2])))
    assert top1[False] <= 0.3 and err[False] >= 1.0  # the drift, kept visible
    assert top1[True] >= 0.9
    assert err[True] <= 0.35


@pytest.mark.parametrize("seed", [0, 1])
def test_particles_going_the_wrong_way_down_a_corridor_die_at_the_first_observation(seed):
    """Started from the first observation (any heading), half the particles face the wrong way; the implied heading kills them."""
    path = polyline([(9, 0), (21, 0)], 0.5)
    truth = truth_places(path, CORRIDOR)
    ll = sensor_scores(truth, CORRIDOR.shape[0], 3.0, seed)
    hd = np.full(ll.shape, np.nan)
    first = int(np.flatnonzero(truth >= 0)[0])
    hd[first, truth[first]] = path[first, 2]
    ok = {}
    for use in (False, True):
        hm = HeadingModel(kappa=100.0, intercept=3.0, cap=0.95) if use else None
        f = PoseFilter(CORRIDOR, 1.0, n_particles=1000, heading=hm, random_state=seed)
        run_pose_filter(ll[: first + 1], odometry_increments(path[: first + 1]), f, start_at_first_observation=True, headings=hd[: first + 1])
        at = np.hypot(f.particles_[:, 0] - CORRIDOR[truth[first], 0], f.particles_[:, 1]) <= 1.0
        ok[use] = float(np.mean(np.abs(wrap(f.particles_[at, 2] - path[first, 2])) < math.radians(45)))
    assert ok[False] <= 0.4  # uniform headings: a quarter within 45 deg
    assert ok[True] >= 0.85


def _reversed_case(seed, hm):
    """The robot drives the corridor west; the mapping run drove it east (module test below)."""
    rng = np.random.default_rng(seed + 10)
    back = polyline([(38, 0), (0, 0)], 0.5)
    truth = truth_places(back, CORRIDOR)
    q = truth >= 0
    # a reversed view matches no stored view well: a flat row (the true place's probability about 0.1)
    ll = 0.4 * sensor_scores(truth, CORRIDOR.shape[0], 2.5, seed)
    hd = np.full(ll.shape, np.nan)
    hd[q] = rng.uniform(-math.pi, math.pi, (int(q.sum()), CORRIDOR.shape[0]))  # alignments with other places: noise
    hd[q, truth[q]] = wrap(back[q, 2] + math.pi + math.radians(5) * rng.standard_normal(int(q.sum())))  # the mapping's way
    f = PoseFilter(CORRIDOR, 1.0, n_particles=1000, kidnap=0.005, heading=hm, random_state=seed)
    res = run_pose_filter(ll, odometry_increments(back), f, temper=(2.0, math.pi), start_at_first_observation=True, headings=hd)
    return float(np.mean(res.best[q] == truth[q]))


def test_a_reversed_traversal_falls_to_the_outlier_part():
    """Mapped one way, driven the other: the implied headings are the mapping's (off by pi) or noise.

    The model is fitted on mapping-run errors where the estimates that
    were noise came with poor matches (low place probability), as on the
    shared logs; the reversed pass's views match poorly too, so their
    headings weigh almost nothing and the filter tracks as without them. A
    model without the outlier part and the reliability (every estimate
    trusted) turns the particles around and loses the robot.
    """
    rng = np.random.default_rng(0)
    n = 150
    good = rng.uniform(size=n) < 0.85
    delta = np.where(good, math.radians(4) * rng.standard_normal(n), rng.uniform(-math.pi, math.pi, n))
    x = np.where(good, rng.uniform(-0.7, 0.0, n), rng.uniform(-5.0, -1.5, n))
    fitted = fit_heading_model(delta, x)
    assert fitted is not None and fitted.slope > 1.0
    naive = HeadingModel(kappa=50.0, intercept=10.0, slope=0.0, reverse=0.0, cap=1.0)
    seeds = range(4)
    none = np.mean([_reversed_case(s, None) for s in seeds])
    robust = np.mean([_reversed_case(s, fitted) for s in seeds])
    trusting = np.mean([_reversed_case(s, naive) for s in seeds])
    assert none >= 0.8
    assert robust >= none - 0.1
    assert trusting <= 0.3  # the case can fail


def test_implied_headings_follow_the_alignment_sign_convention():
    """A view turned by theta at a training view's spot implies theta (not -theta: bearing in the view = bearing in the query - h)."""
    from fingerloc.experiments.carmen import FingerprintMethod, best_fingerprint_params
    from fingerloc.pipeline.calibration import implied_headings

    from ._logs import box_scan

    train = [box_scan(5, 12, 2.5, 6, 0.0, noise=0.005), box_scan(5, 12, 2.5, 6.2, 0.05, noise=0.005),
             box_scan(8, 3, 3, 1.5, 0.0), box_scan(8, 3, 3.2, 1.5, 0.0)]  # fmt: skip
    fm = FingerprintMethod(**best_fingerprint_params()).fit(train, np.array([0, 0, 1, 1]))
    for theta in (0.3, -0.4):
        h = implied_headings(fm.model_, fm._observations([box_scan(8, 3, 3.1, 1.5, theta, noise=0.005)]), ["0", "1"])
        assert h.shape == (1, 2)
        assert abs(float(wrap(h[0, 1] - theta))) < 0.1


def test_the_heading_is_the_pose_filter_default_can_be_switched_off_and_round_trips():
    from fingerloc.experiments.filtered import PoseFilteredMethod
    from fingerloc.experiments.protocol import METHODS, load_methods

    load_methods()
    cc = PoseFilteredMethod("fingerprint").config.calibration
    assert cc.heading is True and cc.heading_temper_m == 8.0  # the default
    assert METHODS["fingerprint-odometry-noheading"]().config.calibration.heading is False
    assert METHODS["fingerprint-odometry-heading-untempered"]().config.calibration.heading_temper_m == 0.0
    cal = Calibration(heading=HeadingModel(50.0, 1.5, 2.0, 0.1, 0.95), heading_temper_metres=8.0)
    back = Calibration.from_json(cal.to_json())
    assert back == cal
    assert back.heading == HeadingModel(50.0, 1.5, 2.0, 0.1, 0.95)
    old = {k: v for k, v in cal.to_json().items() if not k.startswith("heading")}  # a database from before: off
    assert Calibration.from_json(old).heading is None


def test_cli_track_pose_filter_with_and_without_heading(rooms_log, tmp_path, capsys):
    import json

    from tests._cli import run_cli

    db = tmp_path / "rooms.sqlite"
    tops = []
    for flag in ("--heading", "--no-heading"):
        out = tmp_path / f"t{flag}.json"
        args = ["track", str(rooms_log), "--db", str(db), "--filter", "pose", "--json", str(out), "-q", flag]
        code, _, err = run_cli(capsys, *(args + (["--map"] if flag == "--heading" else [])))
        assert code == 0, err
        tops.append(json.loads(out.read_text())["summary"]["filtered"]["top1"])
    assert all(np.isfinite(tops))


def test_the_heading_evidence_can_be_tempered_on_its_own():
    hm = HeadingModel(kappa=20.0, intercept=0.0, slope=0.0, cap=0.8)
    centres = np.array([[0.0, 0.0], [10.0, 0.0]])
    row = np.array([0.0, -50.0])
    shares = {}
    for hw in (None, 0.25):
        f = PoseFilter(centres, 1.0, n_particles=1000, kidnap=0.0, outlier=0.0, heading=hm, random_state=0)
        f.particles_ = np.array([[0.0, 0.0, 0.0]] * 500 + [[0.0, 0.0, math.pi]] * 500)
        f.log_weights_ = np.full(1000, -math.log(1000))
        f.update(row, 1.0, headings=np.array([0.0, np.nan]), heading_weight=hw)
        shares[hw] = float(np.mean(np.abs(f.particles_[:, 2]) < 1.0))
    x = row[0] - logsumexp(row)
    r = math.exp(float(hm.log_factor(0.0, x) - hm.log_factor(math.pi, x)))  # odds of facing the implied heading
    assert shares[None] == pytest.approx(r / (1 + r), abs=0.02)
    assert shares[0.25] == pytest.approx(r**0.25 / (1 + r**0.25), abs=0.02)
    with pytest.raises(InvalidParameterError):
        f.update(row, 1.0, headings=np.array([0.0, np.nan]), heading_weight=0.0)


def test_prepared_headings_are_those_aligned_place_by_place():
    """PlaceModel.prepare_headings (one batch against every view) changes no heading and no reference view."""
    from fingerloc.experiments.carmen import FingerprintMethod, best_fingerprint_params

    from ._logs import box_scan

    train = [box_scan(5, 12, 2.5, 6, 0.0, noise=0.005), box_scan(5, 12, 2.5, 6.2, 0.05, noise=0.005),
             box_scan(8, 3, 3, 1.5, 0.0), box_scan(8, 3, 3.2, 1.5, 0.0), box_scan(6, 6, 2.0, 3.0, 0.2)]  # fmt: skip
    fm = FingerprintMethod(**best_fingerprint_params()).fit(train, np.array([0, 0, 1, 1, 2]))
    queries = [box_scan(8, 3, 3.1, 1.5, 0.3, noise=0.005), box_scan(5, 12, 2.4, 6.1, -0.2, noise=0.005),
               box_scan(6, 6, 2.1, 3.1, 1.0, noise=0.005)]  # fmt: skip
    model = fm.model_
    obs = fm._observations(queries)
    labels = list(model.places_)
    alone = [model.headings_with_reference(obs, [lab] * len(obs)) for lab in labels]
    model.prepare_headings(obs)
    fp = model.terms_["Fp"]
    assert all(fp._query(o)[1] is not None for o in obs)  # the batch is held
    for lab, (h0, v0) in zip(labels, alone, strict=True):
        h1, v1 = model.headings_with_reference(obs, [lab] * len(obs))
        np.testing.assert_array_equal(h1, h0)
        np.testing.assert_array_equal(v1, v0)


def test_headings_at_each_views_own_place_equal_that_column_of_every_place():
    """``own``: one heading a view at its own place, the same value as the full matrix's, NaN elsewhere."""
    from fingerloc.experiments.carmen import FingerprintMethod, best_fingerprint_params
    from fingerloc.pipeline.calibration import implied_headings

    from ._logs import box_scan

    train = [box_scan(5, 12, 2.5, 6, 0.0, noise=0.005), box_scan(5, 12, 2.5, 6.2, 0.05, noise=0.005),
             box_scan(8, 3, 3, 1.5, 0.0), box_scan(8, 3, 3.2, 1.5, 0.0), box_scan(4, 4, 2, 2, 0.0)]  # fmt: skip
    fm = FingerprintMethod(**best_fingerprint_params()).fit(train, np.array([0, 0, 1, 1, 2]))
    queries = fm._observations([box_scan(8, 3, 3.1, 1.5, 0.3, noise=0.005), box_scan(5, 12, 2.4, 6.1, -0.4, noise=0.005),
                                box_scan(4, 4, 2.1, 2, 1.0, noise=0.005), box_scan(8, 3, 2.9, 1.4, -1.0, noise=0.005)])  # fmt: skip
    own = np.array([1, 0, 2, -1])
    full = implied_headings(fm.model_, queries, ["0", "1", "2"])
    mine = implied_headings(fm.model_, queries, ["0", "1", "2"], own=own)
    assert np.isfinite(full[[0, 1, 2], [1, 0, 2]]).all()
    for i, j in enumerate(own.tolist()):
        for c in range(3):
            if c == j:
                assert mine[i, c] == full[i, c]
            else:
                assert np.isnan(mine[i, c])
