"""Fit each log's base method once; cache what FilteredMethod.fit produces plus query scores.

usage: cache.py [LOG ...] [--out=DIR] [--bases=fingerprint,baseline-histogram]
Writes DIR/LOG-BASE.pkl (default DIR /tmp/filter; scripts/issue15_kid/ reads /tmp/kid with --bases=fingerprint).
"""
import pickle, sys, time
from types import SimpleNamespace
import numpy as np
from fingerloc.experiments import markov
from fingerloc.experiments.protocol import load_log_scans, log_name, make_split

LOGS = ["aces", "csail", "freiburg-101", "intel"]
def path(l): return f"/work/shared/data/carmen/{l}-corrected.log.gz"

def build(log, base, out="/tmp/filter"):
    t0 = time.time()
    scans, _ = load_log_scans(path(log))
    pos = markov._positions(scans)
    split = make_split(pos)
    m = markov.FilteredMethod(base)
    m.set_context(scans, split)
    m.fit([scans[i] for i in split.train_idx.tolist()], split.train_labels.copy())
    qs = np.asarray(m.base_.score([scans[i] for i in split.query_idx.tolist()]), dtype=np.float64)
    lite = [SimpleNamespace(pose=s.pose, fov=s.fov) for s in scans]
    d = dict(scans=lite, split=split, graph=m.graph_, transition=m.transition_, scale=m.scale_,
             rows=m.calibration_rows_, held=m.held_out_, qs=qs, n_train=len(split.train_idx))
    with open(f"{out}/{log}-{base}.pkl", "wb") as f:
        pickle.dump(d, f)
    print(log, base, f"{time.time()-t0:.0f}s", flush=True)

if __name__ == "__main__":
    opts = dict(a[2:].split("=", 1) for a in sys.argv[1:] if a.startswith("--"))
    out = opts.get("out", "/tmp/filter")
    bases = opts.get("bases", "fingerprint,baseline-histogram").split(",")
    for log in ([a for a in sys.argv[1:] if not a.startswith("--")] or LOGS):
        for base in bases:
            build(log, base, out)
