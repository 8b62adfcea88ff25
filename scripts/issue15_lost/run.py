"""scripts/issue15_scan/run.py with the lost-filter options (issue 15, branch h-lost); results in /tmp/lost.

usage: run.py NAME SEEDS [k=v ...] [--kidnap] [--log=LOG ...]
Besides PoseFilteredMethod keywords: q.ATTR=V sets ATTR of the query-pass filter only (after the fit, e.g.
q.fresh_factor=10: a diagnosis, nothing tuned); g.NAME=V sets fingerloc.pipeline.tracker.NAME (g.LOST_QUANTILE=0.01).
"""
import importlib.util
import os

_spec = importlib.util.spec_from_file_location(
    "scan_run", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "issue15_scan", "run.py"))
S = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(S)
S.OUT = "/tmp/lost"
os.makedirs(S.OUT, exist_ok=True)
_prep = S.prep


def prep(log, seed, opts):
    opts = dict(opts)
    from fingerloc.map.pose_filter import PoseFilter
    from fingerloc.pipeline import tracker
    for k in [k for k in opts if k.startswith("g.")]:
        setattr(tracker, k[2:], opts.pop(k))
    for k in [k for k in opts if k.startswith("c.")]:
        setattr(PoseFilter, k[2:], opts.pop(k))
    q = {k[2:]: opts.pop(k) for k in list(opts) if k.startswith("q.")}
    data = _prep(log, seed, opts)
    for k, v in q.items():
        setattr(data.method.filter_, k, v)
    return data


S.prep = prep
if __name__ == "__main__":
    S.main()
