"""Figures (PNG) of the pipeline: the only module that imports matplotlib (Agg backend).

Every function draws one figure, writes it to ``path`` and returns the path.
Bearings are radians inside and degrees on the axes; the robot frame has
bearing 0 straight ahead (x axis) and bearings growing counter-clockwise.

- :func:`plot_office_map`: a simulated office from above with measurement poses.
- :func:`plot_scan_features`: a laser scan with its fitted lines, corners,
  extremities and beacons.
- :func:`plot_panorama_features`: a panorama with its vertical edges and colour patches.
- :func:`plot_fingerprint`: a fingerprint's letters drawn around the robot.
- :func:`plot_mixture`: a place's mixture density on the circle with the
  training bearings it was fit on.
- :func:`plot_posterior`: posterior bars over the places.
- :func:`plot_confusion`: a confusion matrix.
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
from matplotlib.patches import FancyArrow, Polygon
from numpy.typing import ArrayLike

from ._types import FArray

__all__ = [
    "LETTER_COLOURS",
    "plot_confusion",
    "plot_fingerprint",
    "plot_image",
    "plot_mixture",
    "plot_office_map",
    "plot_panorama_features",
    "plot_posterior",
    "plot_scan_features",
]


#: Colours of the fingerprint letters (colour patches get their own hue).
LETTER_COLOURS: dict[str, str] = {"v": "tab:blue", "c": "tab:red", "b": "tab:orange", "f": "tab:purple", "n": "0.6"}
_PART_STYLE: dict[str, tuple[str, float]] = {
    "wall": ("black", 2.2),
    "door_frame": ("tab:brown", 2.0),
    "lintel": ("tab:brown", 1.0),
    "furniture": ("peru", 1.6),
    "pillar": ("dimgray", 2.2),
    "corridor": ("0.7", 1.2),
}
_DPI = 110


def _save(fig: Any, path: str | Path) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=_DPI, bbox_inches="tight")
    plt.close(fig)
    return p


def _hue_colour(hue_deg: float) -> tuple[float, float, float]:
    import colorsys

    r, g, b = colorsys.hsv_to_rgb((hue_deg % 360.0) / 360.0, 0.85, 0.9)
    return (r, g, b)


def _letter_colour(letter: str) -> Any:
    if letter in LETTER_COLOURS:
        return LETTER_COLOURS[letter]
    if "A" <= letter <= "P":
        return _hue_colour((ord(letter) - ord("A") + 0.5) * 22.5)
    return "black"


def _deg(x: ArrayLike) -> FArray:
    """Radians to degrees in (-180, 180]."""
    d = np.rad2deg(np.asarray(x, dtype=np.float64))
    return np.asarray(-(np.mod(-d + 180.0, 360.0) - 180.0))


# ----------------------------------------------------------------------------- map


def plot_office_map(
    world: Any,
    path: str | Path,
    *,
    train_poses: Sequence[tuple[float, float, float]] = (),
    test_poses: Sequence[tuple[float, float, float]] = (),
    other_poses: Sequence[tuple[float, float, float]] = (),
    title: str | None = None,
) -> Path:
    """An office from above (:class:`fingerloc.sim.World`) with measurement poses as arrows.

    Parameters
    ----------
    world : fingerloc.sim.World
    path : str or Path
        Output PNG.
    train_poses, test_poses, other_poses : sequence of (x, y, theta)
        Poses in metres and radians (world frame), drawn blue, red and green.
    title : str, optional
    """
    from .sim import PARTS

    fig, ax = plt.subplots(figsize=(6.4, 5.2))
    if world.room.size:
        ax.add_patch(Polygon(world.room, closed=True, facecolor="0.96", edgecolor="none", zorder=0))
    seen_parts: set[str] = set()
    for (x0, y0, x1, y1), part_i, mat_i, dm in zip(
        world.segments, world.part, world.material, world.decal_material, strict=True
    ):
        part = PARTS[int(part_i)]
        colour, lw = _PART_STYLE.get(part, ("black", 1.5))
        mat = world.materials[int(mat_i)]
        label = None
        if getattr(mat, "beacon", False):
            colour, lw, label = "gold", 4.0, "beacon"
        elif part not in seen_parts:
            label = part.replace("_", " ")
            seen_parts.add(part)
        ax.plot([x0, x1], [y0, y1], color=colour, lw=lw, solid_capstyle="butt", label=label, zorder=2)
        decal = world.materials[int(dm)] if int(dm) >= 0 else None
        if decal is not None and decal.beacon:
            ax.plot([x0, x1], [y0, y1], color="gold", lw=6.0, solid_capstyle="butt", label="beacon", zorder=3)
        elif decal is not None and decal.patch:  # a coloured poster on this segment, drawn on both faces
            nx, ny = y1 - y0, -(x1 - x0)
            off = 0.06 / (math.hypot(nx, ny) or 1.0)
            for sgn in (1.0, -1.0):
                xs = [x0 + sgn * nx * off, x1 + sgn * nx * off]
                ys = [y0 + sgn * ny * off, y1 + sgn * ny * off]
                ax.plot(xs, ys, color=decal.rgb, lw=3.0, zorder=3, label="colour patch" if sgn > 0 else None)
    ax.plot(*world.anchor, marker="x", color="k", ms=8, mew=2, ls="none", label="measurement point", zorder=5)
    for poses, colour, label in (
        (train_poses, "tab:blue", "training"),
        (test_poses, "tab:red", "test"),
        (other_poses, "tab:green", "test, random heading"),
    ):
        for i, (x, y, th) in enumerate(poses):
            ax.add_patch(
                FancyArrow(
                    x,
                    y,
                    0.25 * math.cos(th),
                    0.25 * math.sin(th),
                    width=0.03,
                    head_width=0.1,
                    head_length=0.08,
                    color=colour,
                    zorder=6,
                    label=label if i == 0 else None,
                )
            )
    # one legend entry per beacon/part only
    handles, labels = ax.get_legend_handles_labels()
    uniq = dict(zip(labels, handles, strict=False))
    ax.legend(uniq.values(), uniq.keys(), loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or f"{world.name}: map and measurement poses")
    ax.grid(True, lw=0.3, alpha=0.5)
    return _save(fig, path)


# ----------------------------------------------------------------------------- laser


def plot_scan_features(
    scan: Any,
    features: Any,
    path: str | Path,
    *,
    title: str | None = None,
) -> Path:
    """A 360 deg scan in the robot frame with the features extracted from it.

    Parameters
    ----------
    scan : fingerloc.sensors.Scan
    features : fingerloc.features.LaserFeatures
        ``corners``, ``extremities``, ``beacons`` (radians) and ``segments`` (metres).
    path : str or Path
    title : str, optional
    """
    fig, ax = plt.subplots(figsize=(6.4, 6.0))
    pts = scan.points()
    ax.plot(pts[:, 0], pts[:, 1], ".", ms=2.0, color="0.55", label="laser returns", zorder=1)
    for i, ((x0, y0), (x1, y1)) in enumerate(features.segments):
        ax.plot([x0, x1], [y0, y1], "-", color="tab:green", lw=1.6, label="fitted lines" if i == 0 else None, zorder=2)
    ok = scan.valid
    b_ok, r_ok = scan.bearings[ok] + scan.sensor_offset[2], scan.ranges[ok]

    def range_at(bearing: float) -> float:
        d = np.abs(np.angle(np.exp(1j * (b_ok - bearing))))
        return float(r_ok[int(np.argmin(d))]) if d.size else 1.0

    reach = float(np.percentile(r_ok, 95)) if r_ok.size else 1.0
    for name, arr, colour, marker in (
        ("corners c", features.corners, "tab:red", "s"),
        ("extremities Ex", features.extremities, "tab:purple", "^"),
        ("beacons B", features.beacons, "gold", "*"),
    ):
        for i, a in enumerate(np.asarray(arr)):
            r = range_at(float(a))
            x, y = r * math.cos(a), r * math.sin(a)
            ax.plot([0, x], [0, y], color=colour, lw=0.6, alpha=0.6, zorder=3)
            ax.plot(
                x,
                y,
                marker=marker,
                ms=11 if marker == "*" else 7,
                color=colour,
                mec="k",
                mew=0.5,
                ls="none",
                label=f"{name} ({len(arr)})" if i == 0 else None,
                zorder=4,
            )
    ax.add_patch(FancyArrow(0, 0, 0.35, 0, width=0.04, head_width=0.14, head_length=0.1, color="k", zorder=5))
    ax.set_xlim(-reach * 1.1, reach * 1.1)
    ax.set_ylim(-reach * 1.1, reach * 1.1)
    ax.set_aspect("equal")
    ax.set_xlabel("x, robot frame (m)")
    ax.set_ylabel("y, robot frame (m)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_title(title or "laser scan and extracted features")
    ax.grid(True, lw=0.3, alpha=0.5)
    return _save(fig, path)


# ----------------------------------------------------------------------------- camera


def plot_panorama_features(
    pano: Any,
    features: Any,
    path: str | Path,
    *,
    title: str | None = None,
) -> Path:
    """A panorama (columns = bearing) with its vertical edges and colour patches.

    Parameters
    ----------
    pano : fingerloc.sensors.Panorama
    features : fingerloc.features.VisionFeatures
        ``edges``, ``patches`` (radians) and ``patch_hues`` (degrees).
    path : str or Path
    title : str, optional
    """
    from .fingerprint import hue_letter

    img = np.asarray(pano.image, dtype=np.float32)
    if img.dtype != np.uint8 and img.max() > 1.0:
        img = img / 255.0
    h, w = img.shape[:2]
    fig, ax = plt.subplots(figsize=(12.0, 12.0 * h / w + 1.2))
    ax.imshow(np.clip(img, 0, 1), aspect="equal", interpolation="nearest")
    for i, a in enumerate(np.asarray(features.edges)):
        x = float(pano.bearing_column(a)) - 0.5
        ax.axvline(
            x, color="cyan", lw=1.0, alpha=0.9, label=f"vertical edges VE ({len(features.edges)})" if i == 0 else None
        )
    for i, (a, hue) in enumerate(zip(np.asarray(features.patches), np.asarray(features.patch_hues), strict=True)):
        x = float(pano.bearing_column(a)) - 0.5
        ax.plot(
            x,
            0.12 * h,
            marker="v",
            ms=12,
            color=_hue_colour(float(hue)),
            mec="k",
            ls="none",
            label=f"colour patches CP ({len(features.patches)})" if i == 0 else None,
        )
        ax.annotate(
            hue_letter(float(hue)),
            (x, 0.12 * h),
            xytext=(0, 9),
            textcoords="offset points",
            ha="center",
            fontsize=10,
            fontweight="bold",
            color="white",
            bbox={"boxstyle": "round,pad=0.15", "fc": "black", "alpha": 0.6, "lw": 0},
        )
    ticks = np.arange(-180, 181, 45)
    cols = [float(pano.bearing_column(np.deg2rad(t))) - 0.5 for t in ticks]
    order = np.argsort(cols)
    ax.set_xticks(np.asarray(cols)[order])
    ax.set_xticklabels([f"{ticks[i]:d}" for i in order])
    ax.set_yticks([])
    ax.set_xlabel("bearing, robot frame (deg)")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.25), ncol=2, fontsize=9, frameon=False)
    ax.set_title(title or "panorama (unwarped omnidirectional image) with extracted features")
    return _save(fig, path)


def plot_image(image: ArrayLike, path: str | Path, *, title: str | None = None) -> Path:
    """A raw camera image (RGB, ``uint8`` or float in ``[0, 1]``) as it is.

    Parameters
    ----------
    image : array_like, shape (H, W, 3)
    path : str or Path
    title : str, optional
    """
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(img.astype(np.float32), 0.0, 1.0)
    h, w = img.shape[:2]
    fig, ax = plt.subplots(figsize=(6.4, 6.4 * h / w))
    ax.imshow(img, interpolation="nearest")
    ax.axis("off")
    if title:
        ax.set_title(title)
    return _save(fig, path)


# ----------------------------------------------------------------------------- fingerprint


def plot_fingerprint(
    fingerprint: Any,
    path: str | Path,
    *,
    title: str | None = None,
) -> Path:
    """A fingerprint drawn around the robot: each letter at its bearing.

    Parameters
    ----------
    fingerprint : fingerloc.Fingerprint
        ``letters`` and ``bearings`` (radians, robot frame).
    path : str or Path
    title : str, optional
    """
    letters, bearings = fingerprint.letters, np.asarray(fingerprint.bearings)
    fig, ax = plt.subplots(figsize=(6.4, 6.4))
    circle = np.linspace(0, 2 * np.pi, 361)
    ax.plot(np.cos(circle), np.sin(circle), color="0.8", lw=1.0)
    for a, ch in zip(bearings, letters, strict=True):
        col = _letter_colour(ch)
        r_in, r_out = (0.9, 1.0) if ch == "n" else (0.75, 1.0)
        ax.plot([r_in * math.cos(a), r_out * math.cos(a)], [r_in * math.sin(a), r_out * math.sin(a)], color=col, lw=1.5)
        ax.text(
            1.12 * math.cos(a),
            1.12 * math.sin(a),
            ch,
            ha="center",
            va="center",
            fontsize=13 if ch != "n" else 10,
            fontweight="bold" if ch != "n" else "normal",
            color=col,
            family="monospace",
        )
    # the robot: a triangle pointing along bearing 0
    ax.add_patch(Polygon([(0.22, 0), (-0.12, 0.12), (-0.12, -0.12)], closed=True, color="k"))
    ax.text(0, -0.3, "robot", ha="center", fontsize=9)
    legend = [("v", "vertical edge"), ("c", "corner"), ("f", "corner + edge"), ("b", "beacon"), ("n", "20 deg empty")]
    for i, (ch, what) in enumerate(legend):
        ax.text(-1.45, -1.25 - 0.09 * i, f"{ch}: {what}", color=_letter_colour(ch), fontsize=8, family="monospace")
    ax.text(0.55, -1.25, "A..P: colour patch\n(hue bin)", fontsize=8, color="tab:green", family="monospace")
    ax.set_xlim(-1.5, 1.5)
    ax.set_ylim(-1.7, 1.45)
    ax.set_aspect("equal")
    ax.axis("off")
    text = letters if len(letters) <= 60 else letters[:57] + "..."
    ax.set_title(title or "fingerprint around the robot", fontsize=11)
    ax.text(0, 1.33, text, ha="center", fontsize=9, family="monospace")
    return _save(fig, path)


# ----------------------------------------------------------------------------- mixture


def plot_mixture(
    weights: ArrayLike,
    means: ArrayLike,
    sigmas: ArrayLike,
    path: str | Path,
    *,
    samples: ArrayLike | None = None,
    title: str | None = None,
) -> Path:
    """A mixture of Gaussians on the circle (docs/METHOD.md §3) with the bearings it was fit on.

    Parameters
    ----------
    weights, means, sigmas : array_like, shape (K,)
        The mixture (means and sigmas in radians).
    path : str or Path
    samples : array_like, shape (n,), optional
        Training bearings (radians), drawn as a rug.
    title : str, optional
    """
    from .mog import mixture_log_density

    w, m, s = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (weights, means, sigmas))
    keep = w > 0
    w, m, s = w[keep], m[keep], s[keep]
    grid = np.linspace(-np.pi, np.pi, 1441)[:-1]
    dens = np.exp(np.asarray(mixture_log_density(grid, w[None, :], m[None, :], s[None, :])).reshape(-1))
    fig = plt.figure(figsize=(11.0, 4.4))
    ax = fig.add_subplot(1, 2, 1)
    gd = np.rad2deg(grid)
    ax.plot(gd, dens, color="tab:blue", lw=1.8, label="mixture density")
    for k in range(w.size):
        comp = np.exp(np.asarray(mixture_log_density(grid, np.ones((1, 1)), m[None, k : k + 1], s[None, k : k + 1])))
        ax.plot(
            gd,
            w[k] * comp.reshape(-1),
            color="tab:blue",
            lw=0.8,
            ls="--",
            alpha=0.7,
            label="components" if k == 0 else None,
        )
    ax.axhline(1 / (2 * np.pi), color="0.6", lw=0.8, ls=":", label="uniform 1/(2 pi)")
    top = float(dens.max()) if dens.size else 1.0
    if samples is not None:
        x = _deg(np.asarray(samples, dtype=np.float64).reshape(-1))
        ax.plot(x, np.full(x.size, -0.04 * top), "|", color="k", ms=10, label=f"training bearings ({x.size})")
    ax.set_xlim(-180, 180)
    ax.set_xticks(np.arange(-180, 181, 60))
    ax.set_ylim(-0.08 * top, 1.1 * top)
    ax.set_xlabel("bearing (deg)")
    ax.set_ylabel("density (1/rad)")
    ax.legend(fontsize=8, frameon=False)
    pax = fig.add_subplot(1, 2, 2, projection="polar")
    pax.plot(np.append(grid, grid[0]), np.append(dens, dens[0]), color="tab:blue", lw=1.8)
    if samples is not None:
        sx = np.asarray(samples, dtype=np.float64).reshape(-1)
        pax.plot(sx, np.full(sx.size, 1.05 * top), "o", ms=3, color="k")
    pax.set_ylim(0, 1.12 * top)
    pax.set_yticklabels([])
    pax.set_title("on the circle", fontsize=9)
    fig.suptitle(title or "mixture of Gaussians on the circle")
    fig.tight_layout()
    return _save(fig, path)


# ----------------------------------------------------------------------------- results


def plot_posterior(
    classes: Sequence[str],
    proba: ArrayLike,
    path: str | Path,
    *,
    truth: str | None = None,
    title: str | None = None,
) -> Path:
    """Posterior over the places as bars; the true place hatched, the answer outlined.

    Parameters
    ----------
    classes : sequence of str, length P
    proba : array_like, shape (P,)
        Posterior probabilities (sum 1).
    path : str or Path
    truth : str, optional
        The true place.
    title : str, optional
    """
    p = np.asarray(proba, dtype=np.float64).reshape(-1)
    names = [str(c) for c in classes]
    fig, ax = plt.subplots(figsize=(7.5, 3.8))
    colours = ["tab:green" if c == truth else "tab:gray" for c in names]
    bars = ax.bar(range(len(names)), p, color=colours)
    best = int(np.argmax(p)) if p.size else 0
    if p.size:
        bars[best].set_edgecolor("k")
        bars[best].set_linewidth(2.0)
    ax.set_xticks(range(len(names)))
    ax.set_xticklabels(names, rotation=40, ha="right", fontsize=9)
    ax.set_ylabel("P(Loc | VE, Ex, Fp)")
    ax.set_ylim(0, 1.05)
    for i, v in enumerate(p):
        if v >= 0.01:
            ax.text(i, v + 0.02, f"{v:.2f}", ha="center", fontsize=8)
    note = f"true place {truth} (green); answer {names[best]} (outlined)" if truth is not None and names else ""
    ax.set_title(title or f"posterior over the places\n{note}", fontsize=10)
    ax.grid(True, axis="y", lw=0.3, alpha=0.5)
    return _save(fig, path)


def plot_confusion(
    matrix: ArrayLike,
    labels: Sequence[str],
    path: str | Path,
    *,
    title: str | None = None,
) -> Path:
    """A confusion matrix: rows true place, columns answer, counts written in the cells.

    Parameters
    ----------
    matrix : array_like of int, shape (P, P)
    labels : sequence of str, length P
    path : str or Path
    title : str, optional
    """
    c = np.asarray(matrix, dtype=np.float64)
    fig, ax = plt.subplots(figsize=(6.4, 5.6))
    im = ax.imshow(c, cmap="Blues", vmin=0, vmax=max(float(c.max()), 1.0))
    for i in range(c.shape[0]):
        for j in range(c.shape[1]):
            if c[i, j]:
                ax.text(
                    j,
                    i,
                    f"{int(c[i, j])}",
                    ha="center",
                    va="center",
                    fontsize=9,
                    color="white" if c[i, j] > 0.6 * c.max() else "black",
                )
    ax.set_xticks(range(len(labels)))
    ax.set_xticklabels(labels, rotation=40, ha="right", fontsize=8)
    ax.set_yticks(range(len(labels)))
    ax.set_yticklabels(labels, fontsize=8)
    ax.set_xlabel("answer")
    ax.set_ylabel("true place")
    right = float(np.trace(c) / c.sum()) if c.sum() else 0.0
    ax.set_title(title or f"confusion matrix (right {100 * right:.0f}%)")
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04, label="test measurements")
    return _save(fig, path)
