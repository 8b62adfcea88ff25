"""``fingerloc learn``, ``fingerloc localize`` and ``fingerloc places``."""

from __future__ import annotations

import contextlib
import itertools
import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from .._lazy import LazyAttr, LazyModule
from ..errors import InvalidParameterError
from ._io import JsonRecordStream, atomic_text_file, lit
from .app import app, console, err_console
from .options import (
    BASE_FRAME_OPTION,
    KIND_OPTION,
    POSE_SOURCE_OPTION,
    SKIP_BAD_OPTION,
    TOPIC_OPTION,
    bag_options,
    check_output,
    model_overrides,
    read_run_files,
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
    from ..pipeline.mapping import load_map
    from ..pipeline.presets import PRESET_NAMES, empty_terms, resolve_preset
    from ..pipeline.tracker import calibrate_labelled

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


@app.command("localize")
def localize_cmd(
    data: Path = typer.Argument(..., help="Observations to localize: JSON Lines, a CARMEN log or a ROS bag."),
    db: Path = typer.Option(..., "--db", help="Place database written by 'fingerloc learn' or 'fingerloc map'."),
    top: int = typer.Option(3, help="Places to print per observation."),
    json_out: Path | None = typer.Option(None, "--json", help="Write per-observation posteriors as JSON here."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print only the summary (no per-observation table)."),
    report: Path | None = typer.Option(
        None, "--report", help="Write a report folder here: index.html (open it in a browser) and its figures."
    ),
    kind: str = KIND_OPTION,
    topic: list[str] | None = TOPIC_OPTION,
    pose_source: str = POSE_SOURCE_OPTION,
    base_frame: str | None = BASE_FRAME_OPTION,
    skip_bad: bool = SKIP_BAD_OPTION,
    workers: int | None = typer.Option(
        None, "--workers", min=1, max=256, help="JSON Lines: answer chunks of observations on a local Dask cluster of this many processes."
    ),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="JSON Lines: answer chunks of observations on an existing Dask cluster (tcp://HOST:PORT)."
    ),
) -> None:
    """Answer "where am I?" for each observation: the posterior over the learned places.

    A CARMEN log or a bag is read with the database's preset. When its scans
    have poses and the database has place positions ('fingerloc map'),
    every scan within the map's radius of a place is a query labelled with
    its nearest place (on the very run the map was made from: only the scans
    after its mapping part), so the summary gives top-1 and mean rank.
    JSON Lines are read as a stream, a chunk of observations at a time, and
    the answers are written as they come (memory does not grow with the file).
    """
    from ..parallel import check_cluster_options
    from ..pipeline.mapping import load_map
    from ..pipeline.readers import detect_kind
    from .reports import check_report, localize_report

    if top < 1:
        raise InvalidParameterError(f"--top must be >= 1, got {top}")
    check_cluster_options(workers, scheduler)
    check_output(json_out, "--json")
    check_report(report)
    bag = bag_options(topic, pose_source, base_frame)
    if kind not in ("auto", "carmen", "bag", "jsonl"):
        raise InvalidParameterError(f"--kind must be one of auto, carmen, bag, jsonl, got {kind!r}")
    jsonl = kind == "jsonl" or (kind == "auto" and detect_kind(data) is None)
    cluster = workers is not None or scheduler is not None
    if cluster and not jsonl:
        raise InvalidParameterError("--workers/--scheduler: localize runs on Dask for JSON Lines input only")
    if cluster and report is not None:
        raise InvalidParameterError("--report keeps every answer in memory: give it without --workers/--scheduler")
    from ._localize import shows_heading

    lm = load_map(db)
    model = lm.model
    classes = [str(c) for c in model.classes_]
    preset = None if lm.preset is None else lm.preset.name
    records = json_out is not None
    if cluster:
        chunks = _cluster_chunks(data, db, top, table=not quiet, records=records, workers=workers, scheduler=scheduler)
    elif jsonl and report is None:  # a stream: a chunk of lines at a time
        chunks = _serial_chunks(data, model, top, table=not quiet, records=records)
    else:
        run = read_run_files([data], kind=kind, skip_bad=skip_bad, bag=bag)
        obs, names = queries_of_run(run, lm)
        keep = report is not None
        from ._localize import LOCALIZE_CHUNK, answer_chunk

        chunks = (
            answer_chunk(model, obs[s : s + LOCALIZE_CHUNK], names[s:], s, top, table=not quiet, records=records, keep=keep)
            for s in range(0, len(obs), LOCALIZE_CHUNK)
        )
    rank_list: list[int] = []
    pairs: list[tuple[str, str]] = []  # (true, best) of every labelled observation, for the confusion matrix
    kept: list[tuple[Any, Any]] = []  # (log posterior, ranks) per chunk, for the report only
    n = 0
    with contextlib.ExitStack() as stack:
        stream = None
        if json_out is not None:
            stream = JsonRecordStream(stack.enter_context(atomic_text_file(json_out)), "observations")
        for answers in chunks:
            if stream is not None:
                for text, nulls in zip(answers.records, answers.nulls, strict=True):
                    stream.add_encoded(text, nulls)
            rank_list += [r for r in answers.rank_of_true if r > 0]
            pairs += answers.pairs
            if answers.rows:
                console.print(_answers_table(answers.rows, top, cyclic=shows_heading(model)))
            if report is not None:
                kept.append((answers.logp, answers.ranks))
            n += answers.n
        summary: dict[str, Any] = {"n": n, "top1": None, "mean_rank": None}
        if rank_list:
            summary["top1"] = float(np.mean(np.array(rank_list) == 1))
            summary["mean_rank"] = float(np.mean(rank_list))
        if stream is not None:
            stream.finish({"summary": summary, "preset": preset})
    if json_out is not None:
        err_console.print(lit(f"wrote {json_out}"))
    if rank_list:
        console.print(
            f"right classification: {100 * summary['top1']:.1f}% of {len(rank_list)} labelled; "
            f"mean rank of the true place: {summary['mean_rank']:.2f}"
        )
        if not quiet:
            _print_confusion(pairs, classes)
    if report is not None:
        logp_all = np.vstack([k[0] for k in kept]) if kept else np.zeros((0, len(classes)))
        ranks_all = np.vstack([k[1] for k in kept]) if kept else np.zeros((0, len(classes)), dtype=np.int64)
        localize_report(report, model=model, observations=obs, log_proba=logp_all, ranks=ranks_all, data=data, db=db)


def _answers_table(rows: list[list[str]], top: int, *, cyclic: bool) -> Table:
    """The per-observation table of one chunk of answers."""
    tab = Table(show_header=True)
    for c in ("#", "true", "best", f"top {top} (posterior)", "rank of true") + (("heading",) if cyclic else ()):
        tab.add_column(c, overflow="fold")  # long place names wrap, never cut
    for row in rows:
        tab.add_row(*row)
    return tab


def _serial_chunks(data: Path, model: Any, top: int, *, table: bool, records: bool) -> Iterator[Any]:
    """Answers of a JSON Lines file, chunk after chunk, in this process (a stream: bounded memory)."""
    from ._localize import answer_chunk, jsonl_chunks, parse_lines

    for start, lines in jsonl_chunks(data):
        obs = parse_lines(data, lines)
        names = [f"{data.name}:{start + i + 1}" for i in range(len(obs))]
        yield answer_chunk(model, obs, names, start, top, table=table, records=records)


def _cluster_chunks(
    data: Path, db: Path, top: int, *, table: bool, records: bool, workers: int | None, scheduler: str | None
) -> Iterator[Any]:
    """Answers of a JSON Lines file from Dask tasks (a chunk of lines each), in input order, a bounded number in flight."""
    from ..errors import DataFormatError
    from ..parallel import iter_tasks
    from ._localize import LinesTask, answer_lines, file_sha256, jsonl_chunks

    sha = file_sha256(db)
    where = str(Path(db).absolute())
    tasks = (
        LinesTask(where, sha, str(Path(data).absolute()), start, lines, top, table, records)
        for start, lines in jsonl_chunks(data, LOCALIZE_TASK)
    )
    for res in iter_tasks(answer_lines, tasks, workers=workers, scheduler=scheduler):
        if isinstance(res, tuple):
            raise DataFormatError(res[1])
        yield res


#: Observations per Dask task of ``localize --workers`` (each task answers them in chunks of
#: ``_localize.LOCALIZE_CHUNK``, also 256: that module imports numpy, which ``--help`` must not).
LOCALIZE_TASK = 256


def queries_of_run(run: Any, lm: Any) -> tuple[list[Any], list[str]]:
    """The observations ``localize`` answers for a run, with their names.

    JSON Lines: every observation as it is. A laser log: its scans through
    the database's preset; with poses and stored place positions, only the
    scans within the stored radius of a place, labelled with the nearest
    (on the run the map was made from, only those after its mapping part).
    """
    from ..pipeline.places import nearest_within

    if run.records is not None:
        return list(run.records), list(run.names)
    features = {} if lm.preset is None else lm.preset.features
    poses = run.poses
    if poses is None or lm.positions is None or lm.calibration is None:
        why = "its scans have no poses" if poses is None else "the database has no place positions"
        err_console.print(f"{run.paths[0]}: {why}: every scan is a query, unlabelled", markup=False)
        return run.observations(features=features), list(run.names)
    start = 0
    mapped = lm.mapped_run(run.key)
    if mapped is not None:
        start = int(mapped["n_mapping"])
        err_console.print(
            f"{run.paths[0]} is the run the map was made from: querying its scans after the mapping part "
            f"(from scan {start} of {len(run)})",
            markup=False,
        )
    idx, near = nearest_within(poses[start:, :2], lm.positions, lm.calibration.radius)
    idx = idx + start
    obs = [o.with_label(lm.labels[j]) for o, j in zip(run.observations(idx, features=features), near.tolist(), strict=True)]
    err_console.print(
        f"{idx.size} scan(s) within {lm.calibration.radius:g} m of a place are the queries", markup=False
    )
    return obs, [run.names[i] for i in idx.tolist()]


def _print_confusion(pairs: list[tuple[str, str]], classes: list[str]) -> None:
    """The confusion matrix of (true place, best place) pairs of the labelled observations."""
    truths = sorted({t for t, _ in pairs}, key=classes.index)
    cols = sorted({b for _, b in pairs} | set(truths), key=classes.index)
    if len(cols) > 30:
        console.print(
            f"(confusion matrix omitted: {len(cols)} places, more than 30; --report DIR draws the most confused ones)",
            soft_wrap=True,
            markup=False,
        )
        return
    t = Table(title="confusion (rows: true place, columns: best place)")
    t.add_column("true \\ best", overflow="fold")
    for c in cols:
        t.add_column(c, justify="right", overflow="fold")
    for tr in truths:
        counts = [sum(1 for t, b in pairs if t == tr and b == c) for c in cols]
        t.add_row(tr, *[str(x) if x else "." for x in counts])
    console.print(t)


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
    from ..pipeline.mapping import load_map

    lm = load_map(db)
    sm = lm.scan_map
    pos = {} if lm.positions is None else {lab: lm.positions[j].tolist() for j, lab in enumerate(lm.labels)}
    return {
        "preset": None if lm.preset is None else lm.preset.to_json(),
        "calibration": None if lm.calibration is None else lm.calibration.to_json(),
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
