"""``fingerloc reproduce table1``: the paper's Table I (docs/METHOD.md §5)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from .._lazy import LazyAttr
from ._io import check_output
from .app import console, reproduce_app, trial_progress
from .bench import write_json

if TYPE_CHECKING:
    from rich.table import Table
else:
    Table = LazyAttr("rich.table", "Table")  # imported when the command runs, not for --help

# The defaults of fingerloc.experiments.table1 (DEFAULT_PLACE_SPREAD_DEG, DEFAULT_N_EDGES), repeated here so
# that the CLI starts without importing numba; tests/test_table1.py checks they agree.
PLACE_SPREAD_DEG = 10.0
N_EDGES = 6


@reproduce_app.command("table1")
def table1_cmd(
    trials: int = typer.Option(20, "--trials", min=1, max=100_000, help="Independent trials to average (new places each)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed of the places, noise and EM seeding."),
    json_out: Path | None = typer.Option(None, "--json", help="Write k, N, accuracy, stderr and paper as JSON."),
    place_spread_deg: float = typer.Option(
        PLACE_SPREAD_DEG,
        "--place-spread-deg",
        min=0.0,
        help="How alike the places are: std (deg) of each place's offset of the shared layout's edges "
        "(smaller = more alike).",
    ),
    n_edges: int = typer.Option(N_EDGES, "--edges", min=1, help="Edges of the shared office layout."),
    noise_deg: float = typer.Option(5.0, "--noise-deg", min=0.0, help="Bearing noise of an observation (deg std)."),
    held_out: bool = typer.Option(
        False,
        "--held-out",
        help="Score each observation against its place's mixture fit without it (default: with it, as the paper).",
    ),
    model: str = typer.Option(
        "draws",
        "--model",
        help="draws: an observation's features are drawn from its place's edges (default); "
        "fixed: every observation is its place's N bearings plus noise.",
    ),
    workers: int | None = typer.Option(
        None, "--workers", help="Run the trials on a local Dask cluster of this many processes (same results)."
    ),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="Run the trials on an existing Dask cluster: its scheduler address (tcp://host:8786)."
    ),
) -> None:
    """Classify 10 alike simulated places by MOG likelihood, k in {3,4,5}, N in {5..35}; print beside the paper."""
    from ..experiments.table1 import run_table1
    from ..parallel import check_cluster_options

    check_cluster_options(workers, scheduler)
    check_output(json_out, "--json")

    spread, edges = place_spread_deg, n_edges
    with trial_progress("Table I", trials) as on_trial:
        res = run_table1(
            trials=trials,
            seed=seed,
            place_spread_deg=spread,
            n_edges=edges,
            noise_deg=noise_deg,
            observation_model=model,
            evaluation="held-out" if held_out else "resubstitution",
            on_trial=on_trial,
            workers=workers,
            scheduler=scheduler,
        )
    acc, se, paper = res.accuracy * 100, res.stderr * 100, res.paper()
    table = Table(
        title=f"Table I: right classifications %, mean over {trials} trials, with its standard error, and the paper",
        caption=f"10 places alike (spread {spread:g} deg, {edges} edges, model {model}), 4 observations each, "
        f"noise {noise_deg:g} deg, seed {seed}" + (", held-out" if held_out else ""),
    )
    table.add_column("k", justify="right")
    table.add_column("", justify="left")
    for n in res.n:
        table.add_column(f"N={n}", justify="right")
    for a, k in enumerate(res.k):
        table.add_row(str(k), "ours", *[f"{v:.1f}" for v in acc[a]])
        table.add_row("", "± s.e.", *[f"{v:.1f}" for v in se[a]], style="dim")
        if paper is not None:
            table.add_row("", "paper", *[f"{v * 100:.1f}" for v in paper[a]], end_section=True)
    console.print(table)
    if paper is not None:
        diff = acc - paper * 100
        console.print(
            f"mean: ours {acc.mean():.1f}%, paper {paper.mean() * 100:.1f}%; "
            f"cell differences ours - paper: mean {diff.mean():+.1f}, rms {float((diff**2).mean() ** 0.5):.1f} points"
        )
    write_json(json_out, res.to_json())
