"""``fingerloc learn``: labelled observations into a place database."""

from __future__ import annotations

import itertools
import time
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from .._lazy import LazyAttr, LazyModule
from ..errors import InvalidParameterError
from .app import app, err_console
from .options import (
    check_output,
    model_overrides,
    stored_options,
)

if TYPE_CHECKING:
    import numpy as np
    from rich.table import Table
else:  # imported when a command runs, not for --help
    np = LazyModule("numpy")
    Table = LazyAttr("rich.table", "Table")
read_observations = LazyAttr("fingerloc.io.jsonl", "read_observations")

#: PlaceModel parameter -> the ``learn`` option that sets it (messages name the option).
_FLAGS = {
    "n_components": "--components",
    "terms": "--terms",
    "fp_likelihood": "--fp-likelihood",
    "fp_reference": "--fp-reference",
    "cyclic": "--cyclic",
    "laser_letters": "--laser-letters",
    "costs": "--costs",
    "unknown_prior": "--unknown-prior",
    "weights": "--weights",
    "random_state": "--seed",
}


def _with_flags(message: str) -> str:
    """``message`` with PlaceModel's parameter names replaced by the options a user typed."""
    import re

    return re.sub(r"\b(" + "|".join(_FLAGS) + r")\b", lambda m: _FLAGS[m.group(1)], message)


