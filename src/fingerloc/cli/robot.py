"""``fingerloc reproduce robot``: the paper's Tables II-IV in simulation (docs/METHOD.md §5)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from .._lazy import LazyAttr
from ._io import check_output
from .app import console, reproduce_app, trial_progress
from .bench import write_json

#: The ``--world`` option's help (``reproduce robot`` and ``demo``).
WORLD_HELP = (
    "Simulated offices and robot: 'paper' (calibrated to the paper's Tables II and III; the test "
    "measurements at a later visit: chairs moved, doors closed, people, daylight, the robot's heading), "
    "'paper-static' (the same, nothing changed between visits), 'paper-ideal' (the paper world seen with "
    "perfect perception and the same heading at both visits) or 'alike' (the original)."
)

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table

    from ..experiments.robot import RobotResult
else:
    Table = LazyAttr("rich.table", "Table")  # imported when a command runs, not for --help

_METHOD_NAMES = {
    "minimum_energy": "string matching, minimum energy",
    "global_alignment": "string matching, global alignment",
}


def _ci(mean: float, ci: tuple[float, float] | None, fmt: str, scale: float = 1.0) -> str:
    """``mean [low, high]`` (the interval omitted when undefined)."""
    if ci is None:
        return f"{scale * mean:{fmt}}"
    return f"{scale * mean:{fmt}} [{scale * ci[0]:{fmt}}, {scale * ci[1]:{fmt}}]"


def print_robot_tables(res: RobotResult, out: Console, *, title_note: str = "") -> None:
    """Print Tables II-IV and the random-heading row of a :class:`~fingerloc.experiments.robot.RobotResult`."""
    from ..experiments.robot import PAPER_TABLE2, PAPER_TABLE3, PAPER_TABLE4, TABLE4_NAMES, WORLD_PROFILES

    n = len(res.trials)
    avg = f"mean over {n} trials [95% CI]" if n > 1 else "one trial [95% CI over its queries]"
    note = f" ({title_note})" if title_note else ""
    fci = res.feature_ci()
    cci = res.cell_ci()

    t2 = Table(title=f"Table II: mean features per measurement, {avg}{note}")
    t2.add_column("feature")
    t2.add_column("ours", justify="right")
    t2.add_column("paper", justify="right")
    names = {
        "VE": "vertical edges VE",
        "Ex": "extremities Ex",
        "CP": "colour patches CP",
        "B": "beacons B",
        "c": "corners c",
    }
    for t, (m, _s) in res.feature_stats().items():
        paper = PAPER_TABLE2.get(t)
        t2.add_row(names[t], _ci(m, fci[t], ".1f"), "-" if paper is None else f"{paper:.1f}")
    out.print(t2)

    cells = res.cell_stats()
    fitted = WORLD_PROFILES[res.protocol.world].get("calibrated_on", [])
    t3_note = " (calibrated: the robot's perception errors and heading were fit to it)" if "table3" in fitted else ""
    t4_note = " (predicted: nothing was fit to it)" if "table3" in fitted else ""
    t3 = Table(title=f"Table III: string matching, right classification % / mean rank, {avg}{t3_note}")
    t3.add_column("method")
    t3.add_column("ours %", justify="right")
    t3.add_column("ours rank", justify="right")
    t3.add_column("paper", justify="right")
    for key, label in _METHOD_NAMES.items():
        a, _, r, _ = cells[("table3", key)]
        ca, cr = cci[("table3", key)]
        pa, pr = PAPER_TABLE3[key]
        t3.add_row(label, _ci(a, ca, ".1f", 100), _ci(r, cr, ".2f"), f"{100 * pa:.1f} / {pr:.2f}")
    out.print(t3)

    ks = list(res.protocol.ks)
    t4 = Table(title=f"Table IV: Bayesian program, right classification % / mean rank, {avg}{t4_note}")
    t4.add_column("terms")
    t4.add_column("", justify="left")
    for k in ks:
        t4.add_column(f"k={k}", justify="right")
    for row, label in TABLE4_NAMES.items():
        if ("table4", row, str(ks[0])) not in cells:
            continue
        ours = []
        for k in ks:
            a, _, r, _ = cells[("table4", row, str(k))]
            ca, cr = cci[("table4", row, str(k))]
            ours.append(f"{_ci(a, ca, '.1f', 100)} / {_ci(r, cr, '.2f')}")
        t4.add_row(label, "ours", *ours)
        paper_cells = [
            f"{100 * PAPER_TABLE4[row][k][0]:.1f} / {PAPER_TABLE4[row][k][1]:.2f}"
            if k in PAPER_TABLE4.get(row, {})
            else "-"
            for k in ks
        ]
        t4.add_row("", "paper", *paper_cells, style="dim", end_section=True)
    out.print(t4)

    if ("random_heading", "global_alignment") in cells:
        tr = Table(title=f"Random heading, cyclic matching (not in the paper), {avg}")
        tr.add_column("method")
        tr.add_column("right %", justify="right")
        tr.add_column("mean rank", justify="right")
        a, _, r, _ = cells[("random_heading", "global_alignment")]
        ca, cr = cci[("random_heading", "global_alignment")]
        tr.add_row("string matching, cyclic global alignment", _ci(a, ca, ".1f", 100), _ci(r, cr, ".2f"))
        for k in ks:
            a, _, r, _ = cells[("random_heading", "VE+Ex+Fp", str(k))]
            ca, cr = cci[("random_heading", "VE+Ex+Fp", str(k))]
            tr.add_row(
                f"VE, Ex & fingerprint, k={k}, heading from cyclic alignment",
                _ci(a, ca, ".1f", 100),
                _ci(r, cr, ".2f"),
            )
        out.print(tr)
        err = res.heading_error_deg()
        if err is not None:
            out.print(f"median heading error of the cyclic alignment (true place): {err:.1f} deg")


def print_findings(res: RobotResult, out: Console, *, title_note: str = "") -> None:
    """The paper's findings beside ours, with a verdict each (:func:`~fingerloc.experiments.robot_findings.paper_findings`)."""
    n = len(res.trials)
    how = f"paired over {n} trials" if n > 1 else "paired over this trial's test queries"
    note = f" ({title_note})" if title_note else ""
    t = Table(title=f"The paper's findings: difference in right classification, points, 95% CI {how}{note}")
    t.add_column("finding")
    t.add_column("paper", justify="right")
    t.add_column("ours", justify="right")
    t.add_column("verdict")
    for f in res.findings():
        t.add_row(f.claim, f"{100 * f.paper:+.1f}", _ci(f.ours, f.ci95, "+.1f", 100), f.verdict)
    out.print(t)


