"""Real laser logs on the command line.

* ``fingerloc bench carmen``: the real-log place-recognition benchmark;
* :func:`format_scan_line`, how ``fingerloc features`` prints a laser scan's
  features (the readers themselves are the library's,
  :mod:`fingerloc.pipeline.readers` and :mod:`fingerloc.pipeline.files`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from ..errors import InvalidParameterError
from ._io import check_output
from .app import bench_app, console, err_console
from .bench import write_json

if TYPE_CHECKING:
    from ..observation import Observation
    from ..pipeline.files import LASER_KINDS
    from ..pipeline.readers import detect_kind

__all__ = ["LASER_KINDS", "carmen_cmd", "detect_kind", "format_scan_line", "print_benchmark"]


def __getattr__(name: str) -> Any:
    # re-exported from the library, imported on first use (not for --help)
    if name == "LASER_KINDS":
        from ..pipeline.files import LASER_KINDS

        return LASER_KINDS
    if name == "detect_kind":
        from ..pipeline.readers import detect_kind

        return detect_kind
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def format_scan_line(name: str, obs: Observation) -> str:
    """One line per scan: corners, extremities and beacons, bearings in degrees (robot frame, 0..360)."""
    from ..angles import rad_to_deg360

    def degs(a: Any) -> str:
        return " ".join(f"{x:.1f}" for x in rad_to_deg360(a)) if a.size else "-"

    label = f" [{obs.label}]" if obs.label else ""
    return f"{name}{label}  c({obs.c.size}): {degs(obs.c)} | Ex({obs.ex.size}): {degs(obs.ex)} | B({obs.b.size}): {degs(obs.b)}"


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3f}" if abs(v) < 1000 else f"{v:.4g}"
    return str(v)


def print_benchmark(js: dict[str, Any]) -> None:
    """Print a benchmark's JSON (from :meth:`BenchmarkRun.to_json`) as one aligned table (plain text)."""
    rows = [*js["logs"].items(), ("pooled", js["pooled"])]
    width = max([len("method"), *(len(m) for _, lg in rows for m in lg["methods"])])
    lw = max([len("log"), *(len(n) for n, _ in rows)])
    head = (
        f"{'log':<{lw}}  {'places':>6} {'train':>6} {'queries':>7}  {'method':<{width}}  "
        f"{'top1':>6} {'mean_rank':>9} {'recall5':>7} {'ms/query':>8} {'learn_s':>8}"
    )
    console.print(head, soft_wrap=True)
    console.print("-" * len(head), soft_wrap=True)
    for name, lg in rows:
        methods = lg["methods"] or {"-": {}}
        for k, (m, f) in enumerate(methods.items()):
            lead = (
                f"{name:<{lw}}  {lg['places']:>6} {lg['train']:>6} {lg['queries']:>7}"
                if k == 0
                else " " * (lw + 2 + 6 + 1 + 6 + 1 + 7)
            )
            figs = " ".join(
                f"{_fmt(f.get(key, '')):>{w}}"
                for key, w in (("top1", 6), ("mean_rank", 9), ("recall5", 7), ("ms_per_query", 8), ("learn_s", 8))
            )
            console.print(f"{lead}  {m:<{width}}  {figs}", soft_wrap=True)


@bench_app.command("carmen")
def carmen_cmd(
    logs: list[Path] | None = typer.Argument(
        None, metavar="LOG", help="CARMEN logs (.log, .log.gz, .clf), plain or gzip."
    ),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
    plot: Path | None = typer.Option(
        None, "--plot", help="Write a PNG: map, place centres, queries right (green) / wrong (red)."
    ),
    method: list[str] = typer.Option(
        [], "--method", "-m", help="Run only this method (repeatable; default: every default method)."
    ),
    plot_method: str | None = typer.Option(
        None, "--plot-method", help="Method whose answers colour the plot (default: the first fingerprint method)."
    ),
    skip_bad: bool = typer.Option(False, "--skip-bad", help="Skip malformed log lines and report how many."),
    list_methods: bool = typer.Option(False, "--list-methods", help="List the registered methods and exit."),
    report: Path | None = typer.Option(
        None, "--report", help="Write a report folder here: per log a map and a localize report of --plot-method."
    ),
    workers: int | None = typer.Option(
        None, "--workers", min=1, max=256, help="Run one task per log on a local Dask cluster of this many processes."
    ),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="Run one task per log on an existing Dask cluster (tcp://HOST:PORT)."
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of the methods that draw random numbers (the pose filters)."),
    odometry_error: float = typer.Option(
        1.0, "--odometry-error", min=0.0, help="Factor on every method's simulated odometry errors (0 = exact)."
    ),
    mapping_part: float = typer.Option(
        0.5, "--mapping-part", help="Fraction of each log that maps (a harder run: less than 0.5)."
    ),
    query_start: float = typer.Option(
        0.0, "--query-start", help="Fraction of the query pass left out at its start (the robot starts elsewhere)."
    ),
    query_cut: tuple[float, float] | None = typer.Option(
        None, "--query-cut", help="START LENGTH: a block of the query pass left out (fractions of it; a gap)."
    ),
    reverse: bool = typer.Option(False, "--reverse", help="Run the query pass backwards."),
) -> None:
    """Place recognition on CARMEN logs with the fixed protocol of `bench carmen`.

    First half of each log (scan index < n // 2) maps, the rest queries; a place
    every 2 m (strictly) of the mapping pass, training and query scans within
    1 m (inclusive) of a place centre. --mapping-part, --query-start,
    --query-cut and --reverse make a harder run than the protocol (recorded in
    the JSON's "protocol").
    """
    from ..experiments.carmen import DEFAULT_METHODS, METHODS, Hardening, load_methods, plot_benchmark, run_benchmark

    load_methods()
    if list_methods:
        for name in METHODS:
            console.print(f"{name}{'' if name in DEFAULT_METHODS else '  (run only when named)'}")
        raise typer.Exit()
    if not logs:
        raise InvalidParameterError("bench carmen needs at least one LOG (e.g. logs/*.log.gz)")
    from .reports import carmen_report, check_report

    check_output(json_out, "--json")
    check_output(plot, "--plot")
    check_report(report)
    from ..parallel import check_cluster_options

    check_cluster_options(workers, scheduler)
    hard = Hardening(seed=seed, odometry_error=odometry_error, mapping_part=mapping_part, query_start=query_start,
                     query_cut=query_cut, reverse=reverse)  # fmt: skip
    with err_console.status("benchmarking...") as status:
        run = run_benchmark(logs, method or None, skip_bad=skip_bad, on_progress=lambda s: status.update(s),
                            workers=workers, scheduler=scheduler, hardening=hard)  # fmt: skip
    js = run.to_json()
    for lg in run.logs:
        if lg.skipped:
            err_console.print(f"{lg.path}: skipped {lg.skipped} malformed line(s)", soft_wrap=True, markup=False)
    print_benchmark(js)
    write_json(json_out, js)
    if plot is not None:
        chosen = plot_method
        if chosen is None:
            chosen = next((m for m in run.method_names if m.startswith("fingerprint")), None)
        plot_benchmark(run, plot, method=chosen)
        err_console.print(f"wrote {plot}", soft_wrap=True, markup=False)
    if report is not None:
        carmen_report(report, run, plot_method or next((m for m in run.method_names if m.startswith("fingerprint")), None))
