"""Compact tables of /tmp/kid/res-*.json: tracking top-1 and kidnap columns per log and pooled."""
import glob
import json
import sys

def f(v, fmt=".2f"):
    return "-" if v is None else format(v, fmt)

COLS = [("within_10", "<=10"), ("median_recover_steps", "med"), ("floor_within_10", "floor"),
        ("observed_within_10", "obs<=10"), ("median_recover_observed_steps", "obs med"),
        ("floor_observed_within_10", "obs floor"), ("truth_within_10", "truth"),
        ("reference_truth_within_10", "ref truth"), ("kidnapped_top1", "kid top1"), ("reference_top1", "ref top1")]
pats = sys.argv[1:] or ["*"]
for pat in pats:
    for path in sorted(glob.glob(f"/tmp/kid/res-{pat}.json")):
        r = json.load(open(path))
        for seed, per in r["seeds"].items():
            logs = [k for k in per if k != "pooled"]
            top = " ".join(f"{k[:6]} {per[k]['top1']:.3f}" for k in logs)
            print(f"## {r['name']} seed {seed}: pooled top-1 {per['pooled']['pooled']:.3f} ({top})")
            if "kidnap" not in per["pooled"]:
                continue
            print("| log | " + " | ".join(c[1] for c in COLS) + " |")
            for k in [*logs, "pooled"]:
                s = per[k]["kidnap"]
                print(f"| {k} | " + " | ".join(f(s.get(c), ".1f" if "median" in c else ".2f") for c, _ in COLS) + " |")
