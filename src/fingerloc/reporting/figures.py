"""The report figures drawn with matplotlib (Agg); imported only when a report is written.

Every function draws one figure from plain arrays, writes a PNG and returns
its path. Positions in metres, bearings in radians (degrees on the axes).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import EllipseCollection, LineCollection
from numpy.typing import NDArray

from .._types import FArray
from .views import FEATURE_STYLE, FeatureView

_DPI = 100


def _save(fig: Any, path: str | Path) -> Path:
    p = Path(path)
    fig.savefig(p, dpi=_DPI, bbox_inches="tight")
    plt.close(fig)
    return p


def _thin(points: FArray, max_points: int) -> FArray:
    if points.shape[0] > max_points:
        return points[:: math.ceil(points.shape[0] / max_points)]
    return points


def _circles(ax: Any, centres: FArray, radius: FArray, **kw: Any) -> None:
    d = 2.0 * np.broadcast_to(radius, (centres.shape[0],))
    ax.add_collection(
        EllipseCollection(d, d, np.zeros_like(d), units="xy", offsets=centres, offset_transform=ax.transData, **kw)
    )


def draw_map(
    path: str | Path,
    *,
    centres: FArray,
    radius: FArray,
    edges: NDArray[np.int64],
    trajectory: FArray | None,
    scan_points: FArray | None,
    names: Sequence[str],
    queries: FArray | None = None,
    query_right: NDArray[np.bool_] | None = None,
    max_points: int = 80_000,
    title: str = "",
) -> Path:
    """The places over the run: scan end points, trajectory, place circles, centres and graph edges."""
    fig, ax = plt.subplots(figsize=(9.0, 8.0))
    if scan_points is not None and scan_points.size:
        pts = _thin(scan_points, max_points)
        ax.scatter(pts[:, 0], pts[:, 1], s=0.3, c="0.6", linewidths=0, rasterized=True, label="scan end points")
    if trajectory is not None and trajectory.size:
        ax.plot(trajectory[:, 0], trajectory[:, 1], lw=0.7, c="tab:blue", alpha=0.7, label="trajectory")
    if edges.size:
        segs = np.stack([centres[edges[:, 0]], centres[edges[:, 1]]], axis=1)
        ax.add_collection(
            LineCollection(list(segs), colors="tab:orange", linewidths=0.9, alpha=0.8, label="graph edges")
        )
    if centres.size:
        _circles(ax, centres, radius, facecolors="none", edgecolors="k", linewidths=0.5, alpha=0.6)
        size = 12 if centres.shape[0] <= 100 else 3
        ax.scatter(centres[:, 0], centres[:, 1], s=size, c="k", zorder=4, label=f"places ({centres.shape[0]})")
        if len(names) <= 30:
            for (x, y), n in zip(centres, names, strict=True):
                ax.annotate(n, (x, y), xytext=(3, 3), textcoords="offset points", fontsize=7)
    if queries is not None and query_right is not None and queries.size:
        r = np.asarray(query_right, dtype=bool)
        for sel, colour, word in ((r, "tab:green", "right"), (~r, "tab:red", "wrong")):
            qs = queries[sel]
            ax.scatter(qs[:, 0], qs[:, 1], s=8, c=colour, zorder=5, label=f"query {word} ({int(sel.sum())})")
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False, markerscale=3)
    ax.set_title(title)
    return _save(fig, path)


def draw_views_histogram(path: str | Path, views_per_place: NDArray[np.int64]) -> Path:
    """How many views each place has, as a histogram."""
    fig, ax = plt.subplots(figsize=(6.0, 3.2))
    v = np.asarray(views_per_place)
    top = int(v.max()) if v.size else 1
    ax.hist(v, bins=list(np.arange(0.5, top + 1.5, max(1, math.ceil(top / 40)))), color="tab:blue")
    ax.set_xlabel("views per place")
    ax.set_ylabel("places")
    ax.set_title(f"{v.size} places, {int(v.sum())} views")
    ax.grid(True, axis="y", lw=0.3, alpha=0.5)
    return _save(fig, path)


def draw_per_place(path: str | Path, names: Sequence[str], top1: FArray, counts: NDArray[np.int64]) -> Path:
    """Per-place top-1 (labelled queries), sorted from worst to best."""
    order = np.argsort(top1, kind="stable")
    fig, ax = plt.subplots(figsize=(9.0, 3.8))
    x = np.arange(order.size)
    if order.size <= 40:
        ax.bar(x, top1[order], color="tab:blue")
        ax.set_xticks(x)
        ax.set_xticklabels([names[i] for i in order], rotation=60, ha="right", fontsize=7)
        ax.set_xlabel("place (worst first)")
    else:
        ax.fill_between(x, top1[order], step="mid", color="tab:blue", alpha=0.7)
        ax.set_xlabel(f"places sorted by top-1 ({order.size}; names in the table below)")
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("top-1 of its queries")
    ax.set_title(f"per-place top-1 ({int(counts.sum())} labelled queries)")
    ax.grid(True, axis="y", lw=0.3, alpha=0.5)
    return _save(fig, path)


def draw_rank_histogram(path: str | Path, ranks: NDArray[np.int64], n_places: int) -> Path:
    """Rank of the true place among the answers, as a histogram (ranks above 10 pooled)."""
    fig, ax = plt.subplots(figsize=(6.0, 3.2))
    r = np.minimum(np.asarray(ranks), 11)
    counts = np.bincount(r, minlength=12)[1:]
    labels = [str(i) for i in range(1, 11)] + ["> 10"]
    ax.bar(range(11), counts, color=["tab:green"] + ["tab:gray"] * 10)
    ax.set_xticks(range(11))
    ax.set_xticklabels(labels)
    ax.set_xlabel(f"rank of the true place (of {n_places})")
    ax.set_ylabel("queries")
    ax.grid(True, axis="y", lw=0.3, alpha=0.5)
    return _save(fig, path)


def draw_track(
    path_traj: str | Path | None,
    path_series: str | Path,
    *,
    steps: NDArray[np.int64],
    p_true_filtered: FArray,
    p_true_single: FArray,
    entropy_bits: FArray,
    max_entropy_bits: float,
    right: NDArray[np.int8],
    observed: NDArray[np.bool_],
    kidnaps: Sequence[int],
    recoveries: Sequence[int],
    poses: FArray | None,
    centres: FArray | None,
) -> None:
    """The track figures: the trajectory coloured by right/wrong, and P(true place) and entropy over time."""
    kid_kw = {"color": "tab:red", "ls": "--", "lw": 1.0}
    rec_kw = {"color": "tab:green", "ls": ":", "lw": 1.2}
    if path_traj is not None and poses is not None:
        fig, ax = plt.subplots(figsize=(8.0, 7.0))
        if centres is not None and centres.size:
            ax.scatter(centres[:, 0], centres[:, 1], s=14, marker="+", c="k", label="places", zorder=2)
        line = poses[:, :2].astype(np.float64)
        if len(kidnaps):  # no line across a jump
            line = np.insert(line, np.asarray(sorted(kidnaps), dtype=np.int64), np.nan, axis=0)
        ax.plot(line[:, 0], line[:, 1], lw=0.5, c="0.6", zorder=1)
        big = 16 if poses.shape[0] <= 2000 else 6
        for val, colour, label, size in (
            (-1, "0.75", "no label or not observed", big / 3),
            (1, "tab:green", "right", big),
            (0, "tab:red", "wrong", big),
        ):
            sel = right == val
            if np.any(sel):
                ax.scatter(
                    poses[sel, 0], poses[sel, 1], s=size, c=colour, zorder=3, label=f"{label} ({int(sel.sum())})"
                )
        for i, k in enumerate(kidnaps):
            ax.plot(*poses[k, :2], marker="X", ms=12, c="tab:red", mec="k", ls="none", zorder=5,
                    label="kidnapped here" if i == 0 else None)  # fmt: skip
        for i, k in enumerate(recoveries):
            ax.plot(*poses[k, :2], marker="o", ms=10, mfc="none", mec="tab:green", mew=2, ls="none", zorder=5,
                    label="recovered here" if i == 0 else None)  # fmt: skip
        ax.plot(*poses[0, :2], marker="s", ms=8, c="k", ls="none", label="start", zorder=5)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False, markerscale=1.5)
        ax.set_title("trajectory: filtered answer right / wrong")
        _save(fig, path_traj)

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10.0, 6.0), sharex=True)
    a1.plot(steps, p_true_filtered, lw=1.0, c="tab:blue", label="filtered")
    obs = observed & np.isfinite(p_true_single)
    a1.plot(steps[obs], p_true_single[obs], ".", ms=2.5, c="tab:orange", label="single-shot (observed steps)")
    a1.set_ylim(-0.02, 1.02)
    a1.set_ylabel("P(true place)")
    a2.plot(steps, entropy_bits, lw=1.0, c="tab:purple", label="filtered posterior")
    a2.axhline(max_entropy_bits, color="0.5", lw=0.8, ls=":", label=f"uniform ({max_entropy_bits:.1f} bits)")
    a2.set_ylabel("entropy (bits)")
    a2.set_xlabel("step")
    for ax in (a1, a2):
        for i, k in enumerate(kidnaps):
            ax.axvline(k, **kid_kw, label="kidnapping" if i == 0 else None)
        for i, k in enumerate(recoveries):
            ax.axvline(k, **rec_kw, label="recovery" if i == 0 else None)
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    a1.set_title("the true place's probability and the posterior's entropy along the run")
    _save(fig, path_series)


def draw_panorama(
    path: str | Path,
    image: NDArray[Any],
    columns: FArray,
    patch_columns: FArray,
    patch_hues: FArray,
    *,
    reference: tuple[NDArray[Any], FArray, FArray, FArray] | None,
    tick_columns: FArray,
    tick_labels: Sequence[str],
    title: str,
) -> Path:
    """A panorama with its features (and the reference view turned by the heading estimate below it).

    ``columns``, ``patch_columns`` and ``tick_columns`` are fractions of the image's width, in ``[0, 1)``.
    """
    from .views import _hue_rgb

    imgs = [(image, columns, patch_columns, patch_hues, title)]
    if reference is not None:
        imgs.append((*reference, "reference view, turned by the heading estimate"))
    h, w = image.shape[:2]
    fig, axes = plt.subplots(len(imgs), 1, figsize=(12.0, len(imgs) * (12.0 * h / w + 0.9)), squeeze=False)
    for ax, (img, cols, pcols, hues, ttl) in zip(axes[:, 0], imgs, strict=True):
        a = np.asarray(img)
        if a.dtype != np.uint8:
            a = np.clip(a.astype(np.float32), 0.0, 1.0)
        ax.imshow(a, aspect="auto", interpolation="nearest", extent=(0, a.shape[1], a.shape[0], 0))
        scale = a.shape[1]
        for i, x in enumerate(np.asarray(cols)):
            ax.axvline(x * scale, color="cyan", lw=1.0, label=f"vertical edges ({len(cols)})" if i == 0 else None)
        for i, (x, hue) in enumerate(zip(np.asarray(pcols), np.asarray(hues), strict=True)):
            rgb = tuple(v / 255 for v in _hue_rgb(float(hue)))
            ax.plot(x * scale, 0.12 * a.shape[0], marker="v", ms=11, color=rgb, mec="k", ls="none",
                    label=f"colour patches ({len(pcols)})" if i == 0 else None)  # fmt: skip
        ax.set_xticks(np.asarray(tick_columns) * a.shape[1])
        ax.set_xticklabels(tick_labels)
        ax.set_yticks([])
        ax.set_xlim(0, a.shape[1])
        ax.set_title(ttl, fontsize=10)
        if len(cols) or len(pcols):
            ax.legend(loc="upper right", fontsize=8, framealpha=0.7)
    axes[-1, 0].set_xlabel("bearing, robot frame (deg)")
    fig.tight_layout()
    return _save(fig, path)


def draw_heading(
    path: str | Path, query: FeatureView, reference: FeatureView, heading: float | None, *, title: str
) -> Path:
    """The query's feature bearings against the reference's, before and after turning by the heading estimate."""
    rows = [("query", query, 0.0), ("reference", reference, 0.0)]
    if heading is not None:
        rows.append((f"reference + {math.degrees(heading) % 360:.1f} deg", reference, heading))
    fig, ax = plt.subplots(figsize=(10.0, 0.8 + 0.6 * len(rows)))
    for y, (_, view, turn) in enumerate(reversed(rows)):
        for kind, (_, colour, _) in FEATURE_STYLE.items():
            arr = view.bearings.get(kind)
            if arr is None or not arr.size:
                continue
            deg = np.rad2deg(np.angle(np.exp(1j * (arr + turn))))
            if kind == "CP" and view.hues_deg.size == arr.size:
                from .views import _hue_rgb

                cs = [tuple(v / 255 for v in _hue_rgb(float(hh))) for hh in view.hues_deg]
            else:
                cs = [tuple(v / 255 for v in colour)] * arr.size
            ax.scatter(deg, np.full(arr.size, y), marker="|", s=300, c=cs, linewidths=2)
    ax.set_yticks(range(len(rows)))
    ax.set_yticklabels([r[0] for r in reversed(rows)])
    ax.set_xlim(-180, 180)
    ax.set_xticks(np.arange(-180, 181, 45))
    ax.set_ylim(-0.6, len(rows) - 0.4)
    ax.set_xlabel("bearing (deg); blue: vertical edges, hue: colour patches, red: corners, purple: extremities")
    ax.grid(True, axis="x", lw=0.3, alpha=0.5)
    ax.set_title(title, fontsize=10)
    return _save(fig, path)
