"""Speed section ``localize`` of ``fingerloc bench speed``: streaming ``localize`` end to end.

Builds, in a temporary folder, a synthetic case: 1,000 places
of 8 views each (vertical edges ``VE``, extremities ``Ex`` and corners ``c``
around six random bearings per place, 3 deg noise) and labelled queries
drawn the same way; learns them with ``fingerloc learn --preset paper
--no-calibration``; then times the real command, ``fingerloc localize
QUERIES --db DB -q``, in fresh interpreters (the console script's own code,
``from fingerloc.cli import main; main()``) on two query files, the first
``small`` lines and all ``n`` of them.

Figures, each the best of ``repeat`` runs:

* ``*_wall_s`` / ``*_cpu_s``: wall and CPU (user + system of the child) seconds;
* ``steady_obs_per_s`` (wall) and ``steady_obs_per_cpu_s``: ``(n - small)``
  over the difference of the two runs' times: the rate once the fixed cost
  is paid; ``fixed_wall_s`` / ``fixed_cpu_s``: what is left of the small
  run's time (start-up, reading the database, loading the compiled kernels);
* ``end_to_end_obs_per_s``: ``n`` over the whole run's wall time;
* ``peak_rss_mb``: the largest resident size of a localize run;
* ``json_*``: one run of ``--json OUT`` on the small file (every record
  holds the posterior and each term over every place: 130 KB a record at
  1,000 places), its records a second and the output's size;
* ``load_average_1min``: the machine's load when the section ends.

The same code times another checkout when ``FINGERLOC_BENCH_SRC`` names its
``src`` folder (the child processes then import that fingerloc), which is how
docs/RESULTS.md's "before" column was measured.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from .speed import section

__all__ = ["localize_figures", "write_case"]


def write_case(folder: Path, *, places: int = 1000, views: int = 8, queries: int = 5000, seed: int = 0) -> tuple[Path, Path]:
    """Write ``train.jsonl`` (``places`` x ``views`` labelled views) and ``q.jsonl`` (``queries``) into ``folder``.

    Each place has six bearings drawn uniformly; a view adds Gaussian noise of
    3 deg to them (``VE``), to the first three plus 7 deg (``Ex``), and takes
    the first three noisy ``VE`` as corners (``c``). Queries are views of
    places drawn at random. Bearings are rounded to 1/1000 deg.
    """
    rng = np.random.default_rng(seed)
    base = [rng.uniform(0, 360, 6) for _ in range(places)]

    def rec(p: int, noise: float) -> str:
        ve = (base[p] + rng.normal(0, noise, 6)) % 360
        ex = (base[p][:3] + 7 + rng.normal(0, noise, 3)) % 360
        feats = {"VE": ve.round(3).tolist(), "Ex": ex.round(3).tolist(), "c": ve[:3].round(3).tolist()}
        return json.dumps({"place": f"p{p}", "features": feats}) + "\n"

    train, q = folder / "train.jsonl", folder / "q.jsonl"
    with train.open("w", encoding="utf-8") as f:
        for p in range(places):
            for _ in range(views):
                f.write(rec(p, 3.0))
    with q.open("w", encoding="utf-8") as f:
        for _ in range(queries):
            f.write(rec(int(rng.integers(places)), 3.0))
    return train, q


def _env() -> dict[str, str]:
    env = dict(os.environ)
    src = os.environ.get("FINGERLOC_BENCH_SRC")
    if src:
        env["PYTHONPATH"] = src + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def _fingerloc(args: list[str], cwd: Path) -> tuple[float, float, float]:
    """Run ``fingerloc ARGS`` in a fresh interpreter: (wall s, CPU s, peak resident MB); raises on failure."""
    cmd = [sys.executable, "-c", _CHILD, *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=cwd, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    assert proc.stderr is not None
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    proc.stderr.close()
    if proc.returncode != 0:
        raise RuntimeError(f"fingerloc {' '.join(args)} failed ({proc.returncode}): {err.decode(errors='replace')[-500:]}")
    peak = usage.ru_maxrss / 1024.0  # where /proc is missing; on Linux it keeps the parent's peak across fork + exec
    for line in err.decode(errors="replace").splitlines():
        if line.startswith(_HWM):
            peak = float(line[len(_HWM) :]) / 1024.0
    return wall, usage.ru_utime + usage.ru_stime, peak


#: The child's own peak resident size (VmHWM of /proc/self/status, kB), printed on stderr when it exits.
_HWM = "fingerloc-speed-vmhwm-kb="
_CHILD = f"""import atexit, sys
def _hwm():
    try:
        with open("/proc/self/status") as fh:
            kb = next(line.split()[1] for line in fh if line.startswith("VmHWM:"))
    except (OSError, StopIteration):
        return
    sys.stderr.write("{_HWM}" + kb + "\\n")
