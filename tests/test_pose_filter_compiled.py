"""The pose filter's compiled step equals the plain NumPy step bit for bit.

``_NumpyPoseFilter`` keeps the NumPy code of ``PoseFilter.predict``,
``update``, ``_particle_places``, ``_sample_at_places`` and ``_resample`` as
they were before the kernels of ``fingerloc.map._pf_kernels``; both filters
run the same synthetic runs from the same seeds, and every answer, particle
and weight must be the same bytes.
"""

import math

import numpy as np
import pytest

from fingerloc.angles import wrap
from fingerloc.config import Config
from fingerloc.map import _pf_kernels as k
from fingerloc.map import pose_filter as pf
from fingerloc.map.driver import Challenger, PoseTracking, SensorReset, run_pose_filter
from fingerloc.map.filter import MarkovFilter, TransitionModel
from fingerloc.map.graph import PlaceGraph
from fingerloc.map.heading import HeadingModel
from fingerloc.map.motion import simulate_odometry
from fingerloc.map.pose_filter import PoseFilter, observation_weights
from fingerloc.map.replay import SharedDraws
from fingerloc.pipeline.calibrate import tune_pose_filter
from fingerloc.pipeline.calibration import Calibration, HeldOut

logsumexp = pf.logsumexp


class _NumpyPoseFilter(PoseFilter):
    """The pose filter's step as NumPy operations (the code before the compiled kernels)."""

    def _particle_places(self):
        _, near = self._nearest(self.particles_[:, :2])
        mass = np.bincount(near, weights=np.exp(self.log_weights_), minlength=self.n_places)
        with np.errstate(divide="ignore"):
            lp = np.log(mass)
        return lp - logsumexp(lp)

    def predict(self, increment):
        dx, dy, dth = (float(v) for v in np.asarray(increment, dtype=np.float64).reshape(-1))
        m, rng = self.motion, self._rng
        n_now = self.particles_.shape[0]
        dist = math.hypot(dx, dy)
        st = m.translation_floor + m.translation * dist
        ex = dx * (1.0 + m.translation * rng.standard_normal(n_now)) + st * rng.standard_normal(n_now)
        ey = dy * (1.0 + m.translation * rng.standard_normal(n_now)) + st * rng.standard_normal(n_now)
        sr = m.rotation_floor + m.rotation_per_metre * dist + m.rotation * abs(dth)
        th = self.particles_[:, 2]
        c, s = np.cos(th), np.sin(th)
        self.particles_[:, 0] += c * ex - s * ey
        self.particles_[:, 1] += s * ex + c * ey
        self.particles_[:, 2] = wrap(th + dth + sr * rng.standard_normal(n_now))
        self._place_log_posterior = self._particle_places()
        return self.place_log_posterior()

    def update(self, log_likelihood, weight=1.0, kidnap_prior=None, kidnap=None, headings=None, heading_weight=None,
               points=None, scan_map=None):  # fmt: skip
        assert headings is None and points is None and scan_map is None  # the former step had no such evidence
        w_obs = float(weight)
        lp = w_obs * self.place_likelihood(log_likelihood)
        P = self.n_places
        floor = w_obs * math.log(self.off_place / P) if self.off_place > 0 else -np.inf
        d, near = self._nearest(self.particles_[:, :2])
        lik = np.where(d <= self.radius, lp[near], floor)
        w = self.log_weights_ + lik
        tracked = float(logsumexp(w)) if np.any(np.isfinite(w)) else -np.inf
        eps = -math.expm1(w_obs * math.log1p(-self.kidnap)) if kidnap is None else float(kidnap)
        with np.errstate(divide="ignore"):
            mass = np.log(np.bincount(near, weights=np.exp(w - tracked) if math.isfinite(tracked) else None,
                                      minlength=P))  # fmt: skip
        if kidnap_prior is None:
            prior = np.full(P, -math.log(P))
        else:
            prior = np.asarray(kidnap_prior, dtype=np.float64).reshape(-1)
            prior = prior - logsumexp(prior)
        kid = prior + lp
        comp_kid = (math.log(eps) if eps > 0 else -np.inf) + float(logsumexp(kid))
        comp_trk = (math.log1p(-eps) + tracked) if math.isfinite(tracked) and eps < 1 else -np.inf
        if not math.isfinite(comp_trk) and not math.isfinite(comp_kid):
            return self.place_log_posterior()
        post = np.logaddexp(comp_trk + mass, comp_kid + (kid - float(logsumexp(kid))))
        self._place_log_posterior = post - logsumexp(post)
        parts = [self.particles_]
        logw = [w - tracked + comp_trk] if math.isfinite(comp_trk) else [np.full(w.size, -np.inf)]
        if math.isfinite(comp_kid):
            m = self.n_particles if not math.isfinite(comp_trk) else max(self.n_particles // 3, 1)
            parts.append(self._sample_at_places(kid, m))
            logw.append(np.full(m, comp_kid - math.log(m)))
        self._resample(np.concatenate(parts), np.concatenate(logw))
        return self.place_log_posterior()

    def log_evidence(self, log_likelihood, weight=1.0, headings=None):
        assert headings is None
        w_obs = float(weight)
        lp = w_obs * self.place_likelihood(log_likelihood)
        floor = w_obs * math.log(self.off_place / self.n_places) if self.off_place > 0 else -np.inf
        d, near = self._nearest(self.particles_[:, :2])
        w = self.log_weights_ + np.where(d <= self.radius, lp[near], floor)
        return float(logsumexp(w)) if np.any(np.isfinite(w)) else -math.inf

    def _sample_at_places(self, log_p, m):
        rng = self._rng
        pr = np.exp(log_p - logsumexp(log_p))
        j = rng.choice(self.n_places, size=m, p=pr / pr.sum())
        ang = rng.uniform(0.0, 2 * math.pi, m)
        rad = self.radius * np.sqrt(rng.uniform(0.0, 1.0, m))
        out = np.column_stack(
            [self.centres[j, 0] + rad * np.cos(ang), self.centres[j, 1] + rad * np.sin(ang),
             rng.uniform(-math.pi, math.pi, m)]
        )  # fmt: skip
        for q in np.unique(j).tolist():
            known = self._place_poses[q]
            if known.shape[0] == 0:
                continue
            rows = np.flatnonzero(j == q)
            pick = known[rng.integers(0, known.shape[0], rows.size)]
            out[rows, :2] = pick[:, :2] + 0.25 * self.radius * rng.standard_normal((rows.size, 2))
            out[rows, 2] = wrap(pick[:, 2] + self.heading_jitter * rng.standard_normal(rows.size))
        return out

    def _resample(self, particles, log_w):
        n = self.n_particles
        p = np.exp(log_w - logsumexp(log_w))
        cum = np.cumsum(p)
        cum[-1] = 1.0
        u = (self._rng.uniform() + np.arange(n)) / n
        idx = np.minimum(np.searchsorted(cum, u, side="left"), particles.shape[0] - 1)
        self.particles_ = particles[idx].copy()
        self.log_weights_ = np.full(n, -math.log(n))


def _corridor(n_places, seed):
    """A corridor there and back with a turn, a noisy sensor (some rows all -inf), simulated odometry."""
    spacing = 2.0
    xs = np.linspace(0, (n_places - 1) * spacing, (n_places - 1) * 4 + 1)
    ys = 0.3 * np.sin(xs)
    back = np.column_stack([xs[::-1], ys[::-1] + 0.5, np.full_like(xs, math.pi - 1e-9)])
    poses = np.vstack([np.column_stack([xs, ys, 0.2 * np.cos(xs)]), back])
    centres = np.column_stack([np.arange(n_places) * spacing, np.zeros(n_places)])
    dist = np.linalg.norm(poses[:, None, :2] - centres[None], axis=2)
    truth = np.argmin(dist, axis=1)
    truth[dist[np.arange(truth.size), truth] > 0.7] = -1
    rng = np.random.default_rng(seed)
    q = truth >= 0
    ll = np.full((truth.size, n_places), np.nan)
    ll[q] = 2.0 * rng.normal(size=(int(q.sum()), n_places))
    ll[np.flatnonzero(q), truth[q]] += 2.0
    rows = np.flatnonzero(q)
    ll[rows[rng.random(rows.size) < 0.2], rng.integers(0, n_places)] = -np.inf  # impossible places
    inc = simulate_odometry(poses, random_state=seed + 1)
    g = PlaceGraph.from_sequence([str(i) for i in range(n_places)], [str(i) for i in truth[q]])
    return ll, inc, q, centres, poses, g


@pytest.mark.parametrize(
    "seed, n_places, outlier, off_place, start_at_first, reset, poses_known",
    [
        (0, 12, 0.1, None, True, None, False),
        (1, 7, 0.44, 0.1, True, None, False),
        (2, 20, 0.0, 0.0, False, None, False),
        (3, 9, 0.3, 0.1, False, 2.0, True),
        (4, 5, 1.0, None, True, 1.0, False),
    ],
)
def test_compiled_run_equals_the_numpy_run(seed, n_places, outlier, off_place, start_at_first, reset, poses_known):
    ll, inc, q, centres, poses, g = _corridor(n_places, seed)
    res, state = [], []
    for cls in (PoseFilter, _NumpyPoseFilter):
        f = cls(centres, 0.6, n_particles=900, kidnap=0.01, outlier=outlier, off_place=off_place,
                place_poses=poses if poses_known else None, random_state=seed)  # fmt: skip
        drv = PoseTracking(f, place_filter=MarkovFilter(TransitionModel.from_graph(g, metres_per_move=2.0)),
                           start_at_first_observation=start_at_first, gap_metres=5.0,
                           strategy=None if reset is None else SensorReset(reset))  # fmt: skip
        out = run_pose_filter(ll, inc, drv, weights=observation_weights(inc, q, metres=1.5))
        res.append(out.log_posterior)
        state.append((f.particles_.tobytes(), f.log_weights_.tobytes(), drv.resets_, f._rng.uniform()))
    assert res[0].tobytes() == res[1].tobytes()
    assert state[0] == state[1]
    assert np.isfinite(res[0][q]).any(axis=1).all()


def test_compiled_challenged_run_equals_the_numpy_run():
    ll, inc, _, centres, _, _ = _corridor(10, 5)
    res = []
    for cls in (PoseFilter, _NumpyPoseFilter):
        f = cls(centres, 0.6, n_particles=600, kidnap=0.01, outlier=0.2, off_place=0.1, random_state=3)
        drv = PoseTracking(f, strategy=Challenger(n_particles=200, spawn_nats=-1.0), temper=(1.5, math.inf),
                           start_at_first_observation=True)  # fmt: skip
        out = run_pose_filter(ll, inc, drv)
        res.append((out.log_posterior.tobytes(), f.particles_.tobytes(), drv.challenger_trace_))
    assert res[0] == res[1]
    assert any(e == "spawn" for _, e, _ in res[0][2])


def test_kernels_equal_numpy_on_edge_values():
    rng = np.random.default_rng(7)
    n = 4001
    p = np.column_stack([rng.normal(0, 50, n), rng.normal(0, 50, n), rng.uniform(-math.pi, math.pi, n)])
    p[:5, 2] = [-math.pi, math.pi - 1e-17, -1e-17, 0.0, math.pi]
    z = [rng.standard_normal(n) for _ in range(5)]
    z[4][:5] = 0.0
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    for dx, dy, dth in [(0.3, -0.01, 0.05), (0.0, 0.0, -math.pi), (1.7, 0.2, 3.0)]:
        out = np.empty((n, 3))
        k.move_particles(p, *z, c, s, dx, dy, dth, 0.05, 0.02 + 0.05 * math.hypot(dx, dy), 0.3, out)
        ex = dx * (1.0 + 0.05 * z[0]) + (0.02 + 0.05 * math.hypot(dx, dy)) * z[1]
        ey = dy * (1.0 + 0.05 * z[2]) + (0.02 + 0.05 * math.hypot(dx, dy)) * z[3]
        ref = np.column_stack([p[:, 0] + (c * ex - s * ey), p[:, 1] + (s * ex + c * ey),
                               wrap(p[:, 2] + dth + 0.3 * z[4])])  # fmt: skip
        assert out.tobytes() == ref.tobytes()
    # wrap at the edges: exact multiples, tiny negatives, huge values
    a = np.r_[np.arange(-20, 21) * math.pi, -1e-17, 1e-300, -5e-324, 1e15, -1e15, rng.normal(0, 1e3, 500)]
    out = np.empty((a.size, 3))
    zero = np.zeros(a.size)
    k.move_particles(np.column_stack([zero, zero, a]), zero, zero, zero, zero, zero, zero + 1, zero,
                     0.0, 0.0, 0.0, 0.0, 0.0, 0.0, out)  # fmt: skip
    assert out[:, 2].tobytes() == wrap(a).tobytes()
    near = rng.integers(0, 37, n)
    w = np.exp(rng.normal(0, 3, n))
    assert k.bincount_weights(near, w, 40).tobytes() == np.bincount(near, weights=w, minlength=40).tobytes()
    for m in (1, 2, 7, 1000, 4000):
        lw = rng.normal(0, 4, m)
        lw[rng.random(m) < 0.1] = -np.inf
        lw[0] = 0.0
        pr = np.exp(lw - logsumexp(lw))
        u0 = float(rng.uniform())
        cum = np.cumsum(pr)
        cum[-1] = 1.0
        ref = np.minimum(np.searchsorted(cum, (u0 + np.arange(900)) / 900, side="left"), m - 1)
        assert np.array_equal(k.systematic_indices(pr, u0, 900), ref)
    d = rng.uniform(0, 2, n)
    d[:3] = [0.5, np.inf, 0.0]
    lp = rng.normal(size=40)
    lp[3] = -np.inf
    lw = np.full(n, -math.log(n))
    for floor in (-3.0, -np.inf):
        got = np.empty(n)
        fin = k.observation_weights_at(d, near, lp, 0.5, floor, lw, got)
        ref = lw + np.where(d <= 0.5, lp[near], floor)
        assert got.tobytes() == ref.tobytes() and fin == bool(np.any(np.isfinite(ref)))
    got = np.empty(n)
    assert not k.observation_weights_at(d, near, np.full(40, -np.inf), 0.5, -np.inf, lw, got)


def _calls(g, variant):
    """A sequence of draws as the filter makes them; ``variant`` changes one call's size midway."""
    out = [g.integers(0, 7, 50), g.standard_normal((50, 2)), g.uniform(-math.pi, math.pi, 50)]
    for t in range(6):
        out += [g.standard_normal(50) for _ in range(5)]
        out.append(g.choice(9, size=20 + (variant if t == 3 else 0), p=np.full(9, 1 / 9)))
        out += [g.uniform(0.0, 2 * math.pi, 20), g.uniform(0.0, 1.0, 20), np.asarray(g.uniform())]
    out.append(g.choice(50, size=10, replace=False))
    return out


def test_shared_draws_are_those_of_a_fresh_generator():
    shared = SharedDraws(11)
    for variant in (0, 0, 3, 0, 1):
        got = _calls(shared.generator(), variant)
        ref = _calls(np.random.default_rng(11), variant)
        assert len(got) == len(ref)
        assert all(a.tobytes() == b.tobytes() and a.dtype == b.dtype for a, b in zip(got, ref, strict=True))
    g = shared.generator()
    z = g.standard_normal((50,))  # another size than the record's first call: its own draws
    assert z.tobytes() == np.random.default_rng(11).standard_normal((50,)).tobytes()
    rec = shared.generator().integers(0, 7, 50)
    assert not rec.flags.writeable  # recorded arrays are shared: read only


def _tuning_config(share: bool) -> Config:
    return Config().with_(pose_filter={"n_particles": 300}, calibration={"share_draws": share})


def test_tuning_grid_with_shared_draws_equals_separate_runs():
    ll, _, q, centres, poses, g = _corridor(8, 6)
    rows = np.flatnonzero(q)
    truth = np.argmin(np.linalg.norm(poses[rows, None, :2] - centres[None], axis=2), axis=1)
    held = HeldOut(beta=1.0, rows=rows.size, scores=ll[rows], labels=truth, index=np.arange(rows.size))
    cal = Calibration(radius=0.6, kidnap=0.01)
    a = tune_pose_filter(cal, _tuning_config(True), centres, g, held, rows, poses, odometry_error=1.0, seed=3)
    b = tune_pose_filter(cal, _tuning_config(False), centres, g, held, rows, poses, odometry_error=1.0, seed=3)
    assert a == b
    assert len({x["top1"] for x in a[1]}) > 1  # the grid's runs differ


def test_tuning_grid_with_headings_shares_draws_exactly():
    """Heading evidence draws von Mises headings for fresh particles: those draws are shared too."""
    ll, _, q, centres, poses, g = _corridor(8, 5)
    rows = np.flatnonzero(q)
    truth = np.argmin(np.linalg.norm(poses[rows, None, :2] - centres[None], axis=2), axis=1)
    held = HeldOut(beta=1.0, rows=rows.size, scores=ll[rows], labels=truth, index=np.arange(rows.size))
    rng = np.random.default_rng(5)
    headings = poses[rows, 2:3] + 0.1 * rng.standard_normal((rows.size, centres.shape[0]))  # implied at every place
    cal = Calibration(radius=0.6, kidnap=0.05, heading=HeadingModel(kappa=30.0, intercept=1.0, cap=0.9),
                      heading_temper_metres=3.0)  # fmt: skip
    runs = [tune_pose_filter(cal, _tuning_config(share), centres, g, held, rows, poses, odometry_error=1.0, seed=3,
                             headings=headings) for share in (True, False)]  # fmt: skip
    assert runs[0] == runs[1]


def test_shared_place_steps_are_the_filter_own_beliefs():
    from fingerloc.map.filter import SharedPlaceSteps

    ll, inc, q, _, _, g = _corridor(9, 8)
    tm = TransitionModel.from_graph(g, metres_per_move=2.0)
    dist = np.hypot(inc[:, 0], inc[:, 1])

    def run(f, change_at=None):
        f.reset()
        out = [f.log_belief_.copy()]
        for t in range(1, ll.shape[0]):
            out.append(f.predict(dist[t - 1] * (1.5 if t == change_at else 1.0)))
            if q[t]:
                out.append(f.update(np.where(np.isnan(ll[t]), -np.inf, ll[t])))
        return np.array(out).tobytes()

    shared = SharedPlaceSteps()
    for change_at in (None, None, 30, None):
        assert run(shared.filter(tm), change_at) == run(MarkovFilter(tm), change_at)
    other = TransitionModel.from_graph(g, metres_per_move=3.0)  # another model: not replayed
    assert run(shared.filter(other)) == run(MarkovFilter(other)) != run(MarkovFilter(tm))
