"""Markdown rows for RESULTS: one row per variant and seed (pooled kidnap figures, tracking top-1 per log)."""
import json
import sys


def f(v, fmt=".2f"):
    return "-" if v is None else format(v, fmt)


print("| variant | seed | tracking pooled (aces / csail / freiburg-101 / intel) | <= 10 steps (floor) | median steps "
      "| <= 10 at obs (floor) | median at obs | truth <= 10 (reference) | top-1 after (reference) |")
print("|---|---|---|---|---|---|---|---|---|")
for arg in sys.argv[1:]:
    try:
        r = json.load(open(f"/tmp/kid/res-{arg}.json"))
    except FileNotFoundError:
        continue
    for seed, per in r["seeds"].items():
        logs = [k for k in per if k != "pooled"]
        tr = " / ".join(f"{per[k]['top1']:.3f}" for k in logs)
        s = per["pooled"].get("kidnap", {})
        print(f"| {r['name']} | {seed} | {per['pooled']['pooled']:.3f} ({tr}) | {f(s.get('within_10'))} ({f(s.get('floor_within_10'))}) "
              f"| {f(s.get('median_recover_steps'), '.1f')} | {f(s.get('observed_within_10'))} ({f(s.get('floor_observed_within_10'))}) "
              f"| {f(s.get('median_recover_observed_steps'), '.1f')} | {f(s.get('truth_within_10'))} ({f(s.get('reference_truth_within_10'))}) "
              f"| {f(s.get('kidnapped_top1'), '.3f')} ({f(s.get('reference_top1'), '.3f')}) |")
