"""``fingerloc track - --follow``: a run tracked line by line as it arrives, one JSON line out per step; and the
trajectories of ``track --tum / --kitti``.

Each input line is read (:mod:`fingerloc.io.stream`), stepped through the
streaming tracker (:class:`fingerloc.pipeline.follow.StreamStepper`), and its
answer written to standard output as one line of JSON (the ``track --json``
step record) and flushed, before the next line is read. ``--tum`` /
``--kitti`` get each pose as it comes (in a temporary file, put in place when
the stream ends); ``--json`` gets the ``track --json`` document at the end.
Ctrl-C, or a reader that closes the pipe, ends the stream like the end of the
input: what was tracked is written.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from ..errors import DataFormatError, InvalidParameterError
from ..io.stream import StreamItem, iter_stream
from ..io.trajectory import TrajectoryWriter
from ..ros.convert import answer_json
from ._io import check_output

__all__ = ["FollowResult", "follow_summary", "follow_track", "write_reference", "write_trajectories"]

Warn = Callable[[str], None]


@dataclass(slots=True)
class FollowResult:
    """What a followed stream gave: the answers, the lines skipped, the TUM stamps moved, how it ended."""

    answers: list[Any] = field(default_factory=list)
    skipped: int = 0
    nudged: int = 0
    ended: str = "end of input"


def _writers(tum: Path | None, kitti: Path | None) -> list[TrajectoryWriter]:
    out = []
    if tum is not None:
        out.append(TrajectoryWriter(tum, "tum", flush=True, strict=False))
    if kitti is not None:
        out.append(TrajectoryWriter(kitti, "kitti", flush=True))
    return out


def _add(writers: Sequence[TrajectoryWriter], ans: Any) -> None:
    pose = getattr(ans, "pose", None)
    if pose is None:
        return
    for w in writers:
        if w.fmt == "kitti" or ans.stamp is not None:
            w.add(pose, ans.stamp)


def _nudged_warning(writers: Sequence[TrajectoryWriter], warn: Warn) -> int:
    n = sum(w.nudged for w in writers)
    tum = next((w.path for w in writers if w.fmt == "tum"), None)
    if n:
        warn(f"warning: {n} step(s) whose timestamp did not increase were written to {tum} 1 us after the "
             "previous pose (TUM needs increasing timestamps)")  # fmt: skip
    return n


def write_trajectories(answers: Sequence[Any], *, tum: Path | None, kitti: Path | None, warn: Warn) -> None:
    """``track --tum / --kitti``: the answers' poses (those that have one), atomically.

    Raises
    ------
    InvalidParameterError
        ``--tum`` or ``--kitti`` without any pose to write (the place filter).
    """
    if tum is None and kitti is None:
        return
    if not any(getattr(a, "pose", None) is not None for a in answers):
        flag = "--tum" if tum is not None else "--kitti"
        raise InvalidParameterError(f"{flag}: no step has a pose (the pose filter gives one: --filter pose)")
    writers = _writers(tum, kitti)
    try:
        for a in answers:
            _add(writers, a)
    except BaseException:
        for w in writers:
            w.discard()
        raise
    for w in writers:
        w.close()
        warn(f"wrote {w.count} poses to {w.path}")
    _nudged_warning(writers, warn)


def write_reference(path: Path, stamps: Any, poses: Any, *, warn: Warn) -> None:
    """``map --tum``: a run's own poses at its timestamps (the scans' order when it has none), atomically."""
    import numpy as np

    if poses is None:
        raise InvalidParameterError("--tum: the run has no pose on every scan")
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    t = np.arange(p.shape[0], dtype=np.float64) if stamps is None else np.asarray(stamps, dtype=np.float64)
    if stamps is None:
        warn(f"warning: the run has no timestamps: {path} gets the scans' indices as seconds")
    w = TrajectoryWriter(path, "tum", strict=False)
    try:
        for ti, pi in zip(t.tolist(), p.tolist(), strict=True):
            w.add(pi, ti)
    except BaseException:
        w.discard()
        raise
    w.close()
    _nudged_warning([w], warn)
    warn(f"wrote {w.count} poses to {path}")


def follow_track(
    data: Path,
    step: Callable[[StreamItem], Any],
    *,
    kind: str = "auto",
    follow: bool = True,
    skip_bad: bool = False,
    idle_timeout: float | None = None,
    max_range: float | None = None,
    tum: Path | None = None,
    kitti: Path | None = None,
    quiet: bool = False,
    warn: Warn | None = None,
    out: TextIO | None = None,
) -> FollowResult:
    """Track ``data`` (``-``: standard input) line by line, ``step`` giving each item's answer.

    Every output path is checked before the first line is read; a malformed
    line raises :class:`~fingerloc.errors.DataFormatError` (``skip_bad``:
    ``warn`` gets it as a ``warning:`` line and the stream goes on).
    """
    stdout = out if out is not None else sys.stdout
    say = warn or (lambda s: None)
    check_output(tum, "--tum")
    check_output(kitti, "--kitti")
    if idle_timeout is not None and not idle_timeout > 0:
        raise InvalidParameterError(f"--idle-timeout must be a positive number of seconds, got {idle_timeout!r}")

    def on_error(err: DataFormatError) -> None:
        say(f"warning: {' '.join(str(err).split())}")

    reader = iter_stream(data, kind=kind, follow=follow, skip_bad=skip_bad, on_error=on_error,
                         idle_timeout_s=idle_timeout, max_range=max_range)  # fmt: skip
    writers = _writers(tum, kitti)
    res = FollowResult()
    try:
        try:
            for it in reader:
                ans = step(it)
                res.answers.append(ans)
                if not quiet:
                    stdout.write(answer_json(ans) + "\n")
                    stdout.flush()
                _add(writers, ans)
        except KeyboardInterrupt:
            res.ended = "interrupted"
        except BrokenPipeError:
            res.ended = "output closed"
            if out is None:  # the reader is gone: what is left for standard output goes nowhere
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, sys.stdout.fileno())
                os.close(devnull)
    except BaseException:
        for w in writers:
            w.discard()
        raise
    for w in writers:
        w.close()
    res.nudged = _nudged_warning(writers, say)
    res.skipped = reader.stats.skipped
    return res


def follow_summary(answers: Sequence[Any], labels: Sequence[str], filter_kind: str) -> dict[str, Any]:
    """The ``summary`` of a followed stream's ``--json``: steps, observed steps, places, filter, and the filtered
    top-1 / mean rank of the observed steps with a true place."""
    import numpy as np

    from ..experiments.protocol import rank_metrics, true_place_ranks

    col = {lab: j for j, lab in enumerate(labels)}
    observed = [a for a in answers if a.observed]
    known = [a for a in observed if a.true is not None and a.true in col]
    filtered: dict[str, Any] = {"labelled": len(known)}
    if known:
        lp = np.vstack([a.log_posterior for a in known])
        ranks = true_place_ranks(lp, np.array([col[a.true] for a in known], dtype=np.int64))
        filtered.update(rank_metrics(ranks))
    return {"steps": len(answers), "observed_steps": len(observed), "places": len(labels), "filter": filter_kind,
            "filtered": filtered}  # fmt: skip
