"""``fingerloc track - --follow``: a run tracked line by line as it arrives, one JSON line out per step.

Each input line is read (:mod:`fingerloc.io.stream`), stepped through the
streaming tracker, and its answer written to standard output as one line of
JSON (the ``track --json`` step record) and flushed, before the next line is
read. ``--tum`` / ``--kitti`` get each pose as it comes (in a temporary file,
put in place when the stream ends); ``--json`` gets the whole ``track --json``
document at the end. Ctrl-C, or a reader that closes the pipe, ends the stream
like the end of the input: what was tracked is written.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from ..errors import DataFormatError, InvalidParameterError
from ..io.stream import StreamItem, iter_stream
from ..io.trajectory import TrajectoryWriter
from ..ros.convert import answer_json
from ._io import check_output, write_json

__all__ = ["FollowResult", "follow_track"]

#: What the loop gives the tracker for one item: ``(item, odometry, stamp)``.
StepInputs = Callable[[StreamItem], tuple[Any, Any, Any]]


def default_inputs(item: StreamItem) -> tuple[Any, Any, Any]:
    """The item's scan or observation, its odometry pose (else its pose), its stamp."""
    return item.item, item.odometry if item.odometry is not None else item.pose, item.stamp


@dataclass(slots=True)
class FollowResult:
    """What a followed stream gave: the answers, the lines skipped, the TUM stamps moved, how it ended."""

    answers: list[Any] = field(default_factory=list)
    skipped: int = 0
    nudged: int = 0
    ended: str = "end of input"


def follow_track(
    data: Path,
    tracker: Any,
    *,
    kind: str = "auto",
    follow: bool = True,
    skip_bad: bool = False,
    idle_timeout: float | None = None,
    max_range: float | None = None,
    tum: Path | None = None,
    kitti: Path | None = None,
    quiet: bool = False,
    inputs: StepInputs = default_inputs,
    warn: Callable[[str], None] | None = None,
    out: TextIO | None = None,
) -> FollowResult:
    """Track ``data`` (``-``: standard input) with ``tracker`` (``step(item, odometry=, stamp=)``) line by line.

    Every output path is checked before the first line is read; a malformed
    line raises :class:`~fingerloc.errors.DataFormatError` (``skip_bad``:
    ``warn`` gets it and the stream goes on).
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
    writers = [w for w in (TrajectoryWriter(tum, "tum", flush=True, strict=False) if tum else None,
                           TrajectoryWriter(kitti, "kitti", flush=True) if kitti else None) if w is not None]  # fmt: skip
    res = FollowResult()
    try:
        try:
            for it in reader:
                item, odometry, stamp = inputs(it)
                ans = tracker.step(item, odometry=odometry, stamp=stamp)
                res.answers.append(ans)
                if not quiet:
                    stdout.write(answer_json(ans) + "\n")
                    stdout.flush()
                pose = getattr(ans, "pose", None)
                if pose is not None:
                    for w in writers:
                        if w.fmt == "kitti" or ans.stamp is not None:
                            w.add(pose, ans.stamp)
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
        if w.fmt == "tum":
            res.nudged = w.nudged
    res.skipped = reader.stats.skipped
    if res.nudged:
        say(f"warning: {res.nudged} step(s) whose timestamp did not increase were written to {tum} "
            f"1 us after the previous pose (TUM needs increasing timestamps)")  # fmt: skip
    return res


def write_follow_json(json_out: Path | None, res: FollowResult, summary: dict[str, Any]) -> None:
    """The ``track --json`` document of a followed stream: every step's record and the summary."""
    write_json(json_out, {"steps": [a.to_json() for a in res.answers], "summary": summary})
