"""``bench carmen`` shares features, fits and scores between its methods: the same figures.

Each log's methods run inside :func:`fingerloc.experiments.shared.shared_results`;
here the default methods run once that way (``run_benchmark``) and once
without any sharing (``run_log`` outside the context, every method fitting
and scoring on its own, as a plain run does), and every query's rank and
answer must agree. ``fingerloc bench compare`` does the same for two
``--json`` files (e.g. two versions' runs on the shared logs).
"""

import json
import math

import numpy as np
import pytest

from fingerloc.experiments.carmen import (
    DEFAULT_METHODS,
    load_log_scans,
    make_method,
    make_split,
    run_benchmark,
    run_log,
)
from fingerloc.experiments.shared import SharedMethod, observations, shared_method, shared_results

from ._logs import box_scan

# rooms of several sizes, some alike; each visited at a few spots more than 2 m apart (several places a room)
_ROOMS = [(6.0, 4.0), (6.5, 4.0), (9.0, 3.0), (5.0, 8.0), (4.0, 4.0)]


def _walk(loop: int):
    rng = np.random.default_rng(10 + loop)
    out = []
    for j, (w, h) in enumerate(_ROOMS):
        spots = [(1.2, h / 2), (w / 2, h / 2), (w - 1.2, h / 2)]
        for x, y in spots:
            for _ in range(2):
                dx, dy = rng.normal(0.0, 0.25, 2)
                th = float(rng.uniform(-math.pi, math.pi))
                out.append((j, w, h, float(np.clip(x + dx, 0.3, w - 0.3)), float(np.clip(y + dy, 0.3, h - 0.3)), th))
    return out


def _write(path):
    lines = ["# synthetic log", "PARAM robot_front_laser_max 30 nohost 0"]
    for k, (j, w, h, x, y, th) in enumerate(_walk(0) + _walk(1)):
        s = box_scan(w, h, x, y, th, n=181, noise=0.02, rng=np.random.default_rng(k))
        r = " ".join(f"{v:.3f}" for v in np.minimum(s.ranges, 30.0))
        wx = x + 20.0 * j  # room j is 20 m further along x
        lines.append(f"FLASER 181 {r} {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {k}.0 host {k}.0")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    return _write(tmp_path_factory.mktemp("shared") / "rooms5-corrected.log")


@pytest.fixture(scope="module")
def shared_run(small_log):
    return run_benchmark([small_log])  # default methods, shared within the log


def test_shared_run_gives_the_unshared_figures(small_log, shared_run):
    shared = shared_run
    scans, _ = load_log_scans(small_log)
    split = make_split(np.array([s.pose[:2] for s in scans]))
    alone = run_log(scans, split, [make_method(n) for n in DEFAULT_METHODS])  # no sharing at all
    lg = shared.logs[0]
    assert split.n_places >= 8 and split.n_queries >= 15
    assert list(lg.methods) == list(alone) == list(DEFAULT_METHODS)
    for name, run in alone.items():
        np.testing.assert_array_equal(lg.methods[name].ranks, run.ranks, err_msg=name)
        np.testing.assert_array_equal(lg.methods[name].predicted, run.predicted, err_msg=name)
    # a meaningful case: not every method is perfect, and they differ (so a wrong share would show)
    top1 = {n: float(np.mean(r.ranks == 1)) for n, r in alone.items()}
    assert min(top1.values()) < 1.0 and len(set(top1.values())) > 2
    js = json.loads(json.dumps(shared.to_json()))
    assert set(js["logs"]["rooms5"]["methods"]) == set(DEFAULT_METHODS)


def test_sharing_happens_and_is_keyed_on_scans_and_labels(small_log):
    scans, _ = load_log_scans(small_log)
    a, b = scans[:12], scans[12:24]
    y = np.arange(12) % 4
    with shared_results() as cache:
        m1 = shared_method("baseline-histogram").fit(a, y)
        m2 = shared_method("baseline-histogram").fit(list(a), y.copy())  # same scans, same labels: shared
        assert m2.inner_ is m1.inner_ and cache.hits["fit"] == 1
        s1, s2 = m1.score(b), m2.score(b)
        assert cache.hits["score"] == 1 and np.array_equal(s1, s2) and s1 is not s2
        s2[:] = 0.0  # a caller's copy: the cached scores are untouched
        assert np.array_equal(m1.score(b), s1)
        m3 = shared_method("baseline-histogram").fit(a, (y + 1) % 4)  # other labels: a fit of its own
        m4 = shared_method("baseline-histogram").fit(b, y)  # other scans: a fit of its own
        m5 = shared_method("baseline-scancontext").fit(a, y)  # other method
        assert len({id(m.inner_) for m in (m1, m3, m4, m5)}) == 4
        calls: list[int] = []
        o1 = observations(a, "k", lambda s: calls.append(1) or len(calls))
        o2 = observations(a, "k", lambda s: calls.append(1) or len(calls))
        assert o1 == o2 and len(calls) == 12
    m6 = shared_method("baseline-histogram").fit(a, y)  # outside the context: nothing is shared
    assert isinstance(m6, SharedMethod) and m6.inner_ is not m1.inner_
    assert np.array_equal(m6.score(b), s1)
    with pytest.raises(AttributeError):
        shared_method("baseline-histogram").score(b)  # score before fit


def test_sweep_script_cell_matches_the_benchmark(small_log, shared_run, tmp_path):
    """scripts/sweep.py (docs/CLUSTER.md): preset laser2d, seed 0 is the benchmark's fingerprint / fingerprint-odometry."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "sweep.py"
    spec = importlib.util.spec_from_file_location("fingerloc_sweep_example", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "sweep.json"
    assert mod.main([str(small_log), "--seeds", "0", "--presets", "laser2d", "--json", str(out)]) == 0
    (row,) = json.loads(out.read_text())
    assert (row["log"], row["seed"], row["preset"]) == ("rooms5", 0, "laser2d")
    bench = shared_run.to_json()["logs"]["rooms5"]["methods"]
    for mine, theirs in (("single", "fingerprint"), ("odometry", "fingerprint-odometry")):
        for fig in ("top1", "mean_rank", "recall5"):
            assert row["methods"][mine][fig] == bench[theirs][fig], (mine, fig)
