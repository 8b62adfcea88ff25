"""``fingerloc learn``, ``fingerloc localize`` and ``fingerloc places``."""

from __future__ import annotations

import itertools
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import typer
from rich.table import Table

from ..errors import InvalidParameterError
from ..io.jsonl import read_observations
from ..model import TERMS, PlaceModel
from ._io import check_output
from .app import app, console, err_console
from .bench import write_json

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


def _parse_terms(text: str) -> tuple[str, ...]:
    terms = tuple(t.strip() for t in text.replace("+", ",").split(",") if t.strip())
    for t in terms:
        if t not in TERMS:
            raise InvalidParameterError(f"--terms: unknown term {t!r} (expected some of {', '.join(TERMS)})")
    return terms


def _costs(name: str) -> Any:
    if name == "unit":
        return None
    if name == "feature":
        from ..align import CostModel

        return CostModel.feature_aware()
    raise InvalidParameterError(f"--costs must be 'unit' or 'feature', got {name!r}")


def _parse_weights(text: str) -> str | dict[str, float]:
    """``fit`` or ``TERM=W,...`` -> the ``weights`` argument of PlaceModel."""
    if text.strip() == "fit":
        return "fit"
    out: dict[str, float] = {}
    for part in text.split(","):
        name, sep, value = part.partition("=")
        try:
            w = float(value)
        except ValueError:
            w = float("nan")
        if not sep or not name.strip() or not (math.isfinite(w) and w >= 0):
            raise InvalidParameterError(f"--weights: expected 'fit' or TERM=W,... with W >= 0, got {part!r}")
        out[name.strip()] = w
    return out


@app.command("learn")
def learn_cmd(
    data: Path = typer.Argument(..., help="Labelled observations, JSON Lines ('place' on every line)."),
    db: Path = typer.Option(..., "--db", help="Place database (SQLite); created, or extended if it exists."),
    components: int | None = typer.Option(None, "-k", "--components", min=1, max=1000, help="Mixture components per place and feature type [5]."),
    terms: str | None = typer.Option(
        None, help="Terms, comma-separated among VE,CP,Ex,B,Fp and R (range term, our extension) [VE,CP,Ex,B,Fp]."
    ),
    laser_letters: bool | None = typer.Option(
        None, "--laser-letters/--no-laser-letters", help="Write wall segments and line ends into the fingerprint."
    ),
    fp_likelihood: str | None = typer.Option(None, help="'paper' (1/(cost+1)) or 'exp' (exp(-lambda cost)) [paper]."),
    fp_reference: str | None = typer.Option(None, help="'all', 'medoid' or 'consensus' [all]."),
    cyclic: bool | None = typer.Option(None, "--cyclic/--no-cyclic", help="Align over all rotations (unknown heading)."),
    costs: str | None = typer.Option(None, help="Alignment costs: 'unit' (Levenshtein) or 'feature' [unit]."),
    unknown_prior: float | None = typer.Option(None, help="Prior probability of an unknown place [0]."),
    weights: str | None = typer.Option(
        None,
        help="Per-term weights: 'fit' (learned from held-out training views) or TERM=W,... e.g. VE=0.5,Fp=2 [all 1].",
    ),
    seed: int | None = typer.Option(None, min=0, help="Seed of the mixtures' initialisation [0]."),
) -> None:
    """Learn places from labelled observations into a place database.

    When the database exists, new places are added and places named again
    are extended; the other places are not refit. The order of the
    observations in the file adds transitions to the stored place graph
    (used by ``fingerloc track``). Options then default to the
    database's own, and an option that differs from them is an error.
    """
    from ..map.database import load_model, locked, read_graph_edges, save_model
    from ..map.graph import PlaceGraph

    given: dict[str, Any] = {
        "n_components": components,
        "terms": None if terms is None else _parse_terms(terms),
        "fp_likelihood": fp_likelihood,
        "fp_reference": fp_reference,
        "cyclic": cyclic,
        "laser_letters": laser_letters,
        "costs": None if costs is None else _costs(costs),
        "unknown_prior": unknown_prior,
        "weights": None if weights is None else _parse_weights(weights),
        "random_state": seed,
    }
    given = {k: v for k, v in given.items() if v is not None}
    check_output(db, "--db")
    obs = read_observations(data)
    missing = [i + 1 for i, o in enumerate(obs) if not o.label]
    if missing:
        raise InvalidParameterError(f"{data}: observation {missing[0]} has no 'place' label; learn needs labels")
    # read-modify-write under the database's writer lock: a concurrent learn waits, nothing is lost
    with locked(db):
        t0 = time.perf_counter()
        edges: dict[tuple[str, str], int] = {}
        if db.exists():
            model = load_model(db)
            edges = read_graph_edges(db)
            stored = model.get_params()
            for k, v in given.items():
                sv = stored[k]
                if k == "costs":
                    same = (sv is None and v is None) or (
                        sv is not None and v is not None and np.array_equal(sv.substitution, v.substitution)
                        and np.array_equal(sv.indel, v.indel)
                    )
                else:
                    same = (tuple(sv) == tuple(v)) if k == "terms" else (sv == v)
                if not same:
                    flag = _FLAGS.get(k, k)
                    raise InvalidParameterError(f"{db} was learned with {flag} {sv!r}; got {v!r} (use a new --db)")
            before = set(model.places_)
            model.add_places(obs)
            verb = f"added {len(set(model.places_) - before)} place(s), extended {len(before & {o.label for o in obs})}"
        else:
            try:
                model = PlaceModel(**given).fit(obs)
            except InvalidParameterError as err:
                raise InvalidParameterError(_with_flags(str(err))) from err
            verb = f"learned {len(model.places_)} place(s)"
        # The place graph: transitions between consecutive observations of the file, added to the stored ones.
        graph = PlaceGraph([str(c) for c in model.classes_], edges)
        for a, b in itertools.pairwise(obs):
            graph.add_transition(str(a.label), str(b.label))
        size = save_model(model, db, graph_edges=graph.edges())
    err_console.print(
        f"{verb} from {len(obs)} observation(s) in {time.perf_counter() - t0:.2f} s; "
        f"{db}: {len(model.places_)} place(s), {size} bytes"
    )


