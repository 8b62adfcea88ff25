"""``--report DIR`` of the commands: what each command hands to :mod:`fingerloc.reporting`, and ``bench report``.

Each function here turns one command's results into the plain data of a
report writer; the commands call it once, after their own output.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

import typer

from .._lazy import LazyModule
from ..errors import InvalidParameterError
from ._io import check_output
from .app import bench_app, console, err_console
from .bench import write_json

if TYPE_CHECKING:
    import numpy as np
else:
    np = LazyModule("numpy")  # imported when a command runs, not for --help

__all__ = ["carmen_report", "check_report", "localize_report", "map_report", "track_report"]


class _LazyViews(Sequence[Any]):
    """Feature views made on demand (a report draws only a few of thousands)."""

    def __init__(self, items: Sequence[Any], make: Any) -> None:
        self._items = items
        self._make = make

    def __len__(self) -> int:
        return len(self._items)

    @overload
    def __getitem__(self, i: int) -> Any: ...
    @overload
    def __getitem__(self, i: slice) -> list[Any]: ...
    def __getitem__(self, i: int | slice) -> Any:
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        item = self._items[i]
        return None if item is None else self._make(item)


def check_report(report: Path | None) -> None:
    """Check ``--report DIR`` before the command writes anything."""
    if report is not None:
        from ..reporting import check_report_dir

        check_report_dir(report, flag="--report")
        check_output(report, "--report", directory=True)  # its folder (or its parent) writable, before any work


def _done(path: Path) -> None:
    err_console.print(f"wrote {path} (open it in a browser)", soft_wrap=True, markup=False)


def _medoid_views(model: Any, classes: Sequence[str]) -> tuple[list[Any], list[int]]:
    """Each place's medoid training observation (or None) and its number of views."""
    places = list(model.places_.values())
    fp = model.terms_.get("Fp")
    refs, counts = [], []
    for c in classes:
        j = model.column_of(c)
        obs = places[j].observations
        medoid = fp.medoids_[j] if fp is not None and hasattr(fp, "medoids_") else 0
        refs.append(obs[min(int(medoid), len(obs) - 1)] if obs else None)
        counts.append(len(obs))
    return refs, counts


def map_report(
    report: Path,
    *,
    model: Any,
    centres: Any,
    radius: Any,
    edges: Any = (),
    trajectory: Any = None,
    scans: Sequence[Any] | None = None,
    data: Path | None = None,
    db: Path | None = None,
) -> None:
    """The map report of a learned database (for ``fingerloc map --report``).

    ``centres``: a mapping place -> (x, y) or an array in ``model.classes_`` order; ``radius``: metres (one, or
    one per place); ``edges``: (place, place) pairs or a ``{(a, b): count}`` dict; ``trajectory``: (T, 2 or 3)
    poses; ``scans``: the run's scans with poses (their end points are drawn).
    """
    from ..reporting import FeatureView, scan_end_points, write_map_report

    classes = [str(c) for c in model.classes_]
    if isinstance(centres, dict):
        xy = np.array([centres[c][:2] for c in classes], dtype=np.float64)
    else:
        xy = np.asarray(centres, dtype=np.float64)[:, :2]
    letters = bool(model.get_params().get("laser_letters", False))
    refs, counts = _medoid_views(model, classes)
    page = write_map_report(
        report,
        place_names=classes,
        centres=xy,
        radius=radius,
        edges=list(edges),
        trajectory=trajectory,
        scan_points=None if scans is None else scan_end_points(scans),
        views_per_place=counts,
        place_views=_LazyViews(refs, lambda o: FeatureView.from_observation(o, laser_letters=letters)),
        notes=[f"fingerloc map {data} --db {db}"] if data is not None else [],
    )
    _done(page)


def localize_report(
    report: Path, *, model: Any, observations: Sequence[Any], log_proba: Any, ranks: Any, data: Path, db: Path
) -> None:
    """The localize report: ``model`` (a fitted PlaceModel), its log posterior and rank matrix for ``observations``."""
    from ..reporting import FeatureView, write_localize_report

    classes = [str(c) for c in model.classes_]
    col = {c: j for j, c in enumerate(classes)}
    truth = np.array([col.get(str(o.label), -1) if o.label is not None else -1 for o in observations], dtype=np.int64)
    rk = np.asarray(ranks)
    rank_true = np.where(truth >= 0, rk[np.arange(len(observations)), np.clip(truth, 0, None)], 0)
    letters = bool(model.get_params().get("laser_letters", False))

    def view(o: Any) -> Any:
        return FeatureView.from_observation(o, laser_letters=letters)

    refs, _ = _medoid_views(model, classes)
    notes = [f"fingerloc localize {data} --db {db}", "Reference view of a place: its medoid training view."]
    if "K" in model.terms_:  # panoramas: the photos behind the answers, with their verified matches
        from ..reporting.photos import write_photo_answers

        names = [f"{data.name}:{i + 1}" for i in range(len(observations))]
        if write_photo_answers(report / "photos", model=model, observations=observations, names=names) is not None:
            notes.append("The photos behind the answers (verified matches, heading, evidence per term): photos/index.html")
    page = write_localize_report(
        report,
        classes=classes,
        log_proba=log_proba,
        truth=truth,
        ranks=rank_true,
        query_names=[f"{data.name}:{i + 1}" for i in range(len(observations))],
        query_views=_LazyViews(list(observations), view),
        place_views=_LazyViews(refs, view),
        notes=notes,
    )
    _done(page)


