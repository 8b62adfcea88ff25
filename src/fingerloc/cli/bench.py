"""``fingerloc bench ...`` commands."""

from __future__ import annotations

from pathlib import Path

import typer

from ._io import check_output, write_json
from .app import bench_app, console, err_console

__all__ = ["write_json"]


@bench_app.command("speed")
def speed_cmd(
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
    only: list[str] = typer.Option([], "--only", help="Run only this section (repeatable)."),
    quick: bool = typer.Option(False, "--quick", help="Smaller sizes, for a smoke test."),
) -> None:
    """Time the hot kernels (mixtures, alignment, localization) and print the figures."""
    from ..experiments.speed import run_speed

    check_output(json_out, "--json")

    with err_console.status("benchmarking...") as status:
        res = run_speed(only or None, quick=quick, on_section=lambda n: status.update(f"benchmarking {n}..."))
    for name, figs in res.items():
        console.print(name, style="bold")
        for k, v in figs.items():
            console.print(f"  {k}: {v:.4g}" if isinstance(v, float) else f"  {k}: {v}")
    write_json(json_out, res)
