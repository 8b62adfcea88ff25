"""Diagnosis: at each observed step of the query pass, the posterior particles' mean scan fit (mean end-point
log-likelihood against the query-time map) and the fit at the true pose; whether the answer is right.

usage: diag.py LOG SEED [k=v ...]    (options as scripts/issue15_scan/run.py)
"""
import importlib.util
import os
import sys

import numpy as np

_spec = importlib.util.spec_from_file_location(
    "scan_run", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "issue15_scan", "run.py"))
S = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(S)
from fingerloc.map.pose_filter import PoseFilter  # noqa: E402

rec = []
_orig = PoseFilter.update


def update(self, *a, **k):
    out = _orig(self, *a, **k)
    pts = k.get("points")
    if pts is not None and self.scan_map is not None:
        L = self.scan_map.log_likelihood(self.particles_, pts)
        rec.append((float(L.mean()), float(np.median(L)), k.get("kidnap")))
    return out


PoseFilter.update = update


def main():
    log, seed = sys.argv[1], int(sys.argv[2])
    opts = {k: S.R.parse(v) for k, v in (a.split("=", 1) for a in sys.argv[3:])}
    opts.setdefault("scan", True)
    data = S.prep(log, seed, opts)
    d = S.R._cache["d"]
    scans, split = d["scans"], d["split"]
    rec.clear()
    full = data.run()
    m = data.method
    obs = [t for t in range(len(data.points)) if data.points[t] is not None]
    assert len(obs) == len(rec), (len(obs), len(rec))
    print("gamma", m.scan_gamma_)
    for i, t in enumerate(obs):
        pose = np.asarray(scans[split.n_mapping + t].pose, dtype=float).reshape(1, 3)
        Lt = float(m.scan_map_.log_likelihood(pose, data.points[t])[0])
        ok = full.best[t] == data.truth[t] if data.truth[t] >= 0 else None
        print(f"{i:3d} t={t:4d} fit_mean={rec[i][0]:7.3f} fit_med={rec[i][1]:7.3f} truth={Lt:7.3f} ok={ok} kid={rec[i][2]}")


main()
