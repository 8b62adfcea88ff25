#!/usr/bin/env python3
"""A sweep over CARMEN logs x seeds x presets, one task per cell, serially or on a Dask cluster (docs/CLUSTER.md).

Each cell ``(log, seed, preset)`` runs the real-log benchmark's protocol on
one log with two methods: the fingerprint program with the preset's options, verified against the scan map
(single shot; no randomness) and the same front end under the pose filter
(``fingerprint-odometry``'s filter, seeded with ``seed``: simulated odometry
errors and particles). The cells are independent and carry everything random
about them, so the figures do not depend on where or in which order they run.

Usage::

    python scripts/sweep.py LOG... [--seeds 0 1 2] [--presets laser2d paper] [--json sweep.json]
    python scripts/sweep.py LOG... --workers 4                  # a local Dask cluster of 4 processes
    python scripts/sweep.py LOG... --scheduler tcp://HEAD:8786  # an existing cluster (dask-jobqueue, Kubernetes...)

Prints one line per cell and writes every cell's figures (top-1, mean rank,
recall@5, timings) as a JSON list with ``--json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any


def sweep_cell(task: tuple[str, int, str]) -> dict[str, Any]:
    """One cell: ``(log path, seed, preset)`` -> its figures (module-level: Dask ships it by reference)."""
    import numpy as np

    from fingerloc.experiments.carmen import FingerprintMethod, load_log_scans, log_name, make_split, run_log
    from fingerloc.experiments.filtered import PoseFilteredMethod
    from fingerloc.experiments.protocol import METHODS, register_method
    from fingerloc.experiments.shared import shared_method, shared_results
    from fingerloc.pipeline.presets import model_options

    log, seed, preset = task
    single = f"fingerprint-preset-{preset}"
    if single not in METHODS:  # registered in whichever process runs the cell
        register_method(single, default=False)(lambda: FingerprintMethod(**model_options(preset), verify=True))
    scans, _ = load_log_scans(log)
    split = make_split(np.array([s.pose[:2] for s in scans], dtype=np.float64))
    pose = PoseFilteredMethod(single, seed=seed)
    pose.name = f"{single}-odometry"
    methods = [shared_method(single), pose]
    with shared_results():  # the pose filter's front end is the single-shot method's fit
        runs = run_log(scans, split, methods) if split.n_queries else {}
    return {
        "log": log_name(log),
        "seed": seed,
        "preset": preset,
        "places": split.n_places,
        "queries": split.n_queries,
        "methods": {("single" if k == single else "odometry"): v.figures() for k, v in runs.items()},
    }


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="+")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--presets", nargs="+", default=["laser2d"])
    ap.add_argument("--workers", type=int)
    ap.add_argument("--scheduler")
    ap.add_argument("--json")
    a = ap.parse_args(argv)

    import itertools

    from fingerloc.parallel import run_tasks

    cells = list(itertools.product(a.logs, a.seeds, a.presets))
    rows = run_tasks(sweep_cell, cells, workers=a.workers, scheduler=a.scheduler,
                     on_done=lambda k: print(f"{k} of {len(cells)} cells done", file=sys.stderr))  # fmt: skip
    for r in rows:
        figs = " ".join(f"{m} top-1 {f['top1']:.3f} rank {f['mean_rank']:.2f}" for m, f in r["methods"].items())
        print(f"{r['log']} seed {r['seed']} {r['preset']}: {figs}")
    if a.json:
        with open(a.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
