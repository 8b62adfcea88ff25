"""``fingerloc localize``: the posterior over places of every observation, scan or image."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from .._lazy import LazyAttr, LazyModule
from ..errors import InvalidParameterError
from ._io import JsonRecordStream, atomic_text_file, lit, warn
from .app import app, console, err_console
from .options import (
    BASE_FRAME_OPTION,
    KIND_OPTION,
    POSE_SOURCE_OPTION,
    SKIP_BAD_OPTION,
    TOPIC_OPTION,
    bag_options,
    check_output,
    read_run_files,
)

if TYPE_CHECKING:
    import numpy as np
    from rich.table import Table
else:  # imported when a command runs, not for --help
    np = LazyModule("numpy")
    Table = LazyAttr("rich.table", "Table")
read_observations = LazyAttr("fingerloc.io.jsonl", "read_observations")
compat = LazyModule("fingerloc.pipeline.compat")

@app.command("localize")
def localize_cmd(
    data: Path = typer.Argument(..., help="Observations to localize: JSON Lines, a CARMEN log or a ROS bag."),
    db: Path = typer.Option(..., "--db", help="Place database written by 'fingerloc learn' or 'fingerloc map'."),
    top: int = typer.Option(3, help="Places to print per observation."),
    json_out: Path | None = typer.Option(None, "--json", help="Write per-observation posteriors as JSON here."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print only the summary (no per-observation table)."),
    report: Path | None = typer.Option(
        None, "--report", help="Write a report folder here: index.html (open it in a browser) and its figures."
    ),
    kind: str = KIND_OPTION,
    topic: list[str] | None = TOPIC_OPTION,
    pose_source: str = POSE_SOURCE_OPTION,
    base_frame: str | None = BASE_FRAME_OPTION,
    skip_bad: bool = SKIP_BAD_OPTION,
    workers: int | None = typer.Option(
        None, "--workers", min=1, max=256, help="JSON Lines: answer chunks of observations on a local Dask cluster of this many processes."
    ),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="JSON Lines: answer chunks of observations on an existing Dask cluster (tcp://HOST:PORT)."
    ),
) -> None:
    """Answer "where am I?" for each observation: the posterior over the learned places.

    A CARMEN log or a bag is read with the database's preset. When its scans
    have poses and the database has place positions ('fingerloc map'),
    every scan within the map's radius of a place is a query labelled with
    its nearest place (on the very run the map was made from: only the scans
    after its mapping part), so the summary gives top-1 and mean rank.
    JSON Lines are read as a stream, a chunk of observations at a time, and
    the answers are written as they come (memory does not grow with the file).
    """
    from ..parallel import check_cluster_options
    from ..pipeline.placemap import load_map
    from ..pipeline.readers import detect_kind
    from .reports import check_report, localize_report

    if top < 1:
        raise InvalidParameterError(f"--top must be >= 1, got {top}")
    check_cluster_options(workers, scheduler)
    check_output(json_out, "--json")
    check_report(report)
    bag = bag_options(topic, pose_source, base_frame)
    if kind not in ("auto", "carmen", "bag", "jsonl"):
        raise InvalidParameterError(f"--kind must be one of auto, carmen, bag, jsonl, got {kind!r}")
    jsonl = kind == "jsonl" or (kind == "auto" and detect_kind(data) is None)
    cluster = workers is not None or scheduler is not None
    if cluster and not jsonl:
        raise InvalidParameterError("--workers/--scheduler: localize runs on Dask for JSON Lines input only")
    if cluster and report is not None:
        raise InvalidParameterError("--report keeps every answer in memory: give it without --workers/--scheduler")
    from ..pipeline.localize import shows_heading

    lm = load_map(db)
    model = lm.model
    classes = [str(c) for c in model.classes_]
    preset = None if lm.preset is None else lm.preset.name
    records = json_out is not None
    doubts: list[str] = []
    if cluster:
        chunks = _cluster_chunks(data, db, top, table=not quiet, records=records, workers=workers, scheduler=scheduler)
    elif jsonl and report is None:  # a stream: a chunk of lines at a time
        chunks = _serial_chunks(data, model, top, table=not quiet, records=records)
    else:
        run = read_run_files([data], kind=kind, skip_bad=skip_bad, bag=bag)
        doubts = compat.check_run(lm, run, what=str(data))  # another modality or frame: an error now; doubts below
        obs, names = lm.queries(run, on_note=lambda s: err_console.print(s, markup=False))
        keep = report is not None
        from ..pipeline.localize import LOCALIZE_CHUNK, answer_chunk

        chunks = (
            answer_chunk(model, obs[s : s + LOCALIZE_CHUNK], names[s:], s, top, table=not quiet, records=records, keep=keep)
            for s in range(0, len(obs), LOCALIZE_CHUNK)
        )
    rank_list: list[int] = []
    pairs: list[tuple[str, str]] = []  # (true, best) of every labelled observation, for the confusion matrix
    kept: list[tuple[Any, Any]] = []  # (log posterior, ranks) per chunk, for the report only
    n = 0
    with contextlib.ExitStack() as stack:
        stream = None
        if json_out is not None:
            stream = JsonRecordStream(stack.enter_context(atomic_text_file(json_out)), "observations")
        for answers in chunks:
            if stream is not None:
                for text, nulls in zip(answers.records, answers.nulls, strict=True):
                    stream.add_encoded(text, nulls)
            rank_list += [r for r in answers.rank_of_true if r > 0]
            pairs += answers.pairs
            if answers.rows:
                console.print(_answers_table(answers.rows, top, cyclic=shows_heading(model)))
            if report is not None:
                kept.append((answers.logp, answers.ranks))
            n += answers.n
        summary: dict[str, Any] = {"n": n, "top1": None, "mean_rank": None}
        if rank_list:
            summary["top1"] = float(np.mean(np.array(rank_list) == 1))
            summary["mean_rank"] = float(np.mean(rank_list))
        if stream is not None:
            stream.finish({"summary": summary, "preset": preset})
    if json_out is not None:
        err_console.print(lit(f"wrote {json_out}"))
    warn(doubts + compat.check_queries(len(rank_list)))  # said once the answers are out; few queries: rough figures
    if rank_list:
        console.print(
            f"right classification: {100 * summary['top1']:.1f}% of {len(rank_list)} labelled; "
            f"mean rank of the true place: {summary['mean_rank']:.2f}"
        )
        if not quiet:
            _print_confusion(pairs, classes)
    if report is not None:
        logp_all = np.vstack([k[0] for k in kept]) if kept else np.zeros((0, len(classes)))
        ranks_all = np.vstack([k[1] for k in kept]) if kept else np.zeros((0, len(classes)), dtype=np.int64)
        localize_report(report, model=model, observations=obs, log_proba=logp_all, ranks=ranks_all, data=data, db=db)


def _answers_table(rows: list[list[str]], top: int, *, cyclic: bool) -> Table:
    """The per-observation table of one chunk of answers."""
    tab = Table(show_header=True)
    for c in ("#", "true", "best", f"top {top} (posterior)", "rank of true") + (("heading",) if cyclic else ()):
        tab.add_column(c, overflow="fold")  # long place names wrap, never cut
    for row in rows:
        tab.add_row(*row)
    return tab


def _serial_chunks(data: Path, model: Any, top: int, *, table: bool, records: bool) -> Iterator[Any]:
    """Answers of a JSON Lines file, chunk after chunk, in this process (a stream: bounded memory)."""
    from ..pipeline.localize import answer_chunk
    from ._localize import jsonl_chunks, parse_lines

    for start, lines in jsonl_chunks(data):
        obs = parse_lines(data, lines)
        warn(compat.check_observations(model, obs, what=str(data)) if start == 0 else [])  # modality, field of view
        names = [f"{data.name}:{start + i + 1}" for i in range(len(obs))]
        yield answer_chunk(model, obs, names, start, top, table=table, records=records)


def _cluster_chunks(
    data: Path, db: Path, top: int, *, table: bool, records: bool, workers: int | None, scheduler: str | None
) -> Iterator[Any]:
    """Answers of a JSON Lines file from Dask tasks (a chunk of lines each), in input order, a bounded number in flight."""
    from ..errors import DataFormatError
    from ..parallel import iter_tasks
    from ._localize import LinesTask, answer_lines, file_sha256, jsonl_chunks

    sha = file_sha256(db)
    where = str(Path(db).absolute())
    tasks = (
        LinesTask(where, sha, str(Path(data).absolute()), start, lines, top, table, records)
        for start, lines in jsonl_chunks(data, LOCALIZE_TASK)
    )
    for res in iter_tasks(answer_lines, tasks, workers=workers, scheduler=scheduler):
        if isinstance(res, tuple):
            raise DataFormatError(res[1])
        yield res


#: Observations per Dask task of ``localize --workers`` (each task answers them in chunks of
#: ``pipeline.localize.LOCALIZE_CHUNK``, also 256: that module imports numpy, which ``--help`` must not).
LOCALIZE_TASK = 256


def _print_confusion(pairs: list[tuple[str, str]], classes: list[str]) -> None:
    """The confusion matrix of (true place, best place) pairs of the labelled observations."""
    truths = sorted({t for t, _ in pairs}, key=classes.index)
    cols = sorted({b for _, b in pairs} | set(truths), key=classes.index)
    if len(cols) > 30:
        console.print(
            f"(confusion matrix omitted: {len(cols)} places, more than 30; --report DIR draws the most confused ones)",
            soft_wrap=True,
            markup=False,
        )
        return
    t = Table(title="confusion (rows: true place, columns: best place)")
    t.add_column("true \\ best", overflow="fold")
    for c in cols:
        t.add_column(c, justify="right", overflow="fold")
    for tr in truths:
        counts = [sum(1 for t, b in pairs if t == tr and b == c) for c in cols]
        t.add_row(tr, *[str(x) if x else "." for x in counts])
    console.print(t)