@app.command("learn")
def learn_cmd(
    data: Path = typer.Argument(..., help="Labelled observations, JSON Lines ('place' on every line)."),
    db: Path = typer.Option(..., "--db", help="Place database (SQLite); created, or extended if it exists."),
    preset: str | None = typer.Option(
        None,
        "--preset",
        help="paper | laser2d | panorama | multimodal | auto [auto for a new database: picked from the data; "
        "the database's own when it exists]. Explicit options below override it.",
    ),
    components: int | None = typer.Option(None, "-k", "--components", min=1, max=1000, help="Mixture components per place and feature type [5]."),
    terms: str | None = typer.Option(
        None, help="Terms, comma-separated among VE,CP,Ex,B,Fp and R (range term, our extension) [the preset's]."
    ),
    laser_letters: bool | None = typer.Option(
        None, "--laser-letters/--no-laser-letters", help="Write wall segments and line ends into the fingerprint."
    ),
    fp_likelihood: str | None = typer.Option(None, help="'paper' (1/(cost+1)) or 'exp' (exp(-lambda cost)) [the preset's]."),
    fp_reference: str | None = typer.Option(None, help="'all', 'medoid' or 'consensus' [all]."),
    cyclic: bool | None = typer.Option(None, "--cyclic/--no-cyclic", help="Align over all rotations (unknown heading)."),
    costs: str | None = typer.Option(None, help="Alignment costs: 'unit' (Levenshtein) or 'feature' [the preset's]."),
    unknown_prior: float | None = typer.Option(None, help="Prior probability of an unknown place [0]."),
    weights: str | None = typer.Option(
        None,
        help="Per-term weights: 'fit' (learned from held-out training views) or TERM=W,... e.g. VE=0.5,Fp=2 [all 1].",
    ),
    seed: int | None = typer.Option(None, min=0, help="Seed of the mixtures' initialisation [0]."),
    calibrate: bool = typer.Option(
        True,
        "--calibrate/--no-calibration",
        help="New database: fit the filters' likelihood scale beta on held-out views (file order = visiting order).",
    ),
) -> None:
    """Learn places from labelled observations into a place database.

    A new database is learned with --preset (default auto: laser features
    only -> laser2d, image features only -> panorama, both -> multimodal);
    the preset and every resolved option are stored and shown by 'fingerloc
    places'. When the database exists, new places are added and places named
    again are extended; the other places are not refit; observations already
    stored (same content hash) are skipped. The order of the observations in
    the file adds transitions to the stored place graph (used by
    'fingerloc track'). Options then default to the database's own, and an
    option that differs from them is an error.
    """
    from ..map.database import MapInfo, locked, observation_hash, read_graph_edges, read_map_info, save_model
    from ..map.graph import PlaceGraph
    from ..pipeline.calibration import calibrate_labelled
    from ..pipeline.placemap import load_map
    from ..pipeline.presets import PRESET_NAMES, empty_terms, resolve_preset

    if preset is not None and preset not in PRESET_NAMES:
        raise InvalidParameterError(f"--preset must be one of {', '.join(PRESET_NAMES)}, got {preset!r}")
    given = model_overrides(components=components, terms=terms, laser_letters=laser_letters,
                            fp_likelihood=fp_likelihood, fp_reference=fp_reference, cyclic=cyclic, costs=costs,
                            unknown_prior=unknown_prior, weights=weights, seed=seed)  # fmt: skip
    check_output(db, "--db")
    obs = read_observations(data)
    missing = [i + 1 for i, o in enumerate(obs) if not o.label]
    if missing:
        raise InvalidParameterError(f"{data}: observation {missing[0]} has no 'place' label; learn needs labels")
    # read-modify-write under the database's writer lock: a concurrent learn waits, nothing is lost
    with locked(db):
        t0 = time.perf_counter()
        edges: dict[tuple[str, str], int] = {}
        hashes = [observation_hash(o) for o in obs]
        if db.exists():
            lm = load_map(db)
            model = lm.model
            edges = read_graph_edges(db)
            stored = stored_options(model)
            stored_preset = lm.preset
            if preset is not None and stored_preset is not None and preset not in ("auto", stored_preset.name):
                raise InvalidParameterError(f"{db} was learned with preset {stored_preset.name!r}; got --preset {preset} (use a new --db)")
            if preset is not None and stored_preset is None and preset != "auto":
                resolved = resolve_preset(preset, obs)
                for k, v in resolved.options.items():
                    if k in stored and k not in given and stored[k] != v:
                        raise InvalidParameterError(f"{db} was learned with {k}={stored[k]!r}, not preset {preset} (use a new --db)")
            for k, v in given.items():
                sv = stored[k]
                if sv != v:
                    flag = _FLAGS.get(k, k)
                    raise InvalidParameterError(f"{db} was learned with {flag} {sv!r}; got {v!r} (use a new --db)")
            known = set(lm.content_hashes)
            fresh = []
            for i, h in enumerate(hashes):
                if h not in known:
                    fresh.append(i)
                    known.add(h)
            dup = len(obs) - len(fresh)
            new_obs = [obs[i] for i in fresh]
            before = set(model.places_)
            if new_obs:
                model.add_places(new_obs)
            verb = (
                f"added {len(set(model.places_) - before)} place(s), "
                f"extended {len(before & {o.label for o in new_obs})}"
            )
            if dup:
                verb += f", skipped {dup} observation(s) already stored"
            old = read_map_info(db)
            info = MapInfo(
                preset=old.preset,
                positions=old.positions,
                calibration=old.calibration,
                content_hashes=set(lm.content_hashes) | {hashes[i] for i in fresh},
                runs=old.runs,
                scan_map=old.scan_map,
            )
        else:
            resolved = resolve_preset("auto" if preset is None else preset, obs, given)
            try:
                model = resolved.model().fit(obs)
            except InvalidParameterError as err:
                raise InvalidParameterError(_with_flags(str(err))) from err
            err_console.print(resolved.reason, markup=False)  # after the checks: a failure stays one line
            empty = empty_terms(resolved.options, obs)
            if empty:
                err_console.print(f"warning: no observation has {', '.join(empty)} bearings: those terms cannot tell "
                                  "places apart (see --preset / --terms)", markup=False)  # fmt: skip
            verb = f"learned {len(model.places_)} place(s) with preset {resolved.name}"
            cal = None
            if calibrate and len(model.places_) > 1:
                cal = calibrate_labelled(resolved.options, obs).to_json()
                verb += f" (likelihood scale beta {cal['beta']:.3g} from {cal['calibration_rows']} held-out views)"
            info = MapInfo(preset=resolved.to_json(), content_hashes=set(hashes), calibration=cal)
        # The place graph: transitions between consecutive observations of the file, added to the stored ones.
        graph = PlaceGraph([str(c) for c in model.classes_], edges)
        for a, b in itertools.pairwise(obs):
            graph.add_transition(str(a.label), str(b.label))
        size = save_model(model, db, graph_edges=graph.edges(), info=info)
    err_console.print(
        f"{verb} from {len(obs)} observation(s) in {time.perf_counter() - t0:.2f} s; "
        f"{db}: {len(model.places_)} place(s), {size} bytes"
    )


