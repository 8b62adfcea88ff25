"""Two never-kidnapped runs: disagreement between queries and true-cell accuracy between queries, per log and pooled (--null runs)."""
import json
import pickle
import sys

between = {}
for log in ("aces", "csail", "freiburg-101", "intel"):
    d = pickle.load(open(f"/tmp/kid/{log}-fingerprint.pkl", "rb"))
    sp = d["split"]
    between[log] = sp.n_scans - sp.n_mapping - sp.n_queries
print("between-query steps:", between)
print("| answer | seed | aces | csail | freiburg-101 | intel | pooled (aces, csail, intel) |")
print("|---|---|---|---|---|---|---|")
for arg in sys.argv[1:]:  # NAME or NAME:mMARGIN (the hold margin applied to NAME's runs, e.g. base:m0.05)
    name, _, col = arg.partition(":")
    col = col or "m0"
    r = json.load(open(f"/tmp/kid/res-{name}-012.json"))
    for seed, per in r["seeds"].items():
        cells, dis, acc = [], 0.0, 0.0
        for log in ("aces", "csail", "freiburg-101", "intel"):
            m = per[log]["null"][col]
            cells.append(f"{m['disagree_between']:.3f} / {m['cell_acc_between']:.3f}")
            if log != "freiburg-101":
                dis += m["disagree_between"] * between[log]
                acc += m["cell_acc_between"] * between[log]
        n = sum(v for k, v in between.items() if k != "freiburg-101")
        print(f"| {arg} | {seed} | " + " | ".join(cells) + f" | {dis / n:.3f} / {acc / n:.3f} |")
