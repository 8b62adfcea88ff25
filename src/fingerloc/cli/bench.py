"""``fingerloc bench ...`` commands."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from .app import bench_app, console, err_console


def write_json(path: Path | None, data: object) -> None:
    """Write ``data`` as indented JSON to ``path`` (when given), atomically."""
    if path is None:
        return
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    tmp.replace(path)
    err_console.print(f"wrote {path}")


@bench_app.command("speed")
def speed_cmd(
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
    only: list[str] = typer.Option([], "--only", help="Run only this section (repeatable)."),
    quick: bool = typer.Option(False, "--quick", help="Smaller sizes, for a smoke test."),
) -> None:
    """Time the hot kernels (mixtures, alignment, localization) and print the figures."""
    from ..experiments.speed import run_speed

    with err_console.status("benchmarking...") as status:
        res = run_speed(only or None, quick=quick, on_section=lambda n: status.update(f"benchmarking {n}..."))
    for name, figs in res.items():
        console.print(f"[bold]{name}[/bold]")
        for k, v in figs.items():
            console.print(f"  {k}: {v:.4g}" if isinstance(v, float) else f"  {k}: {v}")
    write_json(json_out, res)
