"""The typer application objects shared by every command module."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from .._version import __version__

app = typer.Typer(
    name="fingerloc",
    help="Topological global localization with fingerprints and Bayesian programming.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
bench_app = typer.Typer(help="Speed and accuracy benchmarks (print, and write JSON with --json).", no_args_is_help=True)
reproduce_app = typer.Typer(help="Reproduce the paper's tables.", no_args_is_help=True)
app.add_typer(bench_app, name="bench")
app.add_typer(reproduce_app, name="reproduce")

#: Normal output.
console = Console(highlight=False, markup=False, emoji=False)
#: Progress bars and notes, on stderr so stdout stays clean for pipes.
err_console = Console(stderr=True, highlight=False, markup=False, emoji=False, soft_wrap=True)


@contextmanager
def trial_progress(label: str, total: int) -> Iterator[Callable[[int], None]]:
    """A progress bar on stderr over ``total`` trials; yields ``on_trial(done)``."""
    with Progress(
        TextColumn(label),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=err_console,
        transient=True,
    ) as progress:
        task = progress.add_task("trials", total=total)
        yield lambda done: progress.update(task, completed=done)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"fingerloc {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Topological global localization with fingerprints and Bayesian programming."""
