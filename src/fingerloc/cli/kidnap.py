"""``fingerloc bench kidnap``: the kidnapped-robot experiment on CARMEN logs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from ..errors import InvalidParameterError
from ._io import check_output
from .app import bench_app, console, err_console
from .bench import write_json

__all__ = ["kidnap_cmd"]


@bench_app.command("kidnap")
def kidnap_cmd(
    logs: list[Path] = typer.Argument(..., help="CARMEN logs (.log, .log.gz)."),
    base: str = typer.Option("fingerprint", help="Single-shot method under the filter (a 'bench carmen' name)."),
    trials: int = typer.Option(20, help="Kidnappings per log."),
    stretch: int = typer.Option(40, help="Steps before and after the kidnapping."),
    min_jump: float = typer.Option(10.0, "--min-jump", help="Metres between the two spliced stretches, at least."),
    synthetic: float | None = typer.Option(
        None, help="Replace the method's scores by a synthetic sensor: true place + this many sigma."
    ),
    seed: int = typer.Option(0, help="Seed of the trials' choice (and of the synthetic sensor, odometry, particles)."),
    filter_kind: str = typer.Option(
        "places", "--filter", help="'places': the discrete filter over places; 'pose': the pose particle filter."
    ),
    odometry_error: float = typer.Option(
        1.0, "--odometry-error", help="Pose filter: factor on the simulated odometry's errors (0 = exact)."
    ),
    kidnap: float | None = typer.Option(
        None, "--kidnap-prob", help="Pose filter: kidnapping probability per observation [1 / (training scans + 2)]."
    ),
    hold_margin: float | None = typer.Option(
        None, "--hold-margin", help="Pose filter: between observations keep the previous best place unless another "
        "place's probability exceeds it by this much [0.05; 0 = the argmax]."
    ),
    tie_break: float | None = typer.Option(
        None, "--tie-break", help="Pose filter: between observations, among the places within this probability of "
        "the answer, the one the discrete place filter believes most [0.02; 0 = exact ties only]."
    ),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures and trials as JSON here."),
) -> None:
    """Kidnapped robot: splice two distant stretches of each log's query pass; steps until the filter recovers.

    Recovery = steps after the jump until the kidnapped filter's best place
    agrees with that of the filter that was never kidnapped, for good
    ('agree': at every later step of the stretch; 'at obs': at every later
    observed step, where an answer is scored).

    Second table, what is recovery and what is noise. 'floor': the same two
    criteria applied to a second never-kidnapped run (other random draws)
    against the reference on the same stretch; nothing was kidnapped, so its
    fraction within 10 steps is the best the column can show for this filter
    ('dis': the fraction of steps where the two unkidnapped runs disagree;
    the discrete filter over places is deterministic: floor 1.00, dis 0).
    'truth': steps until the best place is the true place (the corrected
    pose within its radius) at every later observed step, at least one, for
    the kidnapped filter and for the reference ('ref', its floor); 'cell': the same
    against the nearest place centre of the corrected pose at every step.
    'top-1 kid / ref': fraction of the stretches' observed steps at the true
    place after the kidnapping, and in the never-kidnapped run.
    """
    from ..experiments.kidnap import run_kidnap

    check_output(json_out, "--json")
    if filter_kind not in ("places", "pose"):
        raise InvalidParameterError(f"--filter must be 'places' or 'pose', got {filter_kind!r}")
    with err_console.status("kidnapping...") as status:
        res = run_kidnap(
            logs,
            base=base,
            n_trials=trials,
            stretch=stretch,
            min_jump_m=min_jump,
            seed=seed,
            synthetic=synthetic,
            pose=filter_kind == "pose",
            odometry_error=odometry_error,
            kidnap=kidnap,
            hold_margin=hold_margin,
            tie_break=tie_break,
            on_progress=lambda s: status.update(s),
        )
    rows = [*((n, lg["summary"]) for n, lg in res["logs"].items()), ("pooled", res["pooled"])]
    head = (
        f"{'log':<14} {'trials':>6} | {'agree':>5} {'steps':>6} {'obs':>5} {'<=10':>5} | {'at obs':>6} {'<=10':>5} | "
        f"{'merged':>6} {'steps':>6} {'obs':>5} | {'1st right':>9} {'ref':>5}"
    )
    console.print("recovery after a kidnapping (medians; agree = best place as the never-kidnapped filter's, "
                  "at obs = the same compared at observed steps only, "
                  "merged = posteriors within 0.1 total variation)", soft_wrap=True)  # fmt: skip
    console.print(head, soft_wrap=True)
    console.print("-" * len(head), soft_wrap=True)

    def f(v: Any, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    for name, s in rows:
        console.print(
            f"{name:<14} {s['trials']:>6} | {s['recovered']:>5} {f(s['median_recover_steps'], '.1f'):>6} "
            f"{f(s['median_recover_observations'], '.1f'):>5} {f(s['within_10'], '.2f'):>5} | "
            f"{f(s['median_recover_observed_steps'], '.1f'):>6} {f(s['observed_within_10'], '.2f'):>5} | "
            f"{s['merged']:>6} {f(s['median_merge_steps'], '.1f'):>6} {f(s['median_merge_observations'], '.1f'):>5} | "
            f"{f(s['median_first_right_steps'], '.1f'):>9} {f(s['median_reference_first_right_steps'], '.1f'):>5}",
            soft_wrap=True,
        )
    head2 = (
        f"{'log':<14} | {'floor':>5} {'at obs':>6} {'dis':>5} | {'truth':>5} {'ref':>5} | {'cell':>5} {'ref':>5} | "
        f"{'top-1 kid':>9} {'ref':>5}"
    )
    console.print("fraction of trials settled within 10 steps: a second never-kidnapped run (floor, all steps / "
                  "observed steps; dis = its per-step disagreement), the true place at observed steps (truth, "
                  "kidnapped / reference), the true cell at every step (cell); top-1 at the stretches' observed "
                  "steps", soft_wrap=True)  # fmt: skip
    console.print(head2, soft_wrap=True)
    console.print("-" * len(head2), soft_wrap=True)
    for name, s in rows:
        console.print(
            f"{name:<14} | {f(s['floor_within_10'], '.2f'):>5} {f(s['floor_observed_within_10'], '.2f'):>6} "
            f"{f(s['floor_disagreement'], '.3f'):>5} | {f(s['truth_within_10'], '.2f'):>5} "
            f"{f(s['reference_truth_within_10'], '.2f'):>5} | {f(s['cell_within_10'], '.2f'):>5} "
            f"{f(s['reference_cell_within_10'], '.2f'):>5} | {f(s['kidnapped_top1'], '.3f'):>9} "
            f"{f(s['reference_top1'], '.3f'):>5}",
            soft_wrap=True,
        )
    console.print("query steps along the query pass (top-1 / mean rank of the true place)", soft_wrap=True)
    tr = [*((n, lg["tracking"]) for n, lg in res["logs"].items()), ("pooled", res["pooled_tracking"])]
    for name, t in tr:
        a, b = t["single_shot"], t["filtered"]
        console.print(
            f"{name:<14} single-shot {a['top1']:.3f} / {a['mean_rank']:.2f}   filtered {b['top1']:.3f} / {b['mean_rank']:.2f}",
            soft_wrap=True,
        )
    write_json(json_out, res)
