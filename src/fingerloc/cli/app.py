"""The typer application objects shared by every command module."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

import typer

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

if TYPE_CHECKING:
    from rich.console import Console


class _LazyConsole:
    """A :class:`rich.console.Console` made on first use: ``--help`` needs no rich (its output is click's)."""

    def __init__(self, **kwargs: Any) -> None:
        self._kwargs = kwargs
        self._console: Console | None = None

    def resolve(self) -> Console:
        """The real console."""
        if self._console is None:
            from rich.console import Console

            self._console = Console(**self._kwargs)
        return self._console

    def __getattr__(self, name: str) -> Any:
        return getattr(self.resolve(), name)


#: Normal output.
console: Console = _LazyConsole(highlight=False, markup=False, emoji=False)  # type: ignore[assignment]
#: Progress bars and notes, on stderr so stdout stays clean for pipes.
err_console: Console = _LazyConsole(stderr=True, highlight=False, markup=False, emoji=False, soft_wrap=True)  # type: ignore[assignment]


def real_console(c: Console) -> Console:
    """The rich console behind ``c`` (:data:`console`, :data:`err_console` or a real one), for rich's own classes."""
    return c.resolve() if isinstance(c, _LazyConsole) else c


@contextmanager
def trial_progress(label: str, total: int) -> Iterator[Callable[[int], None]]:
    """A progress bar on stderr over ``total`` trials; yields ``on_trial(done)``."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(
        TextColumn(label),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=real_console(err_console),
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
