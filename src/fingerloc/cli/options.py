"""Options and checks shared by the commands that read runs and write place databases.

* model options (``-k``, ``--terms``, ``--costs``...) -> the JSON-form overrides
  of a preset (:func:`model_overrides`);
* the raw-run flags (``--kind``, ``--topic``, ``--pose-source``,
  ``--base-frame``, ``--skip-bad``) -> the library's readers;
* checks done before the first write (:func:`check_output`, :func:`check_db_target`).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from .._lazy import LazyModule
from ..errors import InvalidParameterError
from ._io import check_output
from .app import err_console

if TYPE_CHECKING:
    import numpy as np
else:
    np = LazyModule("numpy")  # imported when a command runs, not for --help

__all__ = [
    "BASE_FRAME_HELP",
    "BASE_FRAME_OPTION",
    "KIND_OPTION",
    "LOCK_TIMEOUT_OPTION",
    "POSE_SOURCE_HELP",
    "POSE_SOURCE_OPTION",
    "RUN_KIND_HELP",
    "SKIP_BAD_OPTION",
    "TOPIC_HELP",
    "TOPIC_OPTION",
    "bag_options",
    "check_db_target",
    "check_lock_timeout",
    "check_output",
    "model_overrides",
    "read_run_files",
]

RUN_KIND_HELP = "Input kind: auto | carmen | bag | jsonl (auto: from the name; JSON Lines otherwise)."
TOPIC_HELP = "ROS bag: the LaserScan topic (when there are several); repeat it to merge lidars into one observation per step."
POSE_SOURCE_HELP = "ROS bag: where poses come from: auto | none | tf[:FRAME] | odom[:TOPIC]."
BASE_FRAME_HELP = "ROS bag: the robot's frame (default: the root of the static transforms above the lidars)."

# The raw-run options of map, localize and track (one definition each).
KIND_OPTION = typer.Option("auto", "--kind", help=RUN_KIND_HELP)
TOPIC_OPTION = typer.Option(None, "--topic", help=TOPIC_HELP)
POSE_SOURCE_OPTION = typer.Option("auto", "--pose-source", help=POSE_SOURCE_HELP)
BASE_FRAME_OPTION = typer.Option(None, "--base-frame", help=BASE_FRAME_HELP)
SKIP_BAD_OPTION = typer.Option(False, "--skip-bad", help="Skip malformed log lines / bag messages and say how many.")
LOCK_TIMEOUT_OPTION = typer.Option(
    60.0,
    "--lock-timeout",
    help="Seconds to wait while another fingerloc writes the same --db (it says so) before giving up; inf: for ever.",
)

#: Largest ``-k`` / ``--components`` (mixture components per place and term).
MAX_COMPONENTS = 1000


def check_lock_timeout(value: float) -> float:
    """``--lock-timeout``: a number of seconds >= 0 (``inf`` waits for ever)."""
    if math.isnan(value) or value < 0:
        raise InvalidParameterError(f"--lock-timeout must be a number of seconds >= 0 (or inf), got {value!r}")
    return value


def bag_options(topic: str | list[str] | None, pose_source: str, base_frame: str | None) -> dict[str, Any]:
    """Keyword options of the bag reader from the command-line flags (checked before anything is read).

    Several ``--topic`` flags go to the reader as a tuple: lidars merged into
    one observation per time step (:func:`fingerloc.io.rosbag.iter_bag_scans`).
    """
    from ..io.rosbag import parse_pose_source

    parse_pose_source(pose_source)  # names --pose-source in its message
    topics = [topic] if isinstance(topic, str) else list(topic or [])
    picked: str | tuple[str, ...] | None = None if not topics else topics[0] if len(topics) == 1 else tuple(topics)
    return {"topic": picked, "pose_source": pose_source, "base_frame": base_frame}


def read_run_files(paths: list[Path], *, kind: str, skip_bad: bool, bag: dict[str, Any]) -> Any:
    """Read run files as one run (:func:`fingerloc.pipeline.readers.read_runs`), noting skipped lines."""
    from ..pipeline.readers import read_runs

    with err_console.status("reading..."):
        run = read_runs(paths, kind=kind, skip_bad=skip_bad, bag_options=bag)
    if run.skipped:
        err_console.print(f"skipped {run.skipped} malformed line(s) / message(s)", markup=False)
    return run


def check_db_target(db: Path, overwrite: bool) -> None:
    """A database about to be written as a whole: refuse to replace one without ``--overwrite``.

    The location is checked first (:func:`check_output`: a regular file or a
    new name in a writable folder), so a device, a FIFO or a symbolic link
    loop is refused even with ``--overwrite``.
    """
    check_output(db, "--db", stdout=False)
    if os.path.lexists(db) and not overwrite:
        raise InvalidParameterError(f"--db: {db} exists; give --overwrite to replace it (or another --db)")


def _parse_terms(text: str) -> tuple[str, ...]:
    from ..model import TERMS  # heavy (scipy, numba): imported when a command runs, not at start-up

    terms = tuple(t.strip() for t in text.replace("+", ",").split(",") if t.strip())
    for t in terms:
        if t not in TERMS:
            raise InvalidParameterError(f"--terms: unknown term {t!r} (expected some of {', '.join(TERMS)})")
    return terms


def _costs(name: str) -> str:
    if name not in ("unit", "feature"):
        raise InvalidParameterError(f"--costs must be 'unit' or 'feature', got {name!r}")
    return name


def model_overrides(
    *,
    components: int | None = None,
    terms: str | None = None,
    laser_letters: bool | None = None,
    fp_likelihood: str | None = None,
    fp_reference: str | None = None,
    cyclic: bool | None = None,
    costs: str | None = None,
    unknown_prior: float | None = None,
    weights: str | None = None,
    seed: int | None = None,
) -> dict[str, Any]:
    """The model options given on the command line (JSON form, see fingerloc.pipeline.presets); unset ones left out."""
    if components is not None and not 1 <= components <= MAX_COMPONENTS:
        raise InvalidParameterError(f"-k / --components must be an integer in [1, {MAX_COMPONENTS}], got {components}")
    if unknown_prior is not None and not (0 <= unknown_prior < 1):
        raise InvalidParameterError(f"--unknown-prior must be a probability in [0, 1), got {unknown_prior!r}")
    given: dict[str, Any] = {
        "n_components": components,
        "terms": None if terms is None else list(_parse_terms(terms)),
        "fp_likelihood": fp_likelihood,
        "fp_reference": fp_reference,
        "cyclic": cyclic,
        "laser_letters": laser_letters,
        "costs": None if costs is None else _costs(costs),
        "unknown_prior": unknown_prior,
        "weights": None if weights is None else _parse_weights(weights),
        "random_state": seed,
    }
    return {k: v for k, v in given.items() if v is not None}


def _parse_weights(text: str) -> str | dict[str, float]:
    """``fit`` or ``TERM=W,...`` -> the ``weights`` argument of PlaceModel."""
    if text.strip() == "fit":
        return "fit"
    out: dict[str, float] = {}
    for part in text.split(","):
        name, sep, value = part.partition("=")
        try:
            w = float(value)
        except ValueError:
            w = float("nan")
        if not sep or not name.strip() or not (math.isfinite(w) and w >= 0):
            raise InvalidParameterError(f"--weights: expected 'fit' or TERM=W,... with W >= 0, got {part!r}")
        out[name.strip()] = w
    return out