def print_term_scale(res: RobotResult, out: Console) -> None:
    """How far each term of the program moves the places, and the weights fit on the training views."""
    stats = res.term_stats()
    if not stats:
        return
    t = Table(
        title="Why the string adds little with the paper's P(Fp) = 1/(cost+1): how far each term moves the places "
        "(median over queries of its log-likelihood range over the places, nats), mean over trials"
    )
    t.add_column("k")
    for name in ("VE", "Ex", "Fp, 1/(cost+1)", "Fp, exp(-λ cost)", "λ", "fitted weights VE / Ex / Fp"):
        t.add_column(name, justify="right")
    for k, st in stats.items():
        sp, w = st["spread_nats"], st["fitted_weights"]
        lam = st.get("fp_lambda")
        t.add_row(
            k,
            f"{sp['VE']:.1f}",
            f"{sp['Ex']:.1f}",
            f"{sp['Fp']:.2f}",
            f"{sp.get('Fp-exp', float('nan')):.1f}",
            "-" if lam is None else f"{lam:.2f}",
            " / ".join(f"{w.get(name, float('nan')):.2f}" for name in ("VE", "Ex", "Fp")),
        )
    out.print(t)


def calibration_checks(res: RobotResult) -> list[tuple[str, bool, str]]:
    """What the ``paper`` world is calibrated to: (check, met, detail) for Table II (20 %) and Table III (5 points)."""
    from ..experiments.robot import PAPER_TABLE2, PAPER_TABLE3

    cells = res.cell_stats()
    fs = res.feature_stats()
    off = {t: fs[t][0] / v - 1.0 for t, v in PAPER_TABLE2.items()}
    t3 = {m: cells[("table3", m)][0] for m in PAPER_TABLE3}
    return [
        (
            "Table II means within 20% of the paper's",
            all(abs(v) <= 0.2 for v in off.values()),
            ", ".join(f"{t} {fs[t][0]:.1f} ({100 * v:+.0f}%)" for t, v in off.items()),
        ),
        (
            "Table III within 5 points of the paper's",
            all(abs(v - PAPER_TABLE3[m][0]) <= 0.05 for m, v in t3.items()),
            ", ".join(
                f"{_METHOD_NAMES[m].split(', ')[1]} {100 * v:.1f}% (paper {100 * PAPER_TABLE3[m][0]:.1f}%)"
                for m, v in t3.items()
            ),
        ),
    ]


