"""Commands on observation files: ``fingerprint``."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from .app import app


@app.command("fingerprint")
def fingerprint_cmd(
    data: Path = typer.Argument(..., help="Observations, JSON Lines (docs/FORMATS.md)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object a line: string, bearings (deg), place."),
    empty_step_deg: float = typer.Option(20.0, min=0.1, max=360.0, help="Degrees of seen empty bearing per 'n' letter."),
    merge_tol_deg: float = typer.Option(5.0, min=0.0, max=180.0, help="Corner/edge merge tolerance into 'f', degrees."),
) -> None:
    """Print the fingerprint of each observation, one line each."""
    from ..fingerprint import make_fingerprint  # numpy: not for --help
    from ..io.jsonl import iter_observations

    for obs in iter_observations(data):
        fp = make_fingerprint(obs, empty_step_deg=empty_step_deg, merge_tol_deg=merge_tol_deg)
        if as_json:
            rec = {"place": obs.label, **fp.to_dict()}
            typer.echo(json.dumps(rec))
        else:
            typer.echo(fp.letters)
