"""Diagnosis: the mapping-pass tuning runs' log score (mean log posterior of the true place, floored at
log 1e-3) beside their top-1, per power of the scan evidence. usage: logscore.py SEED LOG [LOG ...]"""
import sys

import numpy as np

import run as S  # scripts/issue15_scan/run.py (the cached fits)
from fingerloc.pipeline import tracker as T

_orig = T.Tracker.run_pose
_runs = []


def _spy(self, ll, inc, f, **kw):
    res = _orig(self, ll, inc, f, **kw)
    _runs.append((self.calibration.scan_gamma, res))
    return res


T.Tracker.run_pose = _spy

if __name__ == "__main__":
    seed = int(sys.argv[1])
    for log in sys.argv[2:]:
        _runs.clear()
        data = S.prep(log, seed, {"scan": True})
        m = data.method
        held, tr = m.held_out_, m._need_context()[1].train_idx
        rows = tr[held.index]
        for (g, res), t in zip(_runs, m.tuning_, strict=True):
            lp = np.maximum(res.log_posterior[rows, held.labels], np.log(1e-3))
            print(log, seed, f"gamma {g:g} rho {t['outlier']:.2f} temper {t['temper_metres']:g} top1 {t['top1']:.3f} "
                  f"logscore {lp.mean():.3f}")
