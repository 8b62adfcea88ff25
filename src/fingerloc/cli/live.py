"""``fingerloc bench live``: the streaming tracker's latency per step and the pose filter's APE (evo)."""

from __future__ import annotations

from pathlib import Path

import typer

from ._io import check_output, write_json
from .app import bench_app, console, err_console


@bench_app.command("live")
def live_cmd(
    logs: list[Path] = typer.Argument(..., help="CARMEN logs (.log, .log.gz): APE on each; latency on the first."),
    places: int = typer.Option(1000, "--places", min=1, max=100_000, help="Latency: places in the map, about."),
    latency_log: Path | None = typer.Option(None, "--latency-log", help="Latency on this log [the first log]."),
    steps: int | None = typer.Option(None, "--steps", min=1, help="Latency: time at most this many steps."),
    only: list[str] = typer.Option([], "--only", help="Run only this section: latency, ape (repeatable)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of the pose filter."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
) -> None:
    """Per-step latency of the streaming tracker (laser2d, pose filter, ~1,000 places), and evo's APE of the
    pose filter's poses against each run's own poses, over the tracked steps whose answer is right."""
    from ..experiments.live import run_live_bench

    check_output(json_out, "--json")
    with err_console.status("benchmarking...") as status:
        res = run_live_bench(logs, latency_log=latency_log, places=places, seed=seed, steps=steps,
                             sections=only or ("latency", "ape"), on_progress=lambda s: status.update(s))  # fmt: skip
    lat = res.get("latency")
    if lat is not None:
        console.print(f"latency on {lat['log']}, {lat['places']} places ({lat['copies']} copies of "
                      f"{lat['places_per_copy']}); load average {lat['load_average_1min']:.2f}", soft_wrap=True,
                      markup=False)  # fmt: skip
        for name, v in lat["variants"].items():
            w, c, co, cf = v["wall"], v["cpu"], v["cpu_observe"], v["cpu_filter"]
            console.print(
                f"  {name.replace('_', ' ')}, {v['steps']} steps: median {w['median_ms']:.1f} ms, p95 {w['p95_ms']:.1f} ms "
                f"(CPU median {c['median_ms']:.1f} ms, p95 {c['p95_ms']:.1f} ms: observation {co['median_ms']:.1f} ms, "
                f"filter {cf['median_ms']:.1f} ms)",
                soft_wrap=True, markup=False,
            )  # fmt: skip
    for name, a in (res.get("ape") or {}).items():
        r, al = a["ape_right"], a["ape_all"]
        fig = "-" if r["rmse_m"] is None else f"{r['rmse_m']:.3f} m"
        fig_all = "-" if al["rmse_m"] is None else f"{al['rmse_m']:.3f} m"
        st = a["stream"]
        console.print(
            f"{name}: APE (translation RMSE) {fig} over {r['steps']} right steps, {fig_all} over all {al['steps']} "
            f"tracked steps with a pose; query part as a stream: {st['same_place']} of {st['offline_steps']} steps "
            f"the same place ({st['same_record']} the same record, {st['stream_steps']} stream steps)",
            soft_wrap=True, markup=False,
        )  # fmt: skip
    write_json(json_out, res)
