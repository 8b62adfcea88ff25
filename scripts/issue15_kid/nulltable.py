"""The no-kidnap disagreement of two runs and the true-cell accuracy between queries, per hold margin (from --null runs)."""
import glob
import json
import sys

for path in sorted(glob.glob(f"/tmp/kid/res-{sys.argv[1]}.json")):
    r = json.load(open(path))
    for seed, per in r["seeds"].items():
        for log, v in per.items():
            if log == "pooled" or "null" not in v:
                continue
            nl = v["null"]
            ms = [k for k in nl if k.startswith("m")]
            print(f"| {r['name']} | {seed} | {log} | " + " | ".join(
                f"{nl[m]['disagree_between']:.3f} / {nl[m]['cell_acc_between']:.3f} / {nl[m]['floor_within_10']:.2f}"
                for m in ms) + " |")
