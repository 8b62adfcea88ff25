"""``fingerloc bench live``: the streaming tracker's latency per step, and the pose filter's APE against a run's poses.

Two sections:

* **latency**: the streaming tracker (``PlaceMap.tracker(filter="pose")``,
  one ``step`` per scan) on a map of about ``places`` places with the
  ``laser2d`` preset. A real log's map has tens of places; the map is made
  from ``copies`` copies of the log's mapping part laid out on a square grid,
  ``gap_m`` metres between the trajectories' bounding boxes (buildings side
  by side that look alike; close enough that the scan map keeps its
  resolution), and learned without calibration; the single log's own calibration (its
  likelihood scale, the pose filter's tuned reliabilities, scan power...)
  is put on it, with the kidnapping probability of its number of
  training scans. The log's query part (after the mapping part) is then
  tracked step by step, the robot in the first copy; each step's wall time
  (``time.perf_counter``) and CPU time (``time.process_time``) are taken, after
  ``warmup`` steps that compile and fill caches. Figures: median, 95th
  percentile and maximum, milliseconds, and the load average; the CPU time is
  split into the observation (features, the model's scores over every place,
  the heading each place implies, end points) and the filter. Two variants:
  the map's defaults, and without the heading evidence (``heading=False``).
* **ape** (and the stream check): per log, the map of its mapping part (``fingerloc map``'s
  defaults) and ``track --filter pose`` of its query part (the library's
  ``PlaceMap.track``, what ``track --tum`` writes), then evo's APE
  (translation part, RMSE, no alignment: both are in the map's frame)
  between the filter's poses and the run's own (corrected) poses, over the
  steps whose answer is right (the true place, that of the run's pose within
  a place's radius), and over every tracked step. Both trajectories are
  written as TUM files and read back by evo (``evo.tools.file_interface``);
  their timestamps are the steps' indices in the run (seconds), so that evo
  pairs them exactly whatever the log's clock. With the same map, the query
  part written as a log of its own is tracked read whole and line by line
  (:func:`stream_check`): the steps that give the same place, the same record.
"""

from __future__ import annotations

import math
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..pipeline.readers import Run
from ..sensors import Scan

__all__ = ["ape_translation", "held_out_log", "percentile", "run_live_bench", "stream_check", "tiled_run"]

#: Metres between the bounding boxes of two copies' trajectories in the latency map.
COPY_GAP_M = 40.0

Progress = Callable[[str], None]


