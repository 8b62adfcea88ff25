"""Report folders for a user's own data: map, localize, track and panorama reports.

Each ``write_*_report`` function takes plain data (numpy arrays, names,
:class:`~fingerloc.reporting.views.FeatureView`), draws its figures as PNG
files into a folder and writes ``index.html`` beside them (no JavaScript,
readable offline, every image with alt text) and ``report.json`` (the
figures' numbers with the full place names). matplotlib is imported only when
a figure is drawn.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._types import FArray, IArray
from ..errors import InvalidParameterError
from .html import Page, ellipsize_middle, esc, table_html
from .staging import staged_report
from .views import FeatureView, draw_view_thumbnail, legend_text

__all__ = [
    "alignment_rows",
    "detect_jumps",
    "most_confused",
    "recoveries_after",
    "scan_end_points",
    "write_localize_report",
    "write_map_report",
    "write_panorama_report",
    "write_track_report",
]



def _f2(a: ArrayLike | None, name: str, cols: tuple[int, ...] = (2,)) -> FArray | None:
    """An (n, 2) float array from (n, >=2) input (extra columns such as theta dropped), or None."""
    if a is None:
        return None
    x = np.asarray(a, dtype=np.float64)
    if x.size == 0:
        return np.zeros((0, 2))
    if x.ndim != 2 or x.shape[1] < 2:
        raise InvalidParameterError(f"{name}: expected an (n, 2) or (n, 3) array of metres, got shape {x.shape}")
    return np.ascontiguousarray(x[:, :2])


def _write_json(out: Path, data: dict[str, Any]) -> None:
    (out / "report.json").write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")


def _view_cell(out: Path, rel: str, view: FeatureView | None, caption: str, *, extra: str = "") -> str:
    """HTML of one view: its thumbnail, a caption, the feature counts and the fingerprint string."""
    if view is None:
        return f'<div class="view"><div class="name">{esc(caption)}</div><p class="note">no view stored</p></div>'
    draw_view_thumbnail(view, out / rel, size=140)
    counts = ", ".join(f"{k} {v}" for k, v in view.counts().items()) or "no feature"
    alt = f"features of {caption}: {counts}"
    return (
        f'<div class="view"><img src="{esc(rel)}" alt="{esc(alt)}" width="140" height="140">'
        f'<div class="name">{esc(caption)}</div><div>{esc(counts)}</div>'
        f'<div class="fp">{esc(view.fingerprint) or "(empty)"}</div>{extra}</div>'
    )


# ----------------------------------------------------------------------------- map


def scan_end_points(scans: Sequence[Any], *, max_points: int = 200_000) -> FArray:
    """Laser end points of scans with a pose, in the world frame, evenly thinned to at most ``max_points``.

    Parameters
    ----------
    scans : sequence of fingerloc.sensors.Scan
        Scans without a pose are skipped.
    max_points : int, default 200000

    Returns
    -------
    ndarray, shape (m, 2)
        Metres.
    """
    parts = []
    for s in scans:
        if s.pose is None:
            continue
        x, y, th = s.pose
        pts = s.points()
        c, si = math.cos(th), math.sin(th)
        parts.append(np.column_stack([x + c * pts[:, 0] - si * pts[:, 1], y + si * pts[:, 0] + c * pts[:, 1]]))
    out = np.concatenate(parts) if parts else np.zeros((0, 2))
    if out.shape[0] > max_points:
        out = out[:: math.ceil(out.shape[0] / max_points)]
    return out


def _edge_indices(edges: Sequence[tuple[Any, Any]], names: Sequence[str]) -> IArray:
    col = {n: j for j, n in enumerate(names)}
    out = []
    for a, b in edges:
        ia = col.get(a, a) if isinstance(a, str) else int(a)
        ib = col.get(b, b) if isinstance(b, str) else int(b)
        if not isinstance(ia, int) or not isinstance(ib, int) or not (0 <= ia < len(names) and 0 <= ib < len(names)):
            raise InvalidParameterError(f"edges: ({a!r}, {b!r}) is not a pair of places")
        if ia != ib:
            out.append((ia, ib))
    return np.array(out, dtype=np.int64).reshape(-1, 2)


@staged_report
def write_map_report(
    out_dir: str | Path,
    *,
    place_names: Sequence[str],
    centres: ArrayLike,
    radius: float | ArrayLike,
    edges: Sequence[tuple[Any, Any]] = (),
    trajectory: ArrayLike | None = None,
    scan_points: ArrayLike | None = None,
    views_per_place: ArrayLike | None = None,
    place_views: Sequence[FeatureView | None] | None = None,
    queries: ArrayLike | None = None,
    query_right: ArrayLike | None = None,
    title: str = "fingerloc map report",
    notes: Sequence[str] = (),
) -> Path:
    """Write a map report: the places over the run, and per place its views and one view's features.

    Parameters
    ----------
    out_dir : str or Path
        The report folder (created; its report files are overwritten).
    place_names : sequence of str, length P
    centres : array_like, shape (P, 2)
        Place centres, metres (world frame).
    radius : float or array_like, shape (P,)
        Radius of each place, metres.
    edges : sequence of (a, b)
        Place-graph edges, as place indices or names.
    trajectory : array_like, shape (T, 2) or (T, 3), optional
        The robot's poses along the run, metres (a third column, the heading, is ignored).
    scan_points : array_like, shape (N, 2), optional
        Laser end points in the world frame, metres (thinned for drawing).
    views_per_place : array_like of int, shape (P,), optional
        Number of learned views of each place.
    place_views : sequence of FeatureView or None, length P, optional
        One view of each place, drawn as a thumbnail with its fingerprint.
    queries : array_like, shape (Q, 2), optional
        Query positions, metres, drawn green where ``query_right`` and red elsewhere.
    query_right : array_like of bool, shape (Q,), optional
    title : str
    notes : sequence of str
        Lines for the page's first paragraph list (what was run, on which file).

    Returns
    -------
    Path
        ``out_dir / "index.html"``.
    """
    from . import figures

    names = [str(n) for n in place_names]
    c = _f2(centres, "centres")
    assert c is not None
    if c.shape[0] != len(names):
        raise InvalidParameterError(f"centres: one per place is needed, got {c.shape[0]} for {len(names)} places")
    rad = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(names),)).copy()
    if not np.all(np.isfinite(rad) & (rad >= 0)):
        raise InvalidParameterError("radius: must be finite metres >= 0")
    e = _edge_indices(edges, names)
    views = None if views_per_place is None else np.asarray(views_per_place, dtype=np.int64).reshape(-1)
    if views is not None and views.size != len(names):
        raise InvalidParameterError(f"views_per_place: one count per place is needed, got {views.size}")
    if place_views is not None and len(place_views) != len(names):
        raise InvalidParameterError(f"place_views: one view (or None) per place is needed, got {len(place_views)}")
    traj = _f2(trajectory, "trajectory")
    pts = _f2(scan_points, "scan_points")
    q = _f2(queries, "queries")
    qr = None if query_right is None else np.asarray(query_right, dtype=bool).reshape(-1)
    if q is not None and (qr is None or qr.size != q.shape[0]):
        raise InvalidParameterError("query_right: one flag per query is needed")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    page = Page(title)
    facts = [
        *notes,
        f"{len(names)} places, {e.shape[0]} graph edges"
        + (f", {int(views.sum())} learned views" if views is not None else "")
        + (f", {traj.shape[0]} poses along the run" if traj is not None else "")
        + (f", {pts.shape[0]} scan end points" if pts is not None else "")
        + ".",
    ]
    if rad.size:
        facts.append(
            f"Place radius {np.min(rad):.2f}-{np.max(rad):.2f} m." if np.ptp(rad) else f"Place radius {rad[0]:.2f} m."
        )
    page.items(facts)
    page.heading("The places over the run")
    figures.draw_map(
        out / "map.png",
        centres=c,
        radius=rad,
        edges=e,
        trajectory=traj,
        scan_points=pts,
        names=names,
        queries=q,
        query_right=qr,
        title=f"{len(names)} places",
    )
    page.figure(
        "map.png",
        f"map of {len(names)} places: centres (black dots) with their radius circles, place-graph edges (orange), "
        "the trajectory (blue) over the scans' end points (grey)",
        "Scan end points (grey) in the world frame, the trajectory (blue), each place's centre (black) and radius "
        "(circle), and the place graph's edges (orange): which place the robot passed from one to another."
        + (" Queries right (green) or wrong (red)." if q is not None else ""),
    )
    if views is not None and views.size:
        figures.draw_views_histogram(out / "views.png", views)
        page.figure("views.png", "histogram of the number of learned views per place")
    page.heading("Places")
    if place_views is not None:
        page.paragraph(legend_text(), cls="note")
    cards = []
    for j, n in enumerate(names):
        img = ""
        view = place_views[j] if place_views is not None else None
        if view is not None:
            rel = f"places/p{j:05d}.png"
            draw_view_thumbnail(view, out / rel, size=120)
            counts = ", ".join(f"{k} {v}" for k, v in view.counts().items()) or "no feature"
            img = (
                f'<img src="{esc(rel)}" alt="{esc(f"features of one view of {n}: {counts}")}" width="120" height="120">'
            )
        fp = f'<div class="fp">{esc(view.fingerprint)}</div>' if view is not None else ""
        nv = f"<div>{int(views[j])} view{'s' if views[j] != 1 else ''}</div>" if views is not None else ""
        pos = f"<div>({c[j, 0]:.1f}, {c[j, 1]:.1f}) m</div>"
        cards.append(f'<div class="card">{img}<div class="name">{esc(n)}</div>{nv}{pos}{fp}</div>')
    page.raw('<div class="cards">' + "".join(cards) + "</div>")
    _write_json(
        out,
        {
            "places": [
                {
                    "place": n,
                    "centre_m": [float(c[j, 0]), float(c[j, 1])],
                    "radius_m": float(rad[j]),
                    "views": None if views is None else int(views[j]),
                    "fingerprint": None
                    if place_views is None or place_views[j] is None
                    else place_views[j].fingerprint,  # type: ignore[union-attr]
                }
                for j, n in enumerate(names)
            ],
            "edges": [[names[a], names[b]] for a, b in e.tolist()],
        },
    )
    return page.write(out)


# ----------------------------------------------------------------------------- localize


def _posterior_bars(names: Sequence[str], proba: FArray, *, truth: int, answer: int, top: int = 8) -> str:
    """The ``top`` most probable places (and the true place) as an HTML table of bars."""
    order = [int(j) for j in np.argsort(-proba, kind="stable")[:top]]
    if truth >= 0 and truth not in order:
        order.append(truth)
    rows = []
    for j in order:
        colour = "#2ca02c" if j == truth else ("#d62728" if j == answer else "#999")
        who = " (true)" if j == truth else (" (answer)" if j == answer else "")
        w = max(0.0, min(100.0, 100.0 * float(proba[j])))
        rows.append(
            f'<tr><td>{esc(names[j])}{who}</td><td class="num">{proba[j]:.3f}</td>'
            f'<td style="width:120px"><div style="background:{colour};height:.8em;width:{w:.1f}%"></div></td></tr>'
        )
    return (
        '<div><table class="bars"><thead><tr><th>place</th><th>posterior</th><th></th></tr></thead><tbody>'
        + "".join(rows)
        + "</tbody></table></div>"
    )


def _ranks_from_log_proba(logp: FArray, truth: IArray) -> IArray:
    """1-based rank of the true place in each row (ties counted in its favour)."""
    t = np.clip(truth, 0, None)
    own = logp[np.arange(logp.shape[0]), t]
    return (1 + np.sum(logp > own[:, None], axis=1)).astype(np.int64)


def alignment_rows(a: str, b: str, path: Sequence[tuple[int | None, int | None]]) -> tuple[str, str, str]:
    """Two fingerprints written one above the other along an alignment path, with a match line between.

    Parameters
    ----------
    a, b : str
        The strings.
    path : sequence of (i or None, j or None)
        Aligned letter pairs (``None``: a gap), as ``global_alignment(..., return_alignment=True)`` gives.

    Returns
    -------
    (str, str, str)
        ``a`` with ``-`` at its gaps, the match line (``|`` same letter, ``.`` substitution, space at a gap), and ``b``.
    """
    top, mid, bottom = [], [], []
    for i, j in path:
        x = a[i] if i is not None else "-"
        y = b[j] if j is not None else "-"
        top.append(x)
        bottom.append(y)
        mid.append(" " if i is None or j is None else ("|" if x == y else "."))
    return "".join(top), "".join(mid), "".join(bottom)


def most_confused(confusion: IArray, k: int) -> IArray:
    """Indices of the ``k`` places with the most wrong answers (as true place or as answer), in their order.

    Parameters
    ----------
    confusion : array_like of int, shape (P, P)
        Counts, rows true place, columns answer.
    k : int
    """
    m = np.asarray(confusion, dtype=np.int64)
    off = m - np.diag(np.diag(m))
    score = off.sum(axis=0) + off.sum(axis=1)
    busy = np.flatnonzero(score > 0)
    top = busy[np.argsort(-score[busy], kind="stable")[:k]]
    return np.sort(top)


@staged_report
def write_localize_report(
    out_dir: str | Path,
    *,
    classes: Sequence[str],
    log_proba: ArrayLike | None = None,
    truth: ArrayLike | None = None,
    predicted: ArrayLike | None = None,
    ranks: ArrayLike | None = None,
    query_names: Sequence[str] | None = None,
    query_views: Sequence[FeatureView | None] | None = None,
    place_views: Sequence[FeatureView | None] | None = None,
    n_worst: int = 12,
    max_confusion: int = 25,
    title: str = "fingerloc localize report",
    notes: Sequence[str] = (),
) -> Path:
    """Write a localize report: summary, per-place top-1, confusion, and the worst queries.

    Parameters
    ----------
    out_dir : str or Path
        The report folder (created; its report files are overwritten).
    classes : sequence of str, length P
        The places, in the columns' order.
    log_proba : array_like, shape (n, P), optional
        Log posterior of each query over the places. Without it, ``predicted``
        (and, for labelled queries, ``ranks``) are needed.
    truth : array_like of int, shape (n,), optional
        Index of each query's true place, -1 where unknown.
    predicted : array_like of int, shape (n,), optional
        The answer's index per query (default: the argmax of ``log_proba``).
    ranks : array_like of int, shape (n,), optional
        1-based rank of the true place per query (default: from ``log_proba``).
    query_names : sequence of str, length n, optional
    query_views : sequence of FeatureView or None, length n, optional
        What each query saw; drawn for the worst queries.
    place_views : sequence of FeatureView or None, length P, optional
        A reference view of each place (e.g. its medoid), drawn beside the worst queries.
    n_worst : int, default 12
        Worst queries shown (true place ranked lowest; without labels, the least confident answers).
    max_confusion : int, default 25
        Beyond this many places, the confusion matrix shows only the most confused ones.
    title : str
    notes : sequence of str

    Returns
    -------
    Path
        ``out_dir / "index.html"``.
    """
    from . import figures

    names = [str(c) for c in classes]
    p = len(names)
    logp = None if log_proba is None else np.asarray(log_proba, dtype=np.float64)
    if logp is not None and (logp.ndim != 2 or logp.shape[1] != p):
        raise InvalidParameterError(f"log_proba: expected shape (n, {p}), got {logp.shape}")
    if predicted is None:
        if logp is None:
            raise InvalidParameterError("give log_proba or predicted")
        pred = np.argmax(logp, axis=1).astype(np.int64)
    else:
        pred = np.asarray(predicted, dtype=np.int64).reshape(-1)
    n = pred.size
    tr = np.full(n, -1, dtype=np.int64) if truth is None else np.asarray(truth, dtype=np.int64).reshape(-1)
    if tr.size != n or (logp is not None and logp.shape[0] != n):
        raise InvalidParameterError(f"truth, predicted and log_proba must describe the same {n} queries")
    if np.any(tr >= p) or np.any(pred < 0) or np.any(pred >= p):
        raise InvalidParameterError(f"truth and predicted must be place indices below {p}")
    lab = tr >= 0
    if ranks is not None:
        rk = np.asarray(ranks, dtype=np.int64).reshape(-1)
    elif logp is not None:
        rk = _ranks_from_log_proba(logp, tr)
    else:
        rk = np.where(pred == tr, 1, 2)
    if rk.size != n:
        raise InvalidParameterError(f"ranks: one per query is needed, got {rk.size} for {n}")
    qn = [f"query {i + 1}" for i in range(n)] if query_names is None else [str(x) for x in query_names]
    if len(qn) != n:
        raise InvalidParameterError(f"query_names: one per query is needed, got {len(qn)} for {n}")
    if query_views is not None and len(query_views) != n:
        raise InvalidParameterError(f"query_views: one per query is needed, got {len(query_views)} for {n}")
    if place_views is not None and len(place_views) != p:
        raise InvalidParameterError(f"place_views: one per place is needed, got {len(place_views)} for {p}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    page = Page(title)
    js: dict[str, Any] = {"queries": n, "labelled": int(lab.sum()), "places": p}

    # ------------------------------------------------------------------ summary
    page.heading("Summary")
    facts = [*notes, f"{n} queries, {int(lab.sum())} with a known place; {p} learned places."]
    if lab.any():
        r = rk[lab]
        top1 = float(np.mean(r == 1))
        js.update(top1=top1, mean_rank=float(np.mean(r)), recall5=float(np.mean(r <= 5)))
        facts.append(
            f"Right classification (top-1): {100 * top1:.1f}% ({int(np.sum(r == 1))} of {r.size}); mean rank of the "
            f"true place {np.mean(r):.2f}; true place within the first 5: {100 * np.mean(r <= 5):.1f}%."
        )
    if logp is not None and n:
        conf = np.exp(np.max(logp, axis=1))
        facts.append(f"Median probability of the answer: {np.median(conf):.3f}.")
    page.items(facts)
    if lab.any():
        figures.draw_rank_histogram(out / "ranks.png", rk[lab], p)
        page.figure(
            "ranks.png",
            "histogram of the rank of the true place among the answers",
            "Rank of the true place in each labelled query's posterior: 1 is a right answer.",
        )

    # ------------------------------------------------------------------ per place
    per_place_table = ""
    if lab.any():
        page.heading("Per place")
        cnt = np.bincount(tr[lab], minlength=p)
        right = np.bincount(tr[lab & (pred == tr)], minlength=p)
        rank_sum = np.bincount(tr[lab], weights=rk[lab].astype(np.float64), minlength=p)
        has = np.flatnonzero(cnt)
        top1_p = right[has] / cnt[has]
        figures.draw_per_place(out / "per_place.png", [names[j] for j in has], top1_p, cnt[has])
        page.figure(
            "per_place.png",
            f"per-place top-1 of {has.size} places with labelled queries, sorted from worst to best",
            "Share of each place's queries answered right, worst places first.",
        )
        conf_m = np.zeros((p, p), dtype=np.int64)
        np.add.at(conf_m, (tr[lab], pred[lab]), 1)
        rows = []
        per_place_js = []
        for k in np.argsort(top1_p, kind="stable"):
            j = int(has[k])
            wrong = conf_m[j].copy()
            wrong[j] = 0
            w = int(np.argmax(wrong))
            often = f"{names[w]} ({int(wrong[w])})" if wrong[w] else "-"
            rows.append((names[j], int(cnt[j]), f"{top1_p[k]:.2f}", f"{rank_sum[j] / cnt[j]:.2f}", often))
            per_place_js.append(
                {"place": names[j], "queries": int(cnt[j]), "top1": float(top1_p[k]),
                 "mean_rank": float(rank_sum[j] / cnt[j]), "most_often_instead": names[w] if wrong[w] else None}
            )  # fmt: skip
        per_place_table = table_html(
            ["place", "queries", "top-1", "mean rank", "most often answered instead (times)"],
            rows,
            numeric=[False, True, True, True, False],
        )
        page.paragraph("The table of every place, worst first, is at the end of the page.", cls="note")
        js["per_place"] = per_place_js

        # -------------------------------------------------------------- confusion
        page.heading("Confusion")
        shown = np.flatnonzero(cnt | np.bincount(pred[lab], minlength=p))
        note = ""
        if shown.size > max_confusion:
            shown = most_confused(conf_m, max_confusion)
            note = (
                f" Only the {shown.size} places with the most wrong answers (as true place or as answer) are shown, "
                f"of {np.flatnonzero(cnt | np.bincount(pred[lab], minlength=p)).size}; the table below lists the "
                "most frequent mistakes over all places."
            )
        if shown.size:
            from .. import plot

            sub = conf_m[np.ix_(shown, shown)]
            plot.plot_confusion(
                sub,
                [ellipsize_middle(names[j], 24) for j in shown],
                out / "confusion.png",
                title=f"confusion matrix, {shown.size} places",
            )
            page.figure(
                "confusion.png",
                f"confusion matrix of {shown.size} places: rows true place, columns answer",
                "Rows: true place; columns: the answer; cells: number of queries." + note,
            )
        off = conf_m.copy()
        np.fill_diagonal(off, 0)
        pairs = np.argwhere(off > 0)
        if pairs.size:
            order = np.argsort(-off[pairs[:, 0], pairs[:, 1]], kind="stable")[:20]
            page.paragraph("Most frequent mistakes:")
            page.table(
                ["true place", "answered", "times"],
                [(names[a], names[b], int(off[a, b])) for a, b in pairs[order].tolist()],
                numeric=[False, False, True],
            )
            js["mistakes"] = [[names[a], names[b], int(off[a, b])] for a, b in pairs[order].tolist()]
        else:
            page.paragraph("No mistake: every labelled query was answered right.")

    # ------------------------------------------------------------------ worst queries
    if n:
        if lab.any():
            wrong_idx = np.flatnonzero(lab & (rk > 1))
            p_true = np.exp(logp[wrong_idx, tr[wrong_idx]]) if logp is not None else np.zeros(wrong_idx.size)
            order = np.lexsort((p_true, -rk[wrong_idx]))
            worst = wrong_idx[order][:n_worst]
            head = "Worst queries (true place ranked lowest)"
        elif logp is not None:
            worst = np.argsort(np.max(logp, axis=1), kind="stable")[:n_worst]
            head = "Least confident answers"
        else:
            worst = np.zeros(0, dtype=np.int64)
            head = ""
        if worst.size:
            page.heading(head)
            if query_views is not None or place_views is not None:
                page.paragraph(legend_text(), cls="note")
            from ..align import global_alignment

            js["worst"] = []
            for k, i in enumerate(worst.tolist()):
                t, a = int(tr[i]), int(pred[i])
                page.heading(f"{qn[i]}", level=3)
                line = f"answer {names[a]}" + (f"; true place {names[t]}, ranked {int(rk[i])}" if t >= 0 else "")
                if logp is not None:
                    line += f"; P(answer) {math.exp(logp[i, a]):.3f}" + (
                        f", P(true place) {math.exp(logp[i, t]):.3g}" if t >= 0 else ""
                    )
                page.paragraph(line)
                cells = []
                if logp is not None:
                    cells.append(_posterior_bars(names, np.exp(logp[i]), truth=t, answer=a))
                qv = query_views[i] if query_views is not None else None
                if query_views is not None:
                    cells.append(_view_cell(out, f"worst/q{k:03d}_query.png", qv, f"the query: {qn[i]}"))
                aligned: list[tuple[str, str, float, tuple[str, str, str]]] = []
                rec: dict[str, Any] = {"query": qn[i], "answer": names[a], "true": names[t] if t >= 0 else None,
                                       "rank_of_true": int(rk[i]) if t >= 0 else None}  # fmt: skip
                if place_views is not None:
                    for who, j in (("true place", t), ("answer", a)):
                        if j < 0:
                            continue
                        pv = place_views[j]
                        extra = ""
                        if qv is not None and pv is not None:
                            cost, path = global_alignment(qv.fingerprint, pv.fingerprint, return_alignment=True)
                            extra = f"<div>alignment cost to the query: {float(cost):g}</div>"
                            rec[f"alignment_cost_{who.replace(' ', '_')}"] = float(cost)
                            aligned.append(
                                (who, names[j], float(cost), alignment_rows(qv.fingerprint, pv.fingerprint, path))
                            )
                        cells.append(
                            _view_cell(out, f"worst/q{k:03d}_{who[0]}.png", pv, f"{who}: {names[j]}", extra=extra)
                        )
                page.raw('<div class="row">' + "".join(cells) + "</div>")
                for who, name, cost, (top, mid, bottom) in aligned:
                    page.raw(
                        f'<div class="note">query against the {esc(who)} ({esc(name)}), cost {cost:g} '
                        "(| same letter, . substitution, - gap):</div>"
                        f'<pre class="fp">{esc(top)}\n{esc(mid)}\n{esc(bottom)}</pre>'
                    )
                js["worst"].append(rec)
    if per_place_table:
        page.heading("All places")
        page.details(f"{len(js['per_place'])} places with labelled queries, worst first", per_place_table,
                     open_=len(js["per_place"]) <= 60)  # fmt: skip
    _write_json(out, js)
    return page.write(out)


# ----------------------------------------------------------------------------- track


def detect_jumps(poses: ArrayLike, *, min_jump_m: float = 5.0, factor: float = 20.0) -> IArray:
    """Steps where the pose jumps (a kidnapping, or spliced runs): far beyond the usual step length.

    Parameters
    ----------
    poses : array_like, shape (T, 2) or (T, 3)
        Poses along the run, metres.
    min_jump_m : float, default 5
        A jump is at least this long, metres.
    factor : float, default 20
        ... and at least this many times the median step length.

    Returns
    -------
    ndarray of int
        Index ``t`` of each step whose pose is far from step ``t - 1``'s.
    """
    x = _f2(poses, "poses")
    assert x is not None
    if x.shape[0] < 2:
        return np.zeros(0, dtype=np.int64)
    d = np.linalg.norm(np.diff(x, axis=0), axis=1)
    med = float(np.median(d))
    return (np.flatnonzero(d > max(min_jump_m, factor * med)) + 1).astype(np.int64)


def recoveries_after(kidnaps: ArrayLike, right: ArrayLike) -> IArray:
    """For each kidnapping step, the first step from it on where the answer is right and stays right until the next
    wrong labelled step is after the next kidnapping (or the end); -1 where it never recovers.

    Parameters
    ----------
    kidnaps : array_like of int, shape (K,)
        Steps where the robot was moved.
    right : array_like of int, shape (T,)
        1 right, 0 wrong, -1 unknown (unlabelled or not observed).
    """
    k = np.sort(np.asarray(kidnaps, dtype=np.int64).reshape(-1))
    r = np.asarray(right, dtype=np.int64).reshape(-1)
    out = []
    for i, s in enumerate(k.tolist()):
        end = int(k[i + 1]) if i + 1 < k.size else r.size
        seg = r[s:end]
        wrong = np.flatnonzero(seg == 0)
        after = int(wrong[-1]) + 1 if wrong.size else 0
        right_after = np.flatnonzero(seg[after:] == 1)
        out.append(s + after + int(right_after[0]) if right_after.size else -1)
    return np.array(out, dtype=np.int64)


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(start, stop) of each run of True."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


@staged_report
def write_track_report(
    out_dir: str | Path,
    *,
    classes: Sequence[str],
    log_posterior: ArrayLike,
    single_log_likelihood: ArrayLike | None = None,
    truth: ArrayLike | None = None,
    poses: ArrayLike | None = None,
    centres: ArrayLike | None = None,
    step_names: Sequence[str] | None = None,
    kidnaps: ArrayLike = (),
    title: str = "fingerloc track report",
    notes: Sequence[str] = (),
) -> Path:
    """Write a track report: right/wrong along the trajectory, P(true place) and entropy over time.

    Parameters
    ----------
    out_dir : str or Path
        The report folder (created; its report files are overwritten).
    classes : sequence of str, length P
    log_posterior : array_like, shape (T, P)
        The filter's log posterior after each step.
    single_log_likelihood : array_like, shape (T, P), optional
        Each step's own (scaled) log-likelihoods, NaN rows where the step only predicted; normalised
        per row to the single-shot posterior.
    truth : array_like of int, shape (T,), optional
        True place index per step, -1 where unknown.
    poses : array_like, shape (T, 2) or (T, 3), optional
        Poses along the run, metres.
    centres : array_like, shape (P, 2), optional
        Place centres, metres.
    step_names : sequence of str, length T, optional
    kidnaps : array_like of int
        Steps where the robot was moved (kidnapped, or two runs spliced); marked with the recovery after each.
    title : str
    notes : sequence of str

    Returns
    -------
    Path
        ``out_dir / "index.html"``.
    """
    from scipy.special import logsumexp

    from . import figures

    names = [str(c) for c in classes]
    p = len(names)
    lp = np.asarray(log_posterior, dtype=np.float64)
    if lp.ndim != 2 or lp.shape[1] != p:
        raise InvalidParameterError(f"log_posterior: expected shape (T, {p}), got {lp.shape}")
    t_n = lp.shape[0]
    tr = np.full(t_n, -1, dtype=np.int64) if truth is None else np.asarray(truth, dtype=np.int64).reshape(-1)
    if tr.size != t_n:
        raise InvalidParameterError(f"truth: one per step is needed, got {tr.size} for {t_n}")
    if single_log_likelihood is not None:
        ll = np.asarray(single_log_likelihood, dtype=np.float64)
        if ll.shape != lp.shape:
            raise InvalidParameterError(f"single_log_likelihood: expected shape {lp.shape}, got {ll.shape}")
        observed = ~np.all(np.isnan(ll), axis=1)
        single = np.full_like(ll, np.nan)
        if observed.any():
            x = ll[observed]
            single[observed] = x - logsumexp(x, axis=1, keepdims=True)
    else:
        observed = np.ones(t_n, dtype=bool)
        single = np.full_like(lp, np.nan)
    ps = _f2(poses, "poses")
    if ps is not None and ps.shape[0] != t_n:
        raise InvalidParameterError(f"poses: one per step is needed, got {ps.shape[0]} for {t_n}")
    cs = _f2(centres, "centres")
    sn = [f"step {t}" for t in range(t_n)] if step_names is None else [str(s) for s in step_names]
    kid = np.asarray(kidnaps, dtype=np.int64).reshape(-1)
    if np.any((kid < 0) | (kid >= t_n)):
        raise InvalidParameterError(f"kidnaps: steps must lie in [0, {t_n}), got {kid.tolist()}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    best = np.argmax(lp, axis=1)
    post = np.exp(lp - logsumexp(lp, axis=1, keepdims=True))
    with np.errstate(divide="ignore", invalid="ignore"):
        ent = -np.sum(np.where(post > 0, post * np.log2(post), 0.0), axis=1)
    lab = (tr >= 0) & observed
    right = np.where(lab, (best == tr).astype(np.int64), -1)
    idx = np.arange(t_n)
    p_f = np.where(tr >= 0, post[idx, np.clip(tr, 0, None)], np.nan)
    p_s = np.where(tr >= 0, np.exp(single[idx, np.clip(tr, 0, None)]), np.nan)
    rec = recoveries_after(kid, right)

    page = Page(title)
    page.heading("Summary")
    facts = [*notes, f"{t_n} steps ({int(observed.sum())} observed), {p} places."]
    js: dict[str, Any] = {"steps": t_n, "observed_steps": int(observed.sum()), "places": p}
    if lab.any():
        f_top1 = float(np.mean(right[lab] == 1))
        s_right = np.argmax(np.where(np.isnan(single), -np.inf, single), axis=1) == tr
        s_top1 = float(np.mean(s_right[lab]))
        js.update(filtered_top1=f_top1, single_shot_top1=s_top1)
        facts.append(
            f"Labelled observed steps: {int(lab.sum())}; filtered top-1 {f_top1:.3f}"
            + (f", single-shot top-1 {s_top1:.3f}" if single_log_likelihood is not None else "")
            + "."
        )
    facts.append(
        f"Median entropy of the filtered posterior: {np.median(ent):.2f} bits (uniform: {math.log2(max(p, 1)):.2f})."
    )
    if kid.size:
        got = rec[rec >= 0]
        facts.append(
            f"{kid.size} kidnapping(s) (jumps of the pose); recovered from {got.size}"
            + (
                f", after {', '.join(str(int(r - k)) for k, r in zip(kid, rec, strict=True) if r >= 0)} steps"
                if got.size
                else ""
            )
            + "."
        )
    page.items(facts)
    traj_path = out / "trajectory.png" if ps is not None else None
    figures.draw_track(
        traj_path,
        out / "over_time.png",
        steps=idx,
        p_true_filtered=p_f,
        p_true_single=p_s,
        entropy_bits=ent,
        max_entropy_bits=math.log2(max(p, 1)),
        right=right.astype(np.int8),
        observed=observed,
        kidnaps=kid.tolist(),
        recoveries=[int(r) for r in rec if r >= 0],
        poses=ps,
        centres=cs,
    )
    if traj_path is not None:
        page.heading("Along the trajectory")
        page.figure(
            "trajectory.png",
            "trajectory with each labelled step coloured green where the filtered answer is right, red where wrong",
            "Each pose of the run: green where the filter's best place is the true one, red where it is not, "
            "grey where the true place is unknown or the step only predicted."
            + (" Crosses: kidnappings; circles: where the filter found the right place again." if kid.size else ""),
        )
    else:
        page.paragraph("No poses: the trajectory figure needs a pose on every step.", cls="note")
    page.heading("Over time")
    page.figure(
        "over_time.png",
        "the true place's probability (filtered and single-shot) and the filtered posterior's entropy, per step",
        "Top: probability of the true place, filtered (line) and from each observation alone (dots). Bottom: entropy "
        "of the filtered posterior in bits."
        + (" Dashed red: kidnappings; dotted green: recoveries." if kid.size else ""),
    )
    runs = sorted(_runs(right == 0), key=lambda r: r[0] - r[1])[:10]
    if runs:
        page.heading("Longest wrong stretches")
        page.table(
            ["first step", "last step", "steps", "from", "to"],
            [(a, b - 1, b - a, sn[a], sn[b - 1]) for a, b in runs],
            numeric=[True, True, True, False, False],
        )
    js["kidnaps"] = kid.tolist()
    js["recoveries"] = rec.tolist()
    js["wrong_stretches"] = [[a, b - 1] for a, b in runs]
    _write_json(out, js)
    return page.write(out)


# ----------------------------------------------------------------------------- panorama


@staged_report
def write_panorama_report(
    out_dir: str | Path,
    image: ArrayLike,
    *,
    edges: ArrayLike,
    patches: ArrayLike = (),
    patch_hues_deg: ArrayLike = (),
    bearing_offset: float = 0.0,
    clockwise: bool = True,
    reference_image: ArrayLike | None = None,
    reference_edges: ArrayLike = (),
    reference_patches: ArrayLike = (),
    reference_hues_deg: ArrayLike = (),
    heading: float | None = None,
    title: str = "fingerloc panorama report",
    notes: Sequence[str] = (),
) -> Path:
    """Write a panorama report: the image with its features, and the heading estimate against a reference view.

    Parameters
    ----------
    out_dir : str or Path
        The report folder (created; its report files are overwritten).
    image : array_like, shape (H, W, 3)
        The panorama, RGB ``uint8`` or float in ``[0, 1]``; columns are bearings.
    edges : array_like, shape (n_e,)
        Vertical-edge bearings, radians (robot frame).
    patches : array_like, shape (n_p,)
        Colour-patch bearings, radians.
    patch_hues_deg : array_like, shape (n_p,)
        Their hues, degrees.
    bearing_offset : float, default 0
        Bearing (radians) of the left edge of column 0 (as :class:`fingerloc.sensors.Panorama`).
    clockwise : bool, default True
        Bearing decreases as the column grows (as :class:`fingerloc.sensors.Panorama`).
    reference_image : array_like, shape (H', W', 3), optional
        The reference view (same column convention).
    reference_edges, reference_patches, reference_hues_deg : array_like
        Its features.
    heading : float, optional
        The heading estimate, radians: added to the reference's bearings it gives the query's
        (as ``heading_deg`` of :func:`fingerloc.align.cyclic_alignment`).
    title : str
    notes : sequence of str

    Returns
    -------
    Path
        ``out_dir / "index.html"``.
    """
    from . import figures

    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 2 or img.shape[1] < 8:
        raise InvalidParameterError(f"image: expected an (H, W, 3) RGB array, got shape {img.shape}")
    if heading is not None and not math.isfinite(heading):
        raise InvalidParameterError(f"heading: must be finite radians, got {heading!r}")
    sign = -1.0 if clockwise else 1.0

    def frac(b: ArrayLike) -> FArray:
        return np.asarray(
            np.mod(sign * (np.asarray(b, dtype=np.float64).reshape(-1) - bearing_offset), 2 * math.pi) / (2 * math.pi)
        )

    e = np.asarray(edges, dtype=np.float64).reshape(-1)
    pa = np.asarray(patches, dtype=np.float64).reshape(-1)
    hu = np.asarray(patch_hues_deg, dtype=np.float64).reshape(-1)
    if hu.size != pa.size:
        raise InvalidParameterError(f"patch_hues_deg: one hue per patch is needed, got {hu.size} for {pa.size}")
    ticks_deg = np.arange(-180, 180, 45)
    tick_f = frac(np.deg2rad(ticks_deg))
    order = np.argsort(tick_f)
    ref = None
    re_ = np.asarray(reference_edges, dtype=np.float64).reshape(-1)
    rp = np.asarray(reference_patches, dtype=np.float64).reshape(-1)
    rh = np.asarray(reference_hues_deg, dtype=np.float64).reshape(-1)
    if rh.size != rp.size:
        raise InvalidParameterError(f"reference_hues_deg: one hue per patch is needed, got {rh.size} for {rp.size}")
    turn = 0.0 if heading is None else float(heading)
    if reference_image is not None:
        r_img = np.asarray(reference_image)
        if r_img.ndim != 3 or r_img.shape[2] != 3:
            raise InvalidParameterError(f"reference_image: expected an (H, W, 3) RGB array, got shape {r_img.shape}")
        shift = round(sign * turn / (2 * math.pi) * r_img.shape[1])
        ref = (np.roll(r_img, shift, axis=1), frac(re_ + turn), frac(rp + turn), rh)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    page = Page(title)
    facts = [*notes, f"{img.shape[1]} x {img.shape[0]} pixels; {e.size} vertical edges, {pa.size} colour patches."]
    if heading is not None:
        facts.append(f"Heading estimate against the reference view: {math.degrees(turn) % 360:.1f} deg "
                     "(added to the reference's bearings, it gives the query's).")  # fmt: skip
    page.items(facts)
    figures.draw_panorama(
        out / "panorama.png",
        img,
        frac(e),
        frac(pa),
        hu,
        reference=ref,
        tick_columns=tick_f[order],
        tick_labels=[str(int(ticks_deg[i])) for i in order],
        title="the panorama with its vertical edges (cyan) and colour patches (triangles in their hue)",
    )
    page.figure(
        "panorama.png",
        f"the panorama with {e.size} vertical edges drawn as cyan lines and {pa.size} colour patches as triangles"
        + ("; below it the reference view turned by the heading estimate" if ref is not None else ""),
        "Vertical edges (cyan lines) and colour patches (triangles in their hue) at the bearings the extractor found."
        + (
            " Below: the reference view turned by the heading estimate; when the estimate is right, the two line up."
            if ref is not None
            else ""
        ),
    )
    if re_.size or rp.size:
        q = FeatureView({"VE": e, "CP": pa}, hu)
        r = FeatureView({"VE": re_, "CP": rp}, rh)
        figures.draw_heading(out / "heading.png", q, r, None if heading is None else turn,
                             title="feature bearings: query, reference, and reference turned by the heading estimate")  # fmt: skip
        page.figure(
            "heading.png",
            "feature bearings of the query, of the reference, and of the reference turned by the heading estimate",
            "Each row is a strip of bearings; the last row should match the first when the heading estimate is right.",
        )
    _write_json(
        out,
        {"edges_deg": np.rad2deg(e).tolist(), "patches_deg": np.rad2deg(pa).tolist(), "patch_hues_deg": hu.tolist(),
         "heading_deg": None if heading is None else math.degrees(turn) % 360},
    )  # fmt: skip
    return page.write(out)
