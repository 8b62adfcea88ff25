"""Tables of the h-lost runs (scripts/issue15_lost/run.py -> /tmp/lost/res-NAME.json).

usage: tables.py seeds NAME [NAME ...] | tables.py rule NAME [NAME ...] | tables.py kidnap NAME [NAME ...]
The per-log rule uses odometry-only of /tmp/sbench/res-oo.json (scripts/issue15_scan/run.py oo ... observe=False).
"""
import json
import sys

import numpy as np

LOGS = ["aces", "csail", "freiburg-101", "intel"]
SINGLE = {"aces": 0.439, "csail": 0.325, "intel": 0.377}  # single shot fingerprint (bench carmen; no seed)


def load(n):
    return json.load(open(f"/tmp/lost/res-{n}.json"))


def seeds(names):
    print("| variant | seed | " + " | ".join(LOGS) + " | pooled |")
    print("|---|---|" + "---|" * (len(LOGS) + 1))
    for n in names:
        r = load(n)
        ss = sorted(r["seeds"], key=int)
        for s in ss:
            d = r["seeds"][s]
            cells = [f"{d[lg]['top1']:.3f} ({d[lg]['gamma']:g})" for lg in LOGS]
            print(f"| {n} | {s} | " + " | ".join(cells) + f" | {d['pooled']['pooled']:.3f} |")
        mean = [np.mean([r["seeds"][s][lg]["top1"] for s in ss]) for lg in LOGS]
        pooled = np.mean([r["seeds"][s]["pooled"]["pooled"] for s in ss])
        print(f"| **{n}** | mean | " + " | ".join(f"{m:.3f}" for m in mean) + f" | **{pooled:.3f}** |")


def rule(names):
    o = json.load(open("/tmp/sbench/res-oo.json"))
    for n in names:
        r = load(n)
        fails = []
        for s in sorted(r["seeds"], key=int):
            for lg, single in SINGLE.items():
                bar = max(single, o["seeds"][s][lg]["top1"]) - 0.02
                v = r["seeds"][s][lg]["top1"]
                if v < bar - 1e-12:
                    fails.append(f"{lg} seed {s}: {v:.3f} < {bar:.3f}")
        print(n, "rule:", "; ".join(fails) if fails else "met on every log at every seed")


def kidnap(names):
    cols = [("within_10", "floor_within_10"), ("observed_within_10", "floor_observed_within_10"),
            ("truth_within_10", "reference_truth_within_10"), ("kidnapped_top1", "reference_top1")]
    print("| variant | agree within 10 (floor) | at obs within 10 (floor) | truth within 10 (ref) | top-1 (ref) "
          "| median obs to recover | per log at obs within 10 |")
    print("|---|---|---|---|---|---|---|")
    for n in names:
        r = load(n)
        s = sorted(r["seeds"], key=int)[0]
        k = r["seeds"][s]["pooled"]["kidnap"]
        f = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
        per = " / ".join(f(r["seeds"][s][lg]["kidnap"]["observed_within_10"]) for lg in LOGS)
        print(f"| {n} (seed {s}) | " + " | ".join(f"{f(k[a])} ({f(k[b])})" for a, b in cols)
              + f" | {k['median_recover_observations']} | {per} |")


if __name__ == "__main__":
    {"seeds": seeds, "rule": rule, "kidnap": kidnap}[sys.argv[1]](sys.argv[2:])