def track_report(
    report: Path,
    *,
    result: Any,
    log_likelihood: Any,
    truth: Any,
    classes: Sequence[str],
    names: Sequence[str],
    geo: dict[str, Any],
    data: Path,
    db: Path,
) -> None:
    """The track report: the filter's ``result`` (``log_posterior``), the scaled single-shot log-likelihoods,
    the true place per step and the poses / place centres in ``geo`` when known."""
    from ..reporting import detect_jumps, write_track_report

    poses = geo.get("poses")
    kidnaps = detect_jumps(poses) if poses is not None else np.zeros(0, dtype=np.int64)
    notes = [f"fingerloc track {data} --db {db}"]
    if kidnaps.size:
        notes.append("Kidnappings: steps where the pose jumps by more than 5 m and 20 times the median step.")
    page = write_track_report(
        report,
        classes=classes,
        log_posterior=result.log_posterior,
        single_log_likelihood=log_likelihood,
        truth=truth,
        poses=poses,
        centres=geo.get("centres"),
        step_names=names,
        kidnaps=kidnaps,
        notes=notes,
    )
    _done(page)


def carmen_report(report: Path, run: Any, method: str | None) -> None:
    """The benchmark's report: per log, a map report and a localize report of ``method``'s answers."""
    from ..features.laser import observation_from_scan
    from ..pipeline.calibration import mapping_graph
    from ..reporting import FeatureView, Page, scan_end_points, write_localize_report, write_map_report

    out = Path(report)
    page = Page("fingerloc bench carmen report")
    page.paragraph(
        "Place recognition on CARMEN logs: the first half of each log maps (a place every 2 m), the second half "
        f"queries. Answers shown: {method or 'none'}."
    )
    rows = []

    def view(scan: Any) -> Any:
        return FeatureView.from_observation(observation_from_scan(scan))

    for k, lg in enumerate(run.logs):
        sp = lg.split
        names = [str(j) for j in range(sp.n_places)]
        pos = np.array([s.pose[:2] if s.pose is not None else (np.nan, np.nan) for s in lg.scans], dtype=np.float64)
        graph, _ = mapping_graph(pos[: sp.n_mapping], sp.centres)
        mr = lg.methods.get(method) if method is not None else None
        sub = f"log{k + 1}"
        q = pos[sp.query_idx] if mr is not None else None
        write_map_report(
            out / sub / "map",
            place_names=names,
            centres=sp.centres,
            radius=1.0,
            edges=list(graph.edges()),
            trajectory=pos,
            scan_points=scan_end_points(lg.scans),
            views_per_place=np.bincount(sp.train_labels, minlength=sp.n_places),
            place_views=_LazyViews([lg.scans[int(i)] for i in sp.centre_scans], view),
            queries=q,
            query_right=None if mr is None else mr.ranks == 1,
            title=f"{lg.name}: places of the mapping pass",
            notes=[f"Log {lg.path}: {sp.n_scans} scans, {sp.n_places} places, {sp.n_train} training scans."],
        )
        links = f'<a href="{sub}/map/index.html">map</a>'
        if mr is not None:
            write_localize_report(
                out / sub / "localize",
                classes=names,
                truth=sp.query_labels,
                predicted=mr.predicted,
                ranks=mr.ranks,
                query_names=[f"{lg.name}#{int(i)}" for i in sp.query_idx],
                query_views=_LazyViews([lg.scans[int(i)] for i in sp.query_idx], view),
                place_views=_LazyViews([lg.scans[int(i)] for i in sp.centre_scans], view),
                title=f"{lg.name}: {method} answers",
                notes=[
                    f"Queries of the query pass within 1 m of a place; method {method}.",
                    "Reference view of a place: the scan that created it.",
                ],
            )
            links += f' · <a href="{sub}/localize/index.html">localize</a>'
        figs = mr.figures() if mr is not None else {}
        top1 = figs.get("top1")
        rows.append((lg.name, sp.n_places, sp.n_queries, "-" if top1 is None else f"{top1:.3f}", links))
    page.table(["log", "places", "queries", f"top-1 ({method})", "reports"], rows,
               numeric=[False, True, True, True, False], raw_columns=(4,))  # fmt: skip
    _done(page.write(out))


@bench_app.command("report")
def report_bench_cmd(
    out: Path = typer.Option(..., "--out", help="Folder for the three reports (map/, localize/, track/)."),
    places: int = typer.Option(1000, help="Places."),
    queries: int = typer.Option(5000, help="Queries (and track steps)."),
    seed: int = typer.Option(0, help="Seed of the synthetic data."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the figures as JSON to this file."),
) -> None:
    """Time and size of the map, localize and track reports on synthetic data of the given scale."""
    from ..experiments.report_bench import run_report_bench

    if places < 2 or queries < 1:
        raise InvalidParameterError(f"--places must be >= 2 and --queries >= 1, got {places} and {queries}")
    from ..reporting import check_report_dir

    check_report_dir(out, flag="--out")
    check_output(json_out, "--json")
    with err_console.status("writing reports...") as status:
        res = run_report_bench(out, n_places=places, n_queries=queries, seed=seed,
                               on_stage=lambda s: status.update(f"writing the {s} report..."))  # fmt: skip
    for name in ("map", "localize", "track"):
        r = res[name]
        console.print(f"{name:<9} {r['seconds']:6.2f} s  {r['bytes'] / 1e6:7.2f} MB  {r['files']:5d} files")
    console.print(
        f"{'total':<9} {res['total_seconds']:6.2f} s  {res['total_bytes'] / 1e6:7.2f} MB  "
        f"({places} places, {queries} queries)"
    )
    write_json(json_out, res)
