"""Markdown tables of the issue-15 scan runs: per log top-1 at seeds (res-NAME.json of run.py) and the CLI's JSON.

usage: tables.py seeds NAME [NAME ...]  |  tables.py cli FILE.json [FILE.json ...]
"""
import json
import sys

import numpy as np

LOGS = ["aces", "csail", "freiburg-101", "intel"]
SINGLE = {"aces": 0.439, "csail": 0.325, "intel": 0.377}  # single shot fingerprint (bench carmen; no seed)


def seeds(names):
    res = {n: json.load(open(f"/tmp/sbench/res-{n}.json")) for n in names}
    print("| method | seed | " + " | ".join(LOGS) + " | pooled |")
    print("|---|---|" + "---|" * (len(LOGS) + 1))
    for n, r in res.items():
        ss = sorted(r["seeds"], key=int)
        for s in ss:
            d = r["seeds"][s]
            cells = [f"{d[l]['top1']:.3f}" + (f" (γ {d[l]['gamma']:g})" if d[l].get("gamma") else "") for l in LOGS]
            print(f"| {n} | {s} | " + " | ".join(cells) + f" | {d['pooled']['pooled']:.3f} |")
        mean = [np.mean([r["seeds"][s][l]["top1"] for s in ss]) for l in LOGS]
        pooled = np.mean([r["seeds"][s]["pooled"]["pooled"] for s in ss])
        print(f"| **{n}** | mean | " + " | ".join(f"{m:.3f}" for m in mean) + f" | **{pooled:.3f}** |")


def rule(name, oo="oo"):
    """The per-log rule (logs with >= 20 queries): top-1 >= max(single shot, odometry-only) - 0.02, per seed."""
    r, o = json.load(open(f"/tmp/sbench/res-{name}.json")), json.load(open(f"/tmp/sbench/res-{oo}.json"))
    for s in sorted(r["seeds"], key=int):
        out = []
        for l, single in SINGLE.items():
            bar = max(single, o["seeds"][s][l]["top1"]) - 0.02
            v = r["seeds"][s][l]["top1"]
            out.append(f"{l} {v:.3f} vs {bar:.3f} {'ok' if v >= bar - 1e-12 else 'FAIL'}")
        print(name, "seed", s, "; ".join(out))


def cli(files):
    for f in files:
        d = json.load(open(f))
        methods = list(next(iter(d["logs"].values()))["methods"])
        print(f"\n{f}\n\n| method | " + " | ".join(list(d["logs"]) + ["pooled"]) + " |")
        print("|---|" + "---|" * (len(d["logs"]) + 1))
        for m in methods:
            cells = [f"{v['methods'][m]['top1']:.3f}" for v in d["logs"].values()]
            print(f"| {m} | " + " | ".join(cells) + f" | {d['pooled']['methods'][m]['top1']:.3f} |" if "methods" in d["pooled"] else "")


if __name__ == "__main__":
    {"seeds": seeds, "cli": cli, "rule": lambda a: [rule(n) for n in a]}[sys.argv[1]](sys.argv[2:])