@app.command("localize")
def localize_cmd(
    data: Path = typer.Argument(..., help="Observations to localize, JSON Lines."),
    db: Path = typer.Option(..., "--db", help="Place database written by 'fingerloc learn'."),
    top: int = typer.Option(3, help="Places to print per observation."),
    json_out: Path | None = typer.Option(None, "--json", help="Write per-observation posteriors as JSON here."),
) -> None:
    """Answer "where am I?" for each observation: the posterior over the learned places."""
    from ..map.database import load_model

    if top < 1:
        raise InvalidParameterError(f"--top must be >= 1, got {top}")
    check_output(json_out, "--json")
    model = load_model(db)
    obs = read_observations(data)
    classes = [str(c) for c in model.classes_]
    terms = model.term_log_likelihoods(obs)
    logp = model.predict_log_proba(obs)
    post = np.exp(logp)
    ranks = model.rank(obs)
    headings = model.headings(obs) if model.cyclic else np.full(len(obs), np.nan)
    unknown = model.predict_unknown_proba(obs) if model.unknown_prior > 0 else None
    col = {c: j for j, c in enumerate(classes)}
    labelled = [o.label is not None and o.label in col for o in obs]
    records = []
    table = Table(show_header=True)
    for c in ("#", "true", "best", f"top {top} (posterior)", "rank of true") + (("heading",) if model.cyclic else ()):
        table.add_column(c)
    for i, o in enumerate(obs):
        order = np.argsort(-logp[i], kind="stable")
        best = classes[order[0]]
        r = int(ranks[i, col[o.label]]) if labelled[i] and o.label is not None else None
        h = None if np.isnan(headings[i]) else float(headings[i])
        rec: dict[str, Any] = {
            "index": i,
            "place": o.label,
            "best": best,
            "posterior": {c: float(post[i, j]) for j, c in enumerate(classes)},
            "rank_of_true": r,
            "terms": {t: {c: float(ll[i, j]) for j, c in enumerate(classes)} for t, ll in terms.items()},
            "heading_deg": h,
        }
        if unknown is not None:
            rec["unknown"] = float(unknown[i])
        records.append(rec)
        topk = ", ".join(f"{classes[j]} {post[i, j]:.3f}" for j in order[:top])
        row = [str(i), o.label or "-", best, topk, "-" if r is None else str(r)]
        if model.cyclic:
            row.append("-" if h is None else f"{h:.1f}")
        table.add_row(*row)
    console.print(table)
    rank_list = [rec["rank_of_true"] for rec in records if rec["rank_of_true"] is not None]
    summary: dict[str, Any] = {"n": len(obs), "top1": None, "mean_rank": None}
    if rank_list:
        summary["top1"] = float(np.mean(np.array(rank_list) == 1))
        summary["mean_rank"] = float(np.mean(rank_list))
        console.print(
            f"right classification: {100 * summary['top1']:.1f}% of {len(rank_list)} labelled; "
            f"mean rank of the true place: {summary['mean_rank']:.2f}"
        )
        _print_confusion(records, classes)
    write_json(json_out, {"observations": records, "summary": summary})


def _print_confusion(records: list[dict[str, Any]], classes: list[str]) -> None:
    truths = sorted({r["place"] for r in records if r["rank_of_true"] is not None}, key=classes.index)
    cols = sorted({r["best"] for r in records if r["rank_of_true"] is not None} | set(truths), key=classes.index)
    if len(cols) > 30:
        console.print(f"(confusion matrix omitted: {len(cols)} places)")
        return
    t = Table(title="confusion (rows: true place, columns: best place)")
    t.add_column("true \\ best")
    for c in cols:
        t.add_column(c, justify="right")
    for tr in truths:
        counts = [sum(1 for r in records if r["place"] == tr and r["best"] == c) for c in cols]
        t.add_row(tr, *[str(x) if x else "." for x in counts])
    console.print(t)


@app.command("places")
def places_cmd(
    db: Path = typer.Option(..., "--db", help="Place database."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """List the places stored in a place database."""
    from ..map.database import load_model

    model = load_model(db)
    rows: list[dict[str, Any]] = []
    for p in model.places_.values():
        rows.append(
            {
                "place": p.label,
                "observations": len(p.observations),
                "fingerprint": p.fingerprints[p.medoid].letters if p.fingerprints else "",
                "mixtures": {t: int(np.count_nonzero(w)) for t, (w, _, _) in p.mixtures.items()},
            }
        )
    if as_json:
        console.print_json(json.dumps({"params": _jsonable(model.get_params()), "places": rows}))
        return
    t = Table(title=f"{db}: {len(rows)} place(s)")
    for c in ("place", "observations", "medoid fingerprint", "components per term"):
        t.add_column(c)
    for r in rows:
        comps = " ".join(f"{k}:{v}" for k, v in r["mixtures"].items())
        t.add_row(r["place"], str(r["observations"]), r["fingerprint"], comps)
    console.print(t)


def _jsonable(params: dict[str, Any]) -> dict[str, Any]:
    out = dict(params)
    c = out.get("costs")
    out["costs"] = None if c is None else getattr(c, "to_dict", lambda: repr(c))()
    rs = out.get("random_state")
    out["random_state"] = rs if rs is None or isinstance(rs, int) else repr(rs)
    return out