def print_verdict(res: RobotResult, out: Console) -> None:
    """The calibration's targets, checked on the measured means, then the paper's findings."""
    for what, ok, detail in calibration_checks(res):
        out.print(f"{what}: {'yes' if ok else 'no'} ({detail})")
    print_findings(res, out)
    print_term_scale(res, out)


@reproduce_app.command("robot")
def robot_cmd(
    trials: int = typer.Option(
        10, "--trials", min=1, max=10_000, help="Independent trials to average (new offices each)."
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed of the offices, poses, sensor noise and EM."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the tables (top1 in [0, 1]) as JSON."),
    similarity: float | None = typer.Option(
        None, "--similarity", min=0.0, max=1.0, help="How alike the offices are (default: the world's, 0.8 / 0.5)."
    ),
    world: str = typer.Option(
        "paper",
        "--world",
        help=WORLD_HELP,
    ),
    workers: int | None = typer.Option(
        None,
        "--workers",
        help="Run one task per trial on a local Dask cluster of N processes (default: a process pool of the "
        "cores, at most 4; 1: in this process).",
    ),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="Run one task per trial on an existing Dask cluster (tcp://HOST:PORT)."
    ),
    quick: bool = typer.Option(
        False, "--quick", help="Four small offices and small images: a smoke test, not the protocol."
    ),
    random_heading: bool = typer.Option(
        True, "--random-heading/--no-random-heading", help="Also run the random-heading rows (not in the paper)."
    ),
) -> None:
    """Simulate the paper's robot experiment (10 offices, 8 training + 2 test measurements each) and print Tables II-IV."""
    from ..errors import InvalidParameterError
    from ..experiments.robot import WORLD_PROFILES, RobotProtocol, run_robot, small_protocol
    from ..parallel import check_cluster_options

    check_cluster_options(workers, scheduler)
    check_output(json_out, "--json")
    if world not in WORLD_PROFILES:
        raise InvalidParameterError(f"--world must be one of {', '.join(WORLD_PROFILES)}, got {world!r}")
    if quick:
        protocol = small_protocol(similarity=similarity, world=world, random_heading=random_heading)
    else:
        protocol = RobotProtocol(similarity=similarity, world=world, random_heading=random_heading)
    with trial_progress("robot experiment", trials) as on_trial:
        res = run_robot(
            trials=trials,
            seed=seed,
            protocol=protocol,
            workers=workers,
            on_trial=on_trial,
            scheduler=scheduler,
        )
    sim_note = f"world {world}, similarity {protocol.office_similarity:g}"
    print_robot_tables(res, console, title_note=f"{sim_note}, seed {seed}")
    print_verdict(res, console)
    write_json(json_out, res.to_json())