atexit.register(_hwm)
from fingerloc.cli import main
main()
"""


def localize_figures(
    *, places: int = 1000, queries: int = 5000, small: int = 1000, repeat: int = 3, json_run: bool = True
) -> dict[str, Any]:
    """Time ``fingerloc localize -q`` on ``small`` and ``queries`` observations against ``places`` places."""
    with tempfile.TemporaryDirectory(prefix="fingerloc-speed-") as d:
        folder = Path(d)
        _, q = write_case(folder, places=places, queries=queries)
        lines = q.read_text(encoding="utf-8").splitlines(keepends=True)
        (folder / "q_small.jsonl").write_text("".join(lines[:small]), encoding="utf-8")
        t0 = time.perf_counter()
        _fingerloc(["learn", "train.jsonl", "--db", "p.sqlite", "--preset", "paper", "--no-calibration"], folder)
        learn_s = time.perf_counter() - t0
        runs: dict[str, list[tuple[float, float, float]]] = {"small": [], "all": []}
        for _ in range(repeat):
            for key, name in (("small", "q_small.jsonl"), ("all", "q.jsonl")):
                runs[key].append(_fingerloc(["localize", name, "--db", "p.sqlite", "-q"], folder))
        best = {k: (min(r[0] for r in v), min(r[1] for r in v)) for k, v in runs.items()}
        rss = max(r[2] for v in runs.values() for r in v)
        extra = queries - small
        slope_wall = max(best["all"][0] - best["small"][0], 1e-9) / extra
        slope_cpu = max(best["all"][1] - best["small"][1], 1e-9) / extra
        out: dict[str, Any] = {
            "places": places,
            "views_per_place": 8,
            "queries": queries,
            "small_queries": small,
            "runs_each": repeat,
            "learn_wall_s": learn_s,
            "small_wall_s": best["small"][0],
            "small_cpu_s": best["small"][1],
            "all_wall_s": best["all"][0],
            "all_cpu_s": best["all"][1],
            "steady_obs_per_s": 1.0 / slope_wall,
            "steady_obs_per_cpu_s": 1.0 / slope_cpu,
            "fixed_wall_s": best["small"][0] - small * slope_wall,
            "fixed_cpu_s": best["small"][1] - small * slope_cpu,
            "end_to_end_obs_per_s": queries / best["all"][0],
            "peak_rss_mb": rss,
        }
        if json_run:
            wall, cpu, rss_j = _fingerloc(["localize", "q_small.jsonl", "--db", "p.sqlite", "-q", "--json", "out.json"], folder)
            out.update(
                json_wall_s=wall,
                json_cpu_s=cpu,
                json_records_per_s=small / wall,
                json_bytes_per_record=(folder / "out.json").stat().st_size / small,
                json_peak_rss_mb=rss_j,
            )
    out["load_average_1min"] = os.getloadavg()[0]
    return out


@section("localize")
def speed_localize(quick: bool) -> dict[str, Any]:
    """Streaming localize, paper preset, 1,000 places (100 with ``quick``), end to end in fresh processes."""
    if quick:
        return localize_figures(places=100, queries=600, small=200, repeat=1)
    return localize_figures()
