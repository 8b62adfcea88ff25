"""``fingerloc bench ...`` commands."""

from __future__ import annotations

from pathlib import Path

import typer

from ..errors import InvalidParameterError
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


def _parse_params(items: list[str], flag: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for it in items:
        name, sep, value = it.partition("=")
        try:
            v = float(value)
        except ValueError:
            v = float("nan")
        if not sep or not name.strip().startswith("beacon_") or v != v:
            raise InvalidParameterError(f"{flag}: expected beacon_NAME=NUMBER, got {it!r}")
        out[name.strip()] = v
    return out


@bench_app.command("beacons")
def beacons_cmd(
    scans: int = typer.Option(300, "--scans", min=1, max=100_000, help="Noisy scans to simulate."),
    step_deg: float = typer.Option(0.25, "--step-deg", min=0.01, max=10.0, help="Beam step, degrees."),
    fov_deg: float = typer.Option(270.0, "--fov-deg", min=10.0, max=360.0, help="Field of view, degrees."),
    diameter: float = typer.Option(0.09, "--diameter", min=0.005, max=0.3, help="Reflector cylinder diameter, metres."),
    distance: float = typer.Option(1.05, "--distance", min=0.2, max=1.4, help="Distance of its centre, metres."),
    param: list[str] = typer.Option(
        [], "--param", help="Detector parameter override beacon_NAME=VALUE (repeatable), e.g. beacon_window_m=0.2."
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of the rooms, poses and noise."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
) -> None:
    """Beacon detection: a retro-reflective cylinder (6,000 vs 1,100) in noisy simulated scans."""
    from ..experiments.beacons import ReflectorScene, run_beacon_bench

    check_output(json_out, "--json")
    params = _parse_params(param, "--param")
    scene = ReflectorScene(step_deg=step_deg, fov_deg=fov_deg, diameter=diameter, distance=distance)
    with err_console.status(f"simulating {scans} scans..."):
        res = run_beacon_bench(scene, n_scans=scans, seed=seed, params=params)
    err = res["mean_error_deg"]
    console.print(
        f"{res['beams']} beams, {step_deg:g} deg a beam, {diameter * 100:g} cm cylinder at {distance:g} m: "
        f"found in {100 * res['found_rate']:.1f}% of {scans} scans, {res['false_per_scan']:.3f} false beacons a scan "
        f"({100 * res['scans_with_false']:.1f}% of scans with one), mean bearing error "
        f"{'-' if err is None else f'{err:.2f} deg'}",
        soft_wrap=True,
    )
    write_json(json_out, res)


def _sizes(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        p = part.strip().replace("_", "")
        if not p.isdigit() or int(p) < 2:
            raise InvalidParameterError(f"--places: expected sizes like 1000,10000,100000 (each >= 2), got {text!r}")
        out.append(int(p))
    return out


@bench_app.command("scale")
def scale_cmd(
    places: str = typer.Option("1000,10000,100000", "--places", help="Campus sizes, comma-separated."),
    preset: list[str] = typer.Option([], "--preset", help="Preset to measure (repeatable; default laser2d and paper)."),
    queries: int = typer.Option(200, "--queries", min=1, max=100_000, help="Queries a size (random places)."),
    exact_queries: int = typer.Option(20, "--exact-queries", min=0, max=100_000, help="Queries also answered by the linear scan."),
    repeat: int = typer.Option(3, "--repeat", min=1, max=100, help="Timing rounds a query (the best counts)."),
    seed: int = typer.Option(20040426, "--seed", min=0, help="Seed of the campus and of the queries."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
) -> None:
    """Learn and localize on a simulated campus of 1,000 to 100,000 places: time, memory, exactness."""
    from ..experiments.scale import PRESETS, run_scale

    check_output(json_out, "--json")
    sizes = _sizes(places)
    presets = preset or list(PRESETS)
    for p in presets:
        if p not in PRESETS:
            raise InvalidParameterError(f"--preset: unknown preset {p!r} (known: {', '.join(PRESETS)})")
    with err_console.status("measuring...") as status:
        res = run_scale(
            sizes, presets=presets, seed=seed, n_queries=queries, exact_queries=exact_queries, repeat=repeat,
            on_step=lambda s: status.update(f"measuring {s}..."),
        )  # fmt: skip
    cols = (
        "learn_s", "peak_rss_mb", "db_mb", "localize_ms", "localize_cpu_ms", "localize_batched_ms",
        "localize_posterior_cpu_ms", "top1", "mean_rank", "exact", "exact_posterior", "scored",
    )  # fmt: skip
    for name, block in res["presets"].items():
        console.print(name, style="bold")
        console.print("  places  " + "  ".join(cols), soft_wrap=True)
        for n, f in block["sizes"].items():
            cells = [f"{f[c]:.4g}" if isinstance(f[c], float) else str(f[c]) for c in cols]
            console.print(f"  {int(n):>6}  " + "  ".join(cells), soft_wrap=True)
    console.print(f"{res['wall_s']:.0f} s in all", soft_wrap=True)
    write_json(json_out, res)
