"""Rerun only the pose filter, with or without the scan evidence, on the cached front ends of
scripts/issue15_heading/cache.py (/tmp/heading/LOG.pkl) and the logs' scans (cached here once).

usage: run.py NAME SEEDS [k=v ...] [--kidnap] [--log=LOG ...]
Options are PoseFilteredMethod keywords (scan=True, observe=False, scan_gamma=3, odometry_error=2, lost=False ...),
g.NAME=V and q.ATTR=V (see prep), and
base=baseline-histogram (needs /tmp/filter/LOG-baseline-histogram.pkl of scripts/issue15_filter/cache.py).
Writes /tmp/sbench/res-NAME.json; prints per log top-1, the chosen scan_gamma and the mapping-pass tuning.
Shares scripts/issue15_heading/run.py's restore (the cached fits, the filter rerun as the benchmark runs it).
"""
import json, os, pickle, sys, time

import numpy as np

import importlib.util  # noqa: E402

_spec = importlib.util.spec_from_file_location(
    "heading_run", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "issue15_heading", "run.py")
)
R = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(R)  # patches FilteredMethod.fit to restore the cached fits

from fingerloc.experiments.protocol import load_log_scans  # noqa: E402
from fingerloc.pipeline.places import visit_folds  # noqa: E402
from fingerloc.pipeline.tracker import held_out_rows  # noqa: E402

OUT = "/tmp/sbench"
_load = R.load


def scans_of(log):
    """The log's full scans (ranges, bearings, poses), cached as a pickle."""
    f = f"{OUT}/{log}-scans.pkl"
    if not os.path.exists(f):
        scans, _ = load_log_scans(f"/work/shared/data/carmen/{log}-corrected.log.gz")
        with open(f, "wb") as fh:
            pickle.dump(scans, fh)
    with open(f, "rb") as fh:
        return pickle.load(fh)


_full = {}


def load(log, base):
    """The heading cache with the full scans and the held-out folds (the cache predates HeldOut.fold)."""
    d = _load(log, base)
    if log not in _full:
        _full[log] = scans_of(log)
    d["scans"] = _full[log]
    split, held = d["split"], d["held"]
    fold = visit_folds(split.train_idx, split.train_labels)
    if not np.array_equal(held_out_rows(fold), held.index):
        fold = np.arange(split.train_labels.size) % 2
    assert np.array_equal(held_out_rows(fold), held.index), "fold mismatch"
    d["held"] = type(held)(held.beta, held.rows, held.scores, held.labels, held.index, fold)
    return d


R.load = load


def prep(log, seed, opts):
    """The fitted method and the query pass's inputs; ``g.NAME=V`` sets fingerloc.pipeline.tracker.NAME first,
    ``q.ATTR=V`` sets ATTR of the query-pass filter after the fit (a diagnosis, nothing tuned)."""
    from fingerloc.pipeline import tracker

    opts = dict(opts)
    for k in [k for k in opts if k.startswith("g.")]:
        setattr(tracker, k[2:], opts.pop(k))
    q = {k[2:]: opts.pop(k) for k in list(opts) if k.startswith("q.")}
    data = R.prep(log, opts.pop("base", "fingerprint"), seed, opts)
    data.points = data.method.step_points()
    for k, v in q.items():
        setattr(data.method.filter_, k, v)
    return data


def main():
    name, seeds = sys.argv[1], [int(x) for x in sys.argv[2].split(",")]
    args = [a for a in sys.argv[3:] if "=" in a and not a.startswith("--")]
    kid = "--kidnap" in sys.argv
    logs = [a[6:] for a in sys.argv if a.startswith("--log=")] or R.LOGS
    opts = {k: R.parse(v) for k, v in (a.split("=", 1) for a in args)}
    res = {"name": name, "opts": args, "seeds": {}}
    for seed in seeds:
        per = {}
        for log in logs:
            t0 = time.time()
            data = prep(log, seed, opts)
            t1 = time.time()
            full = data.run()
            q = data.truth >= 0
            top1 = float(np.mean(full.best[q] == data.truth[q]))
            m = data.method
            tun = m.tuning_
            cal = m.calibration_
            r = {"n": int(q.sum()), "top1": top1, "gamma": getattr(m, "scan_gamma_", 0.0), "outlier": m.outlier_,
                 "temper": m.temper_metres_,
                 "tuning": [[t.get("scan_gamma", 0.0), round(t["top1"], 4)] for t in tun if "scan_gamma" in t],
                 "mapping_top1_noscan": max((t["top1"] for t in tun if "scan_gamma" not in t), default=None),
                 "lost": [] if cal.lost_fit is None else [[cal.lost_fit, cal.lost_kidnap]],
                 "lost_steps": len(getattr(m.filter_, "lost_steps_", [])),
                 "fit_s": round(t1 - t0, 2), "run_s": round(time.time() - t1, 2)}
            if kid:
                R.kidnap_into(r, data, log, seed)
            per[log] = r
            print(name, seed, log, json.dumps({k: v for k, v in r.items() if k != "trials"}), flush=True)
        res["seeds"][seed] = R.pool(name, seed, per, kid)
    os.makedirs(OUT, exist_ok=True)
    with open(f"{OUT}/res-{name}.json", "w") as fh:
        json.dump(res, fh, indent=1, default=str)


if __name__ == "__main__":
    main()
