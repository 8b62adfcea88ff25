"""Figures and the report page of loop closures and of places made from fingerprints (``bench loops --report``).

* :func:`draw_pr_curves`: precision against recall, one curve per method;
* :func:`draw_fingerprint_places`: the places made from the views alone over
  the true trajectory, each view coloured by its place, with the loop closures
  (a view and the earlier view it revisits) as red edges;
* :func:`write_loops_report`: ``index.html`` with both per log, the figures'
  table and ``report.json``.

Inputs are plain arrays (positions in metres); matplotlib is imported only here. Both pages are
written whole or not at all: their files go to a temporary folder beside the report folder and are
renamed into it at the end (inside a command's :class:`~fingerloc.atomic.OutputGroup`, together with
the command's other outputs; on an error the report folder stays as it was).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from .html import Page
from .staging import staged_report

__all__ = ["draw_fingerprint_places", "draw_pr_curves", "write_loops_report", "write_places_report"]

_DPI = 100


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_pr_curves(
    path: str | Path, curves: Mapping[str, tuple[Any, Any]], *, title: str = "", positives: int | None = None
) -> Path:
    """Precision against recall of each method (a step curve), written as a PNG.

    Parameters
    ----------
    path : path
        The PNG to write.
    curves : mapping of str -> (precision, recall)
        Per method, arrays of the same length (:class:`~fingerloc.experiments.loops.PRCurve`'s).
    title : str
    positives : int, optional
        Shown in the title: the queries with a true match.
    """
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.0, 4.6))
    for name, (precision, recall) in curves.items():
        p = np.asarray(precision, dtype=np.float64).reshape(-1)
        r = np.asarray(recall, dtype=np.float64).reshape(-1)
        if p.size != r.size:
            raise InvalidParameterError(f"curve {name!r}: precision and recall differ in length ({p.size}, {r.size})")
        style = {"lw": 2.0} if name.startswith("fingerprint") else {"lw": 1.2, "ls": "--"}
        ax.step(r, p, where="post", label=name, **style)
    ax.set_xlim(0.0, 1.0)
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title + (f" ({positives} queries with a true match)" if positives is not None else ""), fontsize=10)
    out = Path(path)
    fig.savefig(out, dpi=_DPI, bbox_inches="tight")
    plt.close(fig)
    return out


def draw_fingerprint_places(
    path: str | Path,
    *,
    trajectory: Any,
    assignment: Any,
    closures: Any = None,
    title: str = "",
) -> Path:
    """The places made from fingerprints over the true trajectory, coloured by place, loop closures as edges.

    Parameters
    ----------
    path : path
        The PNG to write.
    trajectory : array_like, shape (n, 2) or (n, 3)
        True positions of the run's views, metres (the whole run is drawn in grey).
    assignment : array_like of int, shape (m,), m <= n
        The place of each of the first ``m`` views (negative: none).
    closures : array_like of int, shape (k, 2), optional
        Loop closures as view indices ``(view, earlier view)``.
    title : str
    """
    plt = _plt()
    from matplotlib.collections import LineCollection

    traj = np.asarray(trajectory, dtype=np.float64)
    if traj.ndim != 2 or traj.shape[1] < 2:
        raise InvalidParameterError(f"trajectory must have shape (n, 2) or (n, 3), got {traj.shape}")
    pos = traj[:, :2]
    lab = np.asarray(assignment, dtype=np.int64).reshape(-1)
    if lab.size > pos.shape[0]:
        raise InvalidParameterError(f"assignment has {lab.size} views for a trajectory of {pos.shape[0]}")
    cl = np.zeros((0, 2), np.int64) if closures is None else np.asarray(closures, dtype=np.int64).reshape(-1, 2)
    if cl.size and (cl.min() < 0 or cl.max() >= pos.shape[0]):
        raise InvalidParameterError("closures must be view indices of the trajectory")
    fig, ax = plt.subplots(figsize=(9.0, 8.0))
    ax.plot(pos[:, 0], pos[:, 1], lw=0.6, c="0.75", zorder=1, label="true trajectory")
    placed = lab >= 0
    n_places = int(lab[placed].max()) + 1 if placed.any() else 0
    cmap = plt.get_cmap("tab20")
    colours = np.array([cmap(k % 20) for k in lab[placed]]) if placed.any() else np.zeros((0, 4))
    m = lab.size
    ax.plot(pos[:m, 0], pos[:m, 1], lw=0.8, c="0.35", zorder=2, alpha=0.7)
    if placed.any():
        ax.scatter(pos[:m][placed, 0], pos[:m][placed, 1], s=14, c=colours, zorder=3, linewidths=0,
                   label=f"views by place ({n_places} places)")  # fmt: skip
        if n_places <= 80:
            for p in range(n_places):
                q = pos[:m][lab == p]
                if q.size:
                    mx, my = np.median(q, axis=0)
                    ax.annotate(str(p), (mx, my), fontsize=6, ha="center", va="center", zorder=5, color="k")
    if cl.size:
        segs = np.stack([pos[cl[:, 0]], pos[cl[:, 1]]], axis=1)
        ax.add_collection(LineCollection(list(segs), colors="tab:red", linewidths=1.2, zorder=4,
                                         label=f"loop closures ({cl.shape[0]})"))  # fmt: skip
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_title(title, fontsize=10)
    out = Path(path)
    fig.savefig(out, dpi=_DPI, bbox_inches="tight")
    plt.close(fig)
    return out


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)


@staged_report
def write_loops_report(
    out_dir: str | Path,
    logs: Sequence[Mapping[str, Any]],
    *,
    pooled: Mapping[str, Any] | None = None,
    protocol: Mapping[str, Any] | None = None,
) -> Path:
    """Write ``index.html``, its figures and ``report.json`` for a loop-closure benchmark.

    Parameters
    ----------
    out_dir : path
        The report folder (created with its parents when missing; its files of the same names are replaced).
    logs : sequence of mapping
        Per log: ``name``; ``metrics`` (method -> figures, as ``bench loops --json``);
        ``curves`` (method -> (precision, recall)); ``positives``; optionally
        ``trajectory`` (n, 2), ``assignment`` (m,), ``closures`` (k, 2) and
        ``map`` (the fingerprint map's figures).
    pooled : mapping, optional
        ``metrics``, ``curves`` and ``positives`` over every log.
    protocol : mapping, optional
        Shown as a list (``D``, ``T``...).

    Returns
    -------
    Path
        ``index.html``.
    """
    out = Path(out_dir)  # a staged folder (staged_report)
    _loops_files(out, logs, pooled=pooled, protocol=protocol)
    return out / "index.html"


def _loops_files(
    out: Path,
    logs: Sequence[Mapping[str, Any]],
    *,
    pooled: Mapping[str, Any] | None,
    protocol: Mapping[str, Any] | None,
) -> None:
    """The files of :func:`write_loops_report`, written into the existing folder ``out``."""
    page = Page("Loop closures and places from fingerprints")
    if protocol:
        page.paragraph(
            "A query is a scan with an earlier candidate (not within the exclusion window); it has a true match "
            "when a candidate lies within the distance D. Each method names its best candidate with a score; a "
            "detection above a threshold is right when the named candidate lies within D."
        )
        page.items([f"{k}: {v}" for k, v in protocol.items()])
    header = ["log", "method", "max F1", "recall at 100 %", "recall at 99 %", "average precision"]
    rows = []
    for lg in [*logs, *([{"name": "pooled", **pooled}] if pooled else [])]:
        for m, f in lg.get("metrics", {}).items():
            rows.append([lg["name"], m, f"{f['max_f1']:.3f}", f"{f['recall_at_100']:.3f}", f"{f['recall_at_99']:.3f}",
                         f"{f['average_precision']:.3f}"])  # fmt: skip
    page.heading("Figures")
    page.table(header, rows, numeric=[False, False, True, True, True, True])
    maps = [lg for lg in logs if lg.get("map")]
    if maps:
        page.heading("Places from fingerprints")
        page.paragraph(
            "Places made from the views alone (no pose), scored against the poses: purity = share of the views "
            "within the purity radius of their place's median position; pose places = the pose-based map's "
            "places (a place every 2 m) over the same part of the run. The rest of the run is localized with the "
            "map: a later view within the purity radius of some place's median position is a query, answered "
            "right when the named place is such a place (single shot, and the place filter)."
        )

        def top1(mp: Mapping[str, Any], key: str) -> str:
            v = mp.get(key)
            return "" if v is None else f"{v:.3f}"

        page.table(
            ["log", "places", "pose places", "ratio", "purity", "loop closures", "keyframes", "queries",
             "localize top-1", "place filter top-1"],
            [[lg["name"], lg["map"]["places"], lg["map"]["pose_places"],
              f"{lg['map']['places'] / max(lg['map']['pose_places'], 1):.2f}", f"{lg['map']['purity']:.3f}",
              lg["map"].get("loop_closures", ""), lg["map"].get("keyframes", ""), lg["map"].get("map_queries", ""),
              top1(lg["map"], "localize_top1"), top1(lg["map"], "track_top1")] for lg in maps],
            numeric=[False] + [True] * 9,
        )  # fmt: skip
    for lg in [*logs, *([{"name": "pooled", **pooled}] if pooled else [])]:
        slug = _slug(str(lg["name"]))
        page.heading(str(lg["name"]))
        if lg.get("curves"):
            draw_pr_curves(out / f"pr-{slug}.png", lg["curves"], title=f"{lg['name']}: precision-recall",
                           positives=lg.get("positives"))  # fmt: skip
            page.figure(f"pr-{slug}.png", f"precision-recall curves of every method on {lg['name']}")
        if lg.get("trajectory") is not None and lg.get("assignment") is not None:
            mp = lg.get("map") or {}
            draw_fingerprint_places(
                out / f"places-{slug}.png",
                trajectory=lg["trajectory"],
                assignment=lg["assignment"],
                closures=lg.get("closures"),
                title=f"{lg['name']}: {mp.get('places', '?')} places from fingerprints, purity "
                f"{mp.get('purity', float('nan')):.3f}",
            )
            page.figure(f"places-{slug}.png", f"places made from fingerprints over the true trajectory of {lg['name']}")
    data = {
        "logs": {str(lg["name"]): {"metrics": lg.get("metrics", {}), "map": lg.get("map")} for lg in logs},
        "pooled": None if not pooled else {"metrics": pooled.get("metrics", {}), "map": pooled.get("map")},
        "protocol": dict(protocol or {}),
    }
    (out / "report.json").write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    page.write(out)


@staged_report
def write_places_report(
    out_dir: str | Path,
    *,
    labels: Sequence[str],
    assignment: Any,
    keyframes: Any,
    closures: Any = None,
    consensus: Sequence[str | None] | None = None,
    trajectory: Any = None,
    notes: Sequence[str] = (),
    figures: Mapping[str, Any] | None = None,
) -> Path:
    """Write ``index.html`` (and ``report.json``) for a map made from fingerprints (``map --places fingerprints --report``).

    Parameters
    ----------
    out_dir : path
        The report folder (created with its parents when missing; its files of the same names are replaced).
    labels : sequence of str
        Place labels (place ``j`` is ``labels[j]``).
    assignment : array_like of int, shape (m,)
        The place of each of the run's first ``m`` views.
    keyframes : array_like of int, shape (k,)
        The keyframes' view indices.
    closures : array_like of int, shape (c, 2), optional
        Loop closures as view indices ``(view, earlier view)``.
    consensus : sequence of str or None, optional
        Per place, its consensus fingerprint's letters.
    trajectory : array_like, shape (n, 2) or (n, 3), optional
        True positions of the views (when the run has poses): the map is drawn over them.
    notes : sequence of str
        Lines shown under the title (the command...).
    figures : mapping, optional
        Numbers shown as a list and kept in ``report.json`` (purity...).

    Returns
    -------
    Path
        ``index.html``.
    """
    out = Path(out_dir)  # a staged folder (staged_report)
    _places_files(out, labels=labels, assignment=assignment, keyframes=keyframes, closures=closures,
                  consensus=consensus, trajectory=trajectory, notes=notes, figures=figures)  # fmt: skip
    return out / "index.html"


def _places_files(
    out: Path,
    *,
    labels: Sequence[str],
    assignment: Any,
    keyframes: Any,
    closures: Any,
    consensus: Sequence[str | None] | None,
    trajectory: Any,
    notes: Sequence[str],
    figures: Mapping[str, Any] | None,
) -> None:
    """The files of :func:`write_places_report`, written into the existing folder ``out``."""
    lab = np.asarray(assignment, dtype=np.int64).reshape(-1)
    keys = np.asarray(keyframes, dtype=np.int64).reshape(-1)
    cl = np.zeros((0, 2), np.int64) if closures is None else np.asarray(closures, dtype=np.int64).reshape(-1, 2)
    page = Page("Places from fingerprints")
    for line in notes:
        page.paragraph(line)
    page.paragraph(
        f"{len(labels)} places from {lab.size} views ({keys.size} keyframes), {cl.shape[0]} loop closures; no pose "
        "was used to make them."
    )
    if figures:
        page.items([f"{k}: {v}" for k, v in figures.items()])
    if trajectory is not None:
        draw_fingerprint_places(out / "places.png", trajectory=trajectory, assignment=lab, closures=cl,
                                title=f"{len(labels)} places from fingerprints over the true trajectory")  # fmt: skip
        page.figure("places.png", "places made from fingerprints, coloured by place, over the true trajectory")
    key_place = lab[keys[keys < lab.size]]
    rows = []
    for j, name in enumerate(labels):
        views = np.flatnonzero(lab == j)
        cons = "" if consensus is None or j >= len(consensus) or consensus[j] is None else str(consensus[j])
        first = int(views[0]) if views.size else -1
        rows.append([name, int(views.size), int(np.count_nonzero(key_place == j)), first, cons])
    page.heading("Places")
    page.table(["place", "views", "keyframes", "first view", "consensus fingerprint"], rows,
               numeric=[False, True, True, True, False])  # fmt: skip
    data = {
        "places": list(labels),
        "views_per_place": [r[1] for r in rows],
        "closures": cl.tolist(),
        "figures": dict(figures or {}),
    }
    (out / "report.json").write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    page.write(out)
