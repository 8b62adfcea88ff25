"""``fingerloc learn``: labelled observations into a place database."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from .._lazy import LazyAttr
from ..errors import InvalidParameterError
from ._io import all_or_nothing, lit, warn
from .app import app, err_console
from .options import LOCK_TIMEOUT_OPTION, check_output, model_overrides

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
@all_or_nothing  # the database renamed into place, and its writer lock released, when the command ends well
def learn_cmd(
    data: Path = typer.Argument(..., help="Labelled observations, JSON Lines ('place' on every line)."),
    db: Path = typer.Option(..., "--db", help="Place database (SQLite); created, or extended if it exists."),
    preset: str | None = typer.Option(
        None,
        "--preset",
        help="paper | laser2d | panorama | multimodal | auto [auto for a new database: picked from the data; "
        "the database's own when it exists]. Explicit options below override it.",
    ),
    components: int | None = typer.Option(None, "-k", "--components", help="Mixture components per place and feature type [5]."),
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
    lock_timeout: float = LOCK_TIMEOUT_OPTION,
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
    option that differs from them is an error. Into a database made by
    'fingerloc map', new places get the mean of their views' poses as their
    position (every view of a new place needs a pose in the map's frame).
    """
    from ..pipeline.learning import learn_into
    from ..pipeline.presets import PRESET_NAMES

    given = model_overrides(components=components, terms=terms, laser_letters=laser_letters,
                            fp_likelihood=fp_likelihood, fp_reference=fp_reference, cyclic=cyclic, costs=costs,
                            unknown_prior=unknown_prior, weights=weights, seed=seed)  # fmt: skip
    if preset is not None and preset not in PRESET_NAMES:
        raise InvalidParameterError(f"--preset must be one of {', '.join(PRESET_NAMES)}, got {preset!r}")
    check_output(db, "--db", stdout=False)
    obs = read_observations(data)
    missing = [i + 1 for i, o in enumerate(obs) if not o.label]
    if missing:
        raise InvalidParameterError(f"{data}: observation {missing[0]} has no 'place' label; learn needs labels")
    t0 = time.perf_counter()
    try:
        res = learn_into(db, obs, preset=preset, overrides=given, calibrate=calibrate)
    except InvalidParameterError as err:
        raise InvalidParameterError(_with_flags(str(err))) from None
    if res.created:
        err_console.print(res.reason, markup=False)
    warn(res.warnings)
    if res.created:
        verb = f"learned {res.places} place(s) with preset {res.preset}"
        if res.beta is not None and res.calibration_rows:
            verb += f" (likelihood scale beta {res.beta:.3g} from {res.calibration_rows} held-out views)"
    else:
        verb = f"added {len(res.added)} place(s), extended {len(res.extended)}"
        if res.skipped:
            verb += f", skipped {res.skipped} observation(s) already stored"
        if res.positions:
            verb += f"; {res.positions} place position(s) kept"
    took = time.perf_counter() - t0
    err_console.print(lit(f"{verb} from {len(obs)} observation(s) in {took:.2f} s; {db}: {res.places} place(s), {res.size} bytes"))

