"""The loop-closure benchmark's protocol and metrics against independent computations, and ``bench loops``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.loops import (
    PRCurve,
    candidate_window,
    loop_metrics,
    loop_truth,
    pr_curve,
    run_loop_benchmark,
    usable_timestamps,
)

from ._cli import run_cli


def _brute_metrics(scores, correct, n_pos):
    """Precision and recall at every distinct threshold by direct counting (no cumulative sums)."""
    s = np.asarray(scores, float)
    ok = np.asarray(correct, bool)
    pts = [(1.0, 0.0)]
    for thr in sorted(set(s[np.isfinite(s)].tolist()), reverse=True):
        sel = s >= thr
        tp = int(np.sum(sel & ok))
        fp = int(np.sum(sel & ~ok))
        pts.append((tp / (tp + fp), tp / max(n_pos, 1)))
    p = np.array([a for a, _ in pts])
    r = np.array([b for _, b in pts])
    f1 = max([2 * a * b / (a + b) for a, b in pts[1:] if a + b > 0], default=0.0)
    r100 = max([b for a, b in pts[1:] if a >= 1.0], default=0.0)
    r99 = max([b for a, b in pts[1:] if a >= 0.99], default=0.0)
    ap = sum((r[k] - r[k - 1]) * p[k] for k in range(1, len(pts)))
    return p, r, {"max_f1": f1, "recall_at_100": r100, "recall_at_99": r99, "average_precision": ap}


@settings(max_examples=60)
@given(
    st.lists(st.tuples(st.integers(0, 6), st.booleans()), min_size=1, max_size=40),
    st.integers(0, 10),
)
def test_pr_metrics_equal_direct_counting(items, extra_positives):
    scores = [float(s) for s, _ in items]  # small integers: many ties
    correct = [c for _, c in items]
    n_pos = sum(correct) + extra_positives
    curve = pr_curve(scores, correct, n_pos)
    p, r, want = _brute_metrics(scores, correct, n_pos)
    np.testing.assert_allclose(curve.precision, p)
    np.testing.assert_allclose(curve.recall, r)
    got = loop_metrics(curve)
    for k, v in want.items():
        assert got[k] == pytest.approx(v, abs=1e-12), k


def test_recall_at_precision_levels_on_a_hand_made_ranking():
    # 100 right detections, then one wrong, then 10 right: precision never drops below 0.99 until the wrong one
    # is followed by nothing else; recall at 100 % stops before the first false positive
    scores = np.arange(111, 0, -1, dtype=float)
    correct = np.ones(111, bool)
    correct[100] = False
    m = loop_metrics(pr_curve(scores, correct, 200))
    assert m["recall_at_100"] == pytest.approx(100 / 200)
    assert m["recall_at_99"] == pytest.approx(110 / 200)  # 110 / 111 >= 0.99
    assert m["max_f1"] == pytest.approx(2 * (110 / 111) * 0.55 / (110 / 111 + 0.55))


def test_a_query_never_detected_lowers_recall_only():
    c = pr_curve([3.0, -np.inf, np.nan], [True, True, False], 2)
    assert isinstance(c, PRCurve)
    assert c.recall[-1] == pytest.approx(0.5) and c.precision[-1] == pytest.approx(1.0)


def test_candidate_window_by_seconds_and_by_scans():
    t = np.array([0.0, 10.0, 20.0, 35.0, 50.0, 61.0])
    el, how = candidate_window(6, t, exclude_s=30.0)
    # scan i may match scans taken at least 30 s before it
    want = [sum(1 for j in range(i) if t[j] <= t[i] - 30.0) for i in range(6)]
    assert el.tolist() == want and how == "30 s"
    frozen = np.array([5.0, 5.0, 5.0, 5.0, 9.0, 9.0])  # timestamps that stand still: not usable
    assert not usable_timestamps(frozen)
    el2, how2 = candidate_window(6, frozen, exclude_s=30.0, exclude_scans=2)
    assert el2.tolist() == [0, 0, 0, 1, 2, 3] and how2 == "2 scans"
    with pytest.raises(InvalidParameterError):
        candidate_window(3, None, exclude_s=-1.0)


def test_loop_truth_counts_a_positive_when_a_candidate_is_near():
    pos = np.array([[0, 0], [5, 0], [10, 0], [0.5, 0.5], [20, 0]], float)
    el = np.array([0, 0, 1, 2, 3])
    q, positive = loop_truth(pos, el, 2.0)
    assert q.tolist() == [2, 3, 4]
    # scan 3 is 0.7 m from scan 0 (a candidate); scan 2 and 4 have no candidate within 2 m
    assert positive.tolist() == [False, True, False]


def test_bench_loops_on_a_synthetic_log_writes_the_json_others_read(rooms_log, tmp_path, capsys):
    out = tmp_path / "loops.json"
    rep = tmp_path / "rep"
    code, _, err = run_cli(capsys, "bench", "loops", rooms_log, "--json", out, "--report", rep, "--exclude-s", 3)
    assert code == 0, err
    js = json.loads(out.read_text())
    lg = js["logs"]["rooms"]
    assert set(lg["methods"]) == {"fingerprint", "baseline-scancontext", "baseline-histogram"}
    for m in lg["methods"].values():
        assert {"max_f1", "recall_at_100", "recall_at_99", "average_precision"} <= set(m)
    assert set(js["pooled"]["methods"]) == set(lg["methods"])
    assert {"places", "pose_places", "purity", "localize_top1", "track_top1"} <= set(lg["fingerprint_map"])
    assert lg["window"] == "3 s"  # the synthetic log's timestamps rise by 1 s a scan
    assert (rep / "index.html").exists() and (rep / "pr-rooms.png").exists() and (rep / "places-rooms.png").exists()


def test_bench_loops_scores_the_same_detections_as_the_library(rooms_log):
    b = run_loop_benchmark([rooms_log], ["baseline-histogram"], exclude_scans=3, fingerprint_map=False)
    lg = b.logs[0]
    m = lg.methods["baseline-histogram"]
    # every named candidate lies before the query's window, and "correct" is the 2 m test on the poses
    el, _ = candidate_window(lg.positions.shape[0], None, exclude_scans=3)
    assert np.all(m.best < el[lg.queries])
    d = np.hypot(*(lg.positions[m.best] - lg.positions[lg.queries]).T)
    assert m.correct.tolist() == (d <= 2.0).tolist()


def test_bench_loops_refuses_an_unknown_method_before_reading(tmp_path, capsys):
    code, _, err = run_cli(capsys, "bench", "loops", tmp_path / "missing.log", "-m", "nope")
    assert code == 2 and "unknown method 'nope'" in err
