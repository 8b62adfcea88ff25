"""``fingerloc demo``: the whole story on simulated offices, with a report folder.

Simulate the paper's robot experiment once (ten offices alike, raw laser scans
and omnidirectional images), extract the features, learn the places, localize
the test measurements, print the paper-style tables beside the paper's
figures, and write a report folder (Markdown page, PNG figures, JSON).
"""

from __future__ import annotations

import time
from pathlib import Path

import typer

from ._io import check_output
from .app import app, console, err_console, real_console
from .robot import WORLD_HELP


@app.command("demo")
def demo_cmd(
    out: Path = typer.Option(Path("fingerloc-report"), "--out", help="Report folder (created; files overwritten)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed of the offices, poses and sensor noise."),
    quick: bool = typer.Option(False, "--quick", help="Four small offices and small images: a smoke test in seconds."),
    workers: int | None = typer.Option(
        None, "--workers", min=1, help="Processes simulating offices (default: cores, at most 4)."
    ),
    random_heading: bool = typer.Option(
        False, "--random-heading", help="Also the random-heading rows (not in the paper; about 10 s more)."
    ),
    world: str = typer.Option(
        "paper",
        "--world",
        help=WORLD_HELP,
    ),
) -> None:
    """Simulate 10 offices, extract features from raw scans and images, learn, localize, print tables, write a report."""
    from ..errors import InvalidParameterError
    from ..experiments.report import write_demo_report
    from ..experiments.robot import (
        WORLD_PROFILES,
        RobotProtocol,
        RobotResult,
        default_workers,
        evaluate_trial,
        simulate_trial,
        simulation_pool,
    )
    from ..experiments.robot import small_protocol as small

    check_output(out, "--out", directory=True)
    if world not in WORLD_PROFILES:
        raise InvalidParameterError(f"--world must be one of {', '.join(WORLD_PROFILES)}, got {world!r}")
    if quick:
        protocol = small(world=world, random_heading=random_heading)
    else:
        protocol = RobotProtocol(world=world, random_heading=random_heading)
    n_workers = default_workers() if workers is None else workers
    timings: dict[str, float] = {}
    n_meas = protocol.n_offices * (protocol.n_train + (2 if random_heading else 1) * protocol.n_test)
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        TimeElapsedColumn(),
        console=real_console(err_console),
        transient=True,
    ) as progress:
        task = progress.add_task(
            f"simulating {protocol.n_offices} offices, {n_meas} scans and omnidirectional images, "
            f"extracting features ({n_workers} process{'es' if n_workers > 1 else ''})"
        )
        t0 = time.perf_counter()
        with simulation_pool(n_workers) as ex:
            data = simulate_trial(protocol, (seed, 0), keep_raw=[0], executor=ex)
        timings["simulate + extract features"] = time.perf_counter() - t0
        progress.update(task, description="learning the places, localizing the test measurements")
        t0 = time.perf_counter()
        ev = evaluate_trial(data, protocol, random_state=seed)
        timings["learn + localize (all tables)"] = time.perf_counter() - t0
        res = RobotResult(protocol=protocol, seed=seed, trials=[ev])
        progress.update(task, description=f"writing the report to {out}")
        t0 = time.perf_counter()
        page = write_demo_report(out, data, ev, res, timings=timings)
        timings["figures + report"] = time.perf_counter() - t0

    from ..experiments.robot_findings import REFERENCE_RUN, reference_story
    from .robot import print_findings, print_robot_tables, print_term_scale

    console.print(
        f"fingerloc demo: {protocol.n_offices} simulated offices alike "
        f"(world {world}, similarity {protocol.office_similarity:g}), "
        f"{protocol.n_train} training + {protocol.n_test} test measurements each, features from raw sensor data"
    )
    for line in reference_story():
        console.print(line, soft_wrap=True)
    if world != REFERENCE_RUN["world"]:
        console.print(f"  (those figures are for world {REFERENCE_RUN['world']}; this run's world is {world})")
    n_q = len(ev.truth)
    console.print(f"This trial alone ({n_q} test queries: most differences lie within its noise):")
    print_findings(res, console, title_note=f"seed {seed}")
    print_robot_tables(res, console, title_note=f"seed {seed}")
    print_term_scale(res, console)
    total = sum(timings.values())
    console.print(
        f"report: {page} (map, scan, panorama, fingerprint, mixture, posterior, confusion matrix); {total:.1f} s in all"
    )
    console.print("average over many trials: fingerloc reproduce robot --trials 20")
