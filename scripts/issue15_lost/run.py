"""scripts/issue15_scan/run.py with the lost-filter options (issue 15, branch h-lost); results in /tmp/lost.

usage: run.py NAME SEEDS [k=v ...] [--kidnap] [--log=LOG ...]
Options are PoseFilteredMethod keywords (scan=True, scan_fresh=10, lost=False, lost_statistic=mean ...), and
q.ATTR=V sets ATTR of the query-pass filter only (after the fit, e.g. q.fresh_factor=10: a diagnosis, nothing
tuned); g.NAME=V sets fingerloc.pipeline.tracker.NAME (g.LOST_QUANTILE=0.01).
Each log's line also gives the lost rule's calibration [lost_fit, lost_kidnap] and how often it fired.
"""
import importlib.util
import json
import os
import sys
import time

import numpy as np

_spec = importlib.util.spec_from_file_location(
    "scan_run", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "issue15_scan", "run.py"))
S = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(S)
S.OUT = "/tmp/lost"  # the scans' pickles: link /tmp/sbench/*-scans.pkl here to reuse them
os.makedirs(S.OUT, exist_ok=True)
R, markov, kidnap_experiment = S.R, S.markov, S.kidnap_experiment


def prep(log, seed, opts):
    from fingerloc.pipeline import tracker

    opts = dict(opts)
    for k in [k for k in opts if k.startswith("g.")]:
        setattr(tracker, k[2:], opts.pop(k))
    q = {k[2:]: opts.pop(k) for k in list(opts) if k.startswith("q.")}
    data = S.prep(log, seed, opts)
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
            m = data.method
            cal = m.calibration_
            r = {"n": int(q.sum()), "top1": float(np.mean(full.best[q] == data.truth[q])),
                 "gamma": getattr(m, "scan_gamma_", 0.0), "outlier": m.outlier_, "temper": m.temper_metres_,
                 "tuning": [[t.get("scan_gamma", 0.0), round(t["top1"], 4)] for t in m.tuning_ if "scan_gamma" in t],
                 "lost": [] if cal.lost_fit is None else [[cal.lost_fit, cal.lost_kidnap]],
                 "lost_steps": len(getattr(m.filter_, "lost_steps_", [])),
                 "fit_s": round(t1 - t0, 2), "run_s": round(time.time() - t1, 2)}
            if kid:
                k = kidnap_experiment(data, name=log, random_state=seed)
                r["kidnap"] = k.summary()
                r["trials"] = k.trials
            per[log] = r
            print(name, seed, log, json.dumps({k: v for k, v in r.items() if k != "trials"}), flush=True)
        n = sum(p["n"] for p in per.values())
        line = {"pooled": sum(p["top1"] * p["n"] for p in per.values()) / n}
        if kid:
            tr = [t for p in per.values() for t in p["trials"]]
            line["kidnap"] = markov.KidnapResult("pooled", tr).summary()
        per["pooled"] = line
        res["seeds"][seed] = per
        print(name, seed, "POOLED", json.dumps(line), flush=True)
    with open(f"{S.OUT}/res-{name}.json", "w") as fh:
        json.dump(res, fh, indent=1, default=str)


if __name__ == "__main__":
    main()
