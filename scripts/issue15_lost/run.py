"""scripts/issue15_scan/run.py (the same runs and options) writing to /tmp/lost (issue 15, branch h-lost).

usage: run.py NAME SEEDS [k=v ...] [--kidnap] [--log=LOG ...]
Options are PoseFilteredMethod keywords (scan=True, scan_fresh=10, lost=False, lost_statistic=mean ...), and
q.ATTR=V sets ATTR of the query-pass filter only (after the fit, e.g. q.fresh_factor=10: a diagnosis, nothing
tuned); g.NAME=V sets fingerloc.pipeline.tracker.NAME (g.LOST_QUANTILE=0.01).
Each log's line also gives the lost rule's calibration [lost_fit, lost_kidnap] and how often it fired.
"""
import importlib.util
import os

_spec = importlib.util.spec_from_file_location(
    "scan_run", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "issue15_scan", "run.py"))
S = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(S)
S.OUT = "/tmp/lost"  # the scans' pickles: link /tmp/sbench/*-scans.pkl here to reuse them


if __name__ == "__main__":
    S.main()
