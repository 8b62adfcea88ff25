"""``fingerloc places``: what a place database holds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from .._lazy import LazyAttr, LazyModule
from .app import app, console

if TYPE_CHECKING:
    import numpy as np
    from rich.table import Table
else:  # imported when a command runs, not for --help
    np = LazyModule("numpy")
    Table = LazyAttr("rich.table", "Table")
read_observations = LazyAttr("fingerloc.io.jsonl", "read_observations")

@app.command("places")
def places_cmd(
    db: Path = typer.Option(..., "--db", help="Place database."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """List the places stored in a place database."""
    from ..map.database import load_model
    from ..terms import FingerprintTerm, MixtureTerm

    model = load_model(db)
    rows: list[dict[str, Any]] = []
    fp = model.terms_.get("Fp")
    for j, p in enumerate(model.places_.values()):
        fps = fp.fingerprints_[j] if isinstance(fp, FingerprintTerm) else []
        mixtures = {
            name: int(np.count_nonzero(mx[0]))
            for name, t in model.terms_.items()
            if isinstance(t, MixtureTerm) and (mx := t.mixtures_[j]) is not None
        }
        rows.append(
            {
                "place": str(p.label),
                "observations": len(p.observations),
                "fingerprint": fps[fp.medoids_[j]].letters if fps and isinstance(fp, FingerprintTerm) else "",
                "mixtures": mixtures,
            }
        )
    if as_json:
        console.print_json(json.dumps({"params": _jsonable(model.get_params()), "places": rows, **_map_info(db)}))
        return
    t = Table(title=f"{db}: {len(rows)} place(s)")
    for c in ("place", "observations", "medoid fingerprint", "components per term"):
        t.add_column(c, overflow="fold")
    for r in rows:
        comps = " ".join(f"{k}:{v}" for k, v in r["mixtures"].items())
        t.add_row(r["place"], str(r["observations"]), r["fingerprint"], comps)
    console.print(t)
    _print_map_info(db, model)


def _map_info(db: Path) -> dict[str, Any]:
    """``preset``, ``calibration``, ``positions`` (label -> [x, y] metres), ``runs`` and ``scan_map`` (its grid:
    ``cells`` occupied, ``shape``, ``resolution`` and ``origin`` in metres) of a database (None / empty when absent)."""
    from ..pipeline.calibration import stored_calibration
    from ..pipeline.placemap import load_map

    lm = load_map(db)
    sm = lm.scan_map
    pos = {} if lm.positions is None else {lab: lm.positions[j].tolist() for j, lab in enumerate(lm.labels)}
    return {
        "preset": None if lm.preset is None else lm.preset.to_json(),
        "calibration": None if lm.calibration is None else stored_calibration(lm.calibration, lm.config),
        "positions": pos,
        "runs": lm.runs,
        "scan_map": None if sm is None else {"cells": int(sm.cells.shape[0]), "shape": list(sm.shape),
                                             "resolution": float(sm.resolution), "origin": sm.origin.tolist()},
    }


def _print_map_info(db: Path, model: Any) -> None:
    """The plain-text part of ``places`` after the table: preset, every option, calibration, positions, mapped runs."""
    info = _map_info(db)
    preset = info["preset"]
    if preset is None:
        console.print("preset: none stored (a database of an older fingerloc)", markup=False)
    else:
        console.print(f"preset: {preset['name']} ({preset['reason']})", markup=False, soft_wrap=True)
    opts = _jsonable(model.get_params())
    if preset is not None:
        opts["costs"] = preset["options"].get("costs", opts["costs"])
    console.print("options: " + ", ".join(f"{k}={_short(v)}" for k, v in opts.items()), markup=False, soft_wrap=True)
    if info["calibration"] is not None:
        cal = info["calibration"]
        console.print("calibration: " + ", ".join(f"{k}={_short(v)}" for k, v in cal.items()), markup=False,
                      soft_wrap=True)  # fmt: skip
    if info["positions"]:
        console.print("positions (m): " + ", ".join(f"{k} ({x:.2f}, {y:.2f})" for k, (x, y) in info["positions"].items()),
                      markup=False, soft_wrap=True)  # fmt: skip
    for r in info["runs"]:
        console.print(f"mapped from: {r['name']} (first {r['n_mapping']} of {r['n_scans']} scans)", markup=False,
                      soft_wrap=True)  # fmt: skip
    sm = info["scan_map"]
    if sm is not None:
        nx, ny = sm["shape"]
        console.print(f"scan map: {sm['cells']} occupied cells of {nx} x {ny}, {sm['resolution']:g} m each",
                      markup=False, soft_wrap=True)  # fmt: skip


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return ",".join(str(x) for x in v)
    if isinstance(v, dict) and len(json.dumps(v)) > 60:
        return "{...}"
    return str(v)


def _jsonable(params: dict[str, Any]) -> dict[str, Any]:
    out = dict(params)
    c = out.get("costs")
    out["costs"] = None if c is None else getattr(c, "to_dict", lambda: repr(c))()
    rs = out.get("random_state")
    out["random_state"] = rs if rs is None or isinstance(rs, int) else repr(rs)
    return out

