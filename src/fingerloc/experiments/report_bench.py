"""Time and size of the report folders on synthetic data of a given scale (``fingerloc bench report``).

The data are random but shaped like a real run: places along a looping
corridor trajectory, a few views per place with random feature bearings,
queries whose posterior puts the true place first most of the time and a near
place otherwise, and a track with two kidnappings. Only the report writers are
timed; the figures' content is not what is measured.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..reporting import FeatureView, write_localize_report, write_map_report, write_track_report

__all__ = ["folder_size", "run_report_bench", "synthetic_report_data"]


def _view(rng: np.random.Generator) -> FeatureView:
    b = {k: rng.uniform(-math.pi, math.pi, rng.integers(lo, hi)) for k, lo, hi in
         (("VE", 2, 9), ("CP", 0, 4), ("c", 1, 6), ("Ex", 1, 7), ("B", 0, 3))}  # fmt: skip
    hues = rng.uniform(0, 360, b["CP"].size)
    letters = "".join(rng.choice(list("vcnnnbfA"), size=int(rng.integers(8, 30))))
    return FeatureView(b, hues, letters)


def synthetic_report_data(n_places: int, n_queries: int, *, seed: int = 0) -> dict[str, Any]:
    """Arrays for the three report writers at the given scale.

    Returns
    -------
    dict
        ``map``, ``localize`` and ``track``: keyword arguments of
        :func:`~fingerloc.reporting.write_map_report`,
        :func:`~fingerloc.reporting.write_localize_report` and
        :func:`~fingerloc.reporting.write_track_report`.
    """
    if n_places < 2 or n_queries < 1:
        raise InvalidParameterError(f"need >= 2 places and >= 1 query, got {n_places} and {n_queries}")
    rng = np.random.default_rng(seed)
    names = [f"place-{j:04d}" for j in range(n_places)]
    # a corridor loop: places every 2 m along a square spiral-ish path
    s = np.arange(n_places) * 2.0
    side = max(20.0, math.sqrt(n_places) * 8.0)
    lap = np.mod(s, 4 * side)
    x = np.where(lap < side, lap, np.where(lap < 2 * side, side, np.where(lap < 3 * side, 3 * side - lap, 0.0)))
    y = np.where(lap < side, 0.0, np.where(lap < 2 * side, lap - side, np.where(lap < 3 * side, side, 4 * side - lap)))
    ring = np.floor(s / (4 * side))
    centres = np.column_stack([x + 3.0 * ring, y + 3.0 * ring])
    traj = np.repeat(centres, 5, axis=0) + rng.normal(0, 0.3, (5 * n_places, 2))
    scan_pts = np.repeat(traj, 40, axis=0) + rng.normal(0, 2.0, (40 * traj.shape[0], 2))
    views = [_view(rng) for _ in range(n_places)]
    edges = [(j, j + 1) for j in range(n_places - 1)]
    truth = rng.integers(0, n_places, n_queries)
    logit = rng.normal(0, 1.0, (n_queries, n_places))
    right = rng.random(n_queries) < 0.8
    neighbour = np.clip(truth + rng.choice([-1, 1], n_queries), 0, n_places - 1)
    logit[np.arange(n_queries), np.where(right, truth, neighbour)] += 8.0
    logp = logit - np.log(np.sum(np.exp(logit), axis=1, keepdims=True))
    qviews = [_view(rng) for _ in range(n_queries)]
    # the track: the queries' order along the loop, two kidnappings
    t_n = n_queries
    ttruth = np.arange(t_n) * n_places // t_n
    k1, k2 = t_n // 3, 2 * t_n // 3
    ttruth[k1:k2] = (ttruth[k1:k2] + n_places // 2) % n_places
    poses = centres[ttruth] + rng.normal(0, 0.3, (t_n, 2))
    ll = rng.normal(0, 1.0, (t_n, n_places))
    ll[np.arange(t_n), ttruth] += 3.0
    ll[rng.random(t_n) < 0.5] = np.nan
    lp = rng.normal(0, 1.0, (t_n, n_places))
    ok = np.ones(t_n, dtype=bool)
    ok[k1 : k1 + 15] = False
    ok[k2 : k2 + 25] = False
    lp[np.arange(t_n)[ok], ttruth[ok]] += 6.0
    lp -= np.log(np.sum(np.exp(lp), axis=1, keepdims=True))
    return {
        "map": {
            "place_names": names,
            "centres": centres,
            "radius": 1.0,
            "edges": edges,
            "trajectory": traj,
            "scan_points": scan_pts,
            "views_per_place": rng.integers(1, 12, n_places),
            "place_views": views,
        },
        "localize": {
            "classes": names,
            "log_proba": logp,
            "truth": truth,
            "query_names": [f"run.jsonl:{i + 1}" for i in range(n_queries)],
            "query_views": qviews,
            "place_views": views,
        },
        "track": {
            "classes": names,
            "log_posterior": lp,
            "single_log_likelihood": ll,
            "truth": ttruth,
            "poses": poses,
            "centres": centres,
            "kidnaps": [k1, k2],
        },
    }


def folder_size(path: str | Path) -> int:
    """Bytes of all files under ``path``."""
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())


def run_report_bench(
    out_dir: str | Path,
    *,
    n_places: int = 1000,
    n_queries: int = 5000,
    seed: int = 0,
    on_stage: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Write the map, localize and track reports of synthetic data into ``out_dir/{map,localize,track}``.

    Returns
    -------
    dict
        Per report: ``seconds`` (writing only), ``bytes`` and ``files``; and their totals.
    """
    data = synthetic_report_data(n_places, n_queries, seed=seed)
    writers: dict[str, Callable[..., Path]] = {
        "map": write_map_report,
        "localize": write_localize_report,
        "track": write_track_report,
    }
    out = Path(out_dir)
    res: dict[str, Any] = {"places": n_places, "queries": n_queries}
    for name, fn in writers.items():
        if on_stage is not None:
            on_stage(name)
        t0 = time.perf_counter()
        fn(out / name, **data[name])
        dt = time.perf_counter() - t0
        files = [f for f in (out / name).rglob("*") if f.is_file()]
        res[name] = {"seconds": dt, "bytes": folder_size(out / name), "files": len(files)}
    res["total_seconds"] = sum(res[k]["seconds"] for k in writers)
    res["total_bytes"] = sum(res[k]["bytes"] for k in writers)
    return res
