"""``fingerloc demo``: the main job on an embedded example."""

from __future__ import annotations

import numpy as np
import typer
from rapidfuzz.distance import Levenshtein
from rich.table import Table

from ..fingerprint import make_fingerprint
from ..observation import Observation
from .app import app, console

# Four small offices: feature bearings (degrees) as a robot at the room centre sees them.
_PLACES: dict[str, dict[str, list[float]]] = {
    "office-1": {"VE": [15, 95, 170, 265], "c": [45, 135, 225, 315], "B": [200]},
    "office-2": {"VE": [30, 120, 250], "c": [45, 135, 225, 315], "B": [80, 290]},
    "corridor": {"VE": [5, 175, 185, 355], "c": [60, 120, 240, 300]},
    "lab": {"VE": [20, 60, 100, 140, 260], "c": [45, 315], "B": [180]},
}


@app.command("demo")
def demo_cmd(
    seed: int = typer.Option(0, help="Random seed of the simulated noise."),
    noise_deg: float = typer.Option(4.0, help="Bearing noise, degrees (standard deviation)."),
) -> None:
    """Learn four embedded places, localize noisy views of them by fingerprint alignment."""
    rng = np.random.default_rng(seed)

    def view(feats: dict[str, list[float]]) -> Observation:
        noisy = {k: list(np.asarray(v) + rng.normal(0, noise_deg, len(v))) for k, v in feats.items()}
        return Observation.from_degrees(noisy)

    refs = {name: make_fingerprint(view(f)).letters for name, f in _PLACES.items()}
    table = Table(title=f"fingerprint localization, noise {noise_deg} deg")
    for col in ("true place", "query fingerprint", "best", "cost"):
        table.add_column(col)
    right = 0
    total = 0
    for name, feats in _PLACES.items():
        for _ in range(3):
            q = make_fingerprint(view(feats)).letters
            costs = {p: Levenshtein.distance(q, r) for p, r in refs.items()}
            best = min(costs, key=lambda p: costs[p])
            right += best == name
            total += 1
            table.add_row(name, q, best, str(costs[best]))
    console.print(table)
    console.print(f"right classification: {right}/{total} ({100 * right / total:.0f}%)")