def tiled_run(run: Run, copies: int, n: int, *, gap_m: float = COPY_GAP_M) -> Run:
    """The first ``n`` scans of a laser run, ``copies`` times, laid out on a square grid of copies.

    Copy ``k`` sits in column ``k % c`` and row ``k // c`` (``c = ceil(sqrt(copies))``),
    moved by the trajectory's extent plus ``gap_m`` metres per column and per
    row. Timestamps go on increasing from copy to copy, so that the run is
    one trajectory.
    """
    if run.scans is None:
        raise InvalidParameterError("tiled_run needs a laser run (scans with poses)")
    if copies < 1 or not 1 <= n <= len(run):
        raise InvalidParameterError(f"tiled_run: copies must be >= 1 and n in [1, {len(run)}], got {copies}, {n}")
    base = run.scans[:n]
    if any(s.pose is None for s in base):
        raise InvalidParameterError("tiled_run needs a pose on every scan")
    xy = np.array([s.pose[:2] for s in base if s.pose is not None], dtype=np.float64)
    dx, dy = (np.ptp(xy, axis=0) + gap_m).tolist()
    cols = math.ceil(math.sqrt(copies))
    t = [float(s.timestamp or 0.0) for s in base]
    span = (max(t) - min(t)) + 1.0
    scans: list[Scan] = []
    names: list[str] = []
    for k in range(copies):
        ox, oy = (k % cols) * dx, (k // cols) * dy
        for i, s in enumerate(base):
            assert s.pose is not None
            x, y, th = s.pose
            scans.append(replace(s, pose=(x + ox, y + oy, th), timestamp=t[i] + k * span))
            names.append(f"copy{k}:{run.names[i]}")
    return Run(list(run.paths), run.kind, names, scans=scans, key=f"tiled{copies}x{n}:{run.key}")


def percentile(values: Sequence[float], q: float) -> float:
    """The ``q``-th percentile (0-100) by linear interpolation (numpy's default)."""
    return float(np.percentile(np.asarray(values, dtype=np.float64), q))


def ape_translation(ref: Any, est: Any, *, folder: Path | None = None) -> dict[str, Any]:
    """evo's APE (translation part, no alignment) between two planar trajectories of the same steps.

    Parameters
    ----------
    ref, est : array_like, shape (n, 3)
        Poses ``(x, y, theta)`` of the same ``n`` steps, metres and radians.
    folder : Path, optional
        Where the two TUM files are written (default: a temporary folder).

    Returns
    -------
    dict
        ``steps``, ``rmse_m``, ``mean_m``, ``median_m``, ``max_m`` (``None``
        figures without a step).
    """
    from evo import main_ape
    from evo.core import metrics, sync
    from evo.tools import file_interface

    from ..io.trajectory import write_tum

    r = np.asarray(ref, dtype=np.float64).reshape(-1, 3)
    e = np.asarray(est, dtype=np.float64).reshape(-1, 3)
    if r.shape != e.shape:
        raise InvalidParameterError(f"ape_translation: {r.shape[0]} reference and {e.shape[0]} estimated poses")
    if r.shape[0] == 0:
        return {"steps": 0, "rmse_m": None, "mean_m": None, "median_m": None, "max_m": None}
    stamps = np.arange(r.shape[0], dtype=np.float64)
    with tempfile.TemporaryDirectory(prefix="fingerloc-ape-") as tmp:
        where = Path(folder) if folder is not None else Path(tmp)
        write_tum(where / "reference.tum", stamps, r)
        write_tum(where / "estimate.tum", stamps, e)
        tr = file_interface.read_tum_trajectory_file(str(where / "reference.tum"))
        te = file_interface.read_tum_trajectory_file(str(where / "estimate.tum"))
    tr, te = sync.associate_trajectories(tr, te, max_diff=1e-3)
    res = main_ape.ape(tr, te, metrics.PoseRelation.translation_part, align=False)
    st = res.stats
    return {"steps": int(r.shape[0]), "rmse_m": float(st["rmse"]), "mean_m": float(st["mean"]),
            "median_m": float(st["median"]), "max_m": float(st["max"])}  # fmt: skip


def _figures_ms(values_s: Sequence[float]) -> dict[str, float]:
    ms = [1000.0 * v for v in values_s]
    return {
        "median_ms": statistics.median(ms),
        "p95_ms": percentile(ms, 95.0),
        "max_ms": max(ms),
        "mean_ms": statistics.fmean(ms),
    }


def latency(
    log: Path, *, places: int = 1000, seed: int = 0, steps: int | None = None, warmup: int = 20,
    config: Any = None, on_progress: Progress | None = None,
) -> dict[str, Any]:  # fmt: skip
    """The latency section (see the module docstring) on one CARMEN log; ``config``: the log's own map's
    (default ``Config()``, what ``fingerloc map`` does)."""
    import fingerloc as fl

    note = on_progress or (lambda s: None)
    note(f"reading {log.name}")
    run = fl.read_run(log)
    if run.scans is None or any(s.pose is None for s in run.scans):
        raise InvalidParameterError(f"{log}: the latency needs a laser log with a pose on every scan (CARMEN)")
    note(f"mapping {log.name} (calibrated)")
    own = fl.make_map(run, config)
    assert own.split is not None and own.calibration is not None
    n_map = int(own.split.n_mapping)
    per_copy = max(len(own.labels), 1)
    copies = max(1, math.ceil(places / per_copy))
    note(f"mapping {copies} copies of its mapping part ({n_map} scans each, without calibration)")
    cfg = fl.Config().with_(places={"mapping_part": 1.0}, calibration={"enabled": False})
    big = fl.make_map(tiled_run(run, copies, n_map), cfg)
    assert big.split is not None
    cal = replace(own.calibration, kidnap=1.0 / (int(big.split.n_train) + 2), n_train=int(big.split.n_train))
    big = replace(big, calibration=cal)
    queries = list(range(n_map, len(run)))
    if steps is not None:
        queries = queries[: warmup + steps]
    assert run.scans is not None
    scans = [run.scans[i] for i in queries]
    variants = {}
    for name, heading in (("default", True), ("no_heading", False)):
        note(f"tracking {len(scans)} scans on {len(big.labels)} places ({name.replace('_', ' ')})")
        variants[name] = _time_steps(big.tracker(filter="pose", seed=seed, heading=heading), scans, warmup)
    return {
        "log": log.name,
        "places": len(big.labels),
        "copies": copies,
        "places_per_copy": per_copy,
        "preset": getattr(big.preset, "name", None),
        "filter": "pose",
        "warmup_steps": warmup,
        **variants["default"],
        "variants": variants,
        "load_average_1min": os.getloadavg()[0],
    }


def _time_steps(tracker: Any, scans: Sequence[Scan], warmup: int) -> dict[str, Any]:
    """Wall and CPU time of each step after ``warmup``; CPU split into the observation (features, the model's
    scores, implied headings, end points: ``Tracker.observe``) and the filter (``Tracker.step_scores``)."""
    wall: list[float] = []
    cpu: list[float] = []
    cpu_observe: list[float] = []
    cpu_filter: list[float] = []
    for k, s in enumerate(scans):
        w0, c0 = time.perf_counter(), time.process_time()
        row, hd, pts, unknown = tracker.observe(s)
        c1 = time.process_time()
        tracker.step_scores(row, s.pose, s.timestamp, headings=hd, points=pts, unknown=unknown, started=w0)
        w2, c2 = time.perf_counter(), time.process_time()
        if k >= warmup:
            wall.append(w2 - w0)
            cpu.append(c2 - c0)
            cpu_observe.append(c1 - c0)
            cpu_filter.append(c2 - c1)
    if not wall:
        raise InvalidParameterError(f"no step to time after {warmup} warm-up steps")
    return {"steps": len(wall), "wall": _figures_ms(wall), "cpu": _figures_ms(cpu),
            "cpu_observe": _figures_ms(cpu_observe), "cpu_filter": _figures_ms(cpu_filter)}  # fmt: skip


def ape(log: Path, *, seed: int = 0, config: Any = None, on_progress: Progress | None = None) -> dict[str, Any]:
    """The APE section (see the module docstring) on one CARMEN log; ``config``: the map's (default ``Config()``)."""
    import fingerloc as fl

    note = on_progress or (lambda s: None)
    run = fl.read_run(log)
    note(f"mapping {log.name}")
    pm = fl.make_map(run, config)
    note(f"tracking {log.name}")
    res = pm.track(run, filter="pose", seed=seed)
    assert pm.split is not None
    note(f"tracking the query part of {log.name} as a stream")
    stream = stream_check(log, pm, int(pm.split.n_mapping), seed=seed)
    ref = res.poses
    assert ref is not None
    rows = [(k, a) for k, a in enumerate(res.answers) if a.pose is not None]
    right = [(k, a) for k, a in rows if a.true is not None and a.place == a.true]

    def pair(sel: list[tuple[int, Any]]) -> tuple[Any, Any]:
        return ref[[k for k, _ in sel]], np.array([a.pose for _, a in sel], dtype=np.float64).reshape(-1, 3)

    labelled = sum(1 for a in res.answers if a.true is not None and a.observed)
    return {
        "log": log.name,
        "tracked_steps": len(res.answers),
        "steps_with_pose": len(rows),
        "labelled_steps": labelled,
        "right_steps": len(right),
        "right_observed_steps": sum(1 for _, a in right if a.observed),
        "top1": sum(1 for _, a in right if a.observed) / labelled if labelled else None,
        "ape_right": ape_translation(*pair(right)),
        "ape_all": ape_translation(*pair(rows)),
        "stream": stream,
    }


def held_out_log(log: Path, n_mapping: int, out: Path) -> int:
    """Write the query part of a CARMEN log as a log of its own: its comment and ``PARAM`` lines, then every line
    after its ``n_mapping``-th front-laser line (``FLASER``, or ``ROBOTLASER1`` in a log without them, the stream
    reader's rule); returns the number of front-laser lines written."""
    from ..io.stream import open_lines

    front: str | None = None
    seen = written = 0
    with open(out, "w", encoding="utf-8") as fh:
        for _, text in open_lines(log):
            head = text.split(None, 1)[0] if text.strip() else ""
            if front is None and head in ("FLASER", "ROBOTLASER1"):
                front = head
            if head == front:
                seen += 1
            if head.startswith("#") or head == "PARAM":
                fh.write(text)
            elif seen > n_mapping:
                fh.write(text)
                written += head == front
    return written


def stream_check(log: Path, place_map: Any, n_mapping: int, *, seed: int = 0) -> dict[str, Any]:
    """The query part of ``log`` as its own log, tracked twice with the pose filter: read whole
    (``PlaceMap.track``, what ``track LOG --json`` does) and line by line (``track - --follow``: the stream
    reader and :class:`~fingerloc.pipeline.follow.StreamStepper`, CARMEN's simulated odometry); how many steps
    give the same place, and how many the same record (every field of ``track --json`` but the name and latency)."""
    import fingerloc as fl

    from ..io.stream import iter_stream
    from ..pipeline.follow import track_stream

    with tempfile.TemporaryDirectory(prefix="fingerloc-held-") as tmp:
        held = Path(tmp) / f"held-{log.name.removesuffix('.gz')}"
        held_out_log(log, n_mapping, held)
        offline = place_map.track(fl.read_run(held), filter="pose", seed=seed).answers
        live = list(track_stream(place_map, iter_stream(held), filter="pose", seed=seed, odometry_error=1.0))

    def record(a: Any) -> dict[str, Any]:
        r = a.to_json()
        return {k: v for k, v in r.items() if k not in ("name", "latency_ms")}

    n = min(len(offline), len(live))
    return {
        "offline_steps": len(offline),
        "stream_steps": len(live),
        "same_place": sum(offline[k].place == live[k].place for k in range(n)),
        "same_record": sum(record(offline[k]) == record(live[k]) for k in range(n)),
    }


def run_live_bench(
    logs: Sequence[Path],
    *,
    latency_log: Path | None = None,
    places: int = 1000,
    seed: int = 0,
    steps: int | None = None,
    sections: Sequence[str] = ("latency", "ape"),
    on_progress: Progress | None = None,
) -> dict[str, Any]:
    """Both sections: latency on ``latency_log`` (default the first log), APE on every log."""
    unknown = set(sections) - {"latency", "ape"}
    if unknown:
        raise InvalidParameterError(f"unknown bench live section {sorted(unknown)[0]!r} (latency, ape)")
    if not logs:
        raise InvalidParameterError("bench live needs at least one CARMEN log")
    out: dict[str, Any] = {"seed": seed}
    if "latency" in sections:
        out["latency"] = latency(latency_log or logs[0], places=places, seed=seed, steps=steps, on_progress=on_progress)
    if "ape" in sections:
        out["ape"] = {Path(lg).name: ape(Path(lg), seed=seed, on_progress=on_progress) for lg in logs}
    return out
