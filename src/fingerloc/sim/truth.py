"""Ground-truth features of a simulated pose, for evaluating extractors (never an input to them).

Laser features come from a dense noise-free scan (``resolution_deg`` apart) in
the laser plane:

- a *depth jump* lies between two neighbouring beams when one misses (or is
  beyond ``max_range``) or their hit points are more than ``jump_tol`` apart on
  segments that do not share an end point;
- *extremity* (``Ex``): the end of the nearer surface at a depth jump, when the
  continuous chain of hits it ends is at least ``min_line_len`` long; its
  bearing is that of the segment's end point;
- *corner* (``c``): two different wall lines meeting without a depth jump at an
  angle of at least ``corner_min_angle_deg`` (concave or convex), each seen
  over at least ``min_line_len``; bearing of the two lines' intersection;
- *beacon* (``B``): a retro-reflective strip hit by at least two dense beams;
  bearing of the middle of its hits.

Camera features come from a dense noise-free render (no sun patches, no random
lighting, no vignetting) at the camera:

- *vertical edge* (``VE``): a column boundary across which the rendered colour
  changes by more than ``ve_contrast`` (any channel) over at least
  ``ve_min_extent_deg`` of elevation; boundaries closer than
  ``ve_merge_deg`` merge into one edge;
- *colour patch* (``CP``): a patch (poster) whose visible part is at least
  ``cp_min_size_deg`` wide and high; bearing of the middle of its visible
  pixels, hue of its albedo.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .._types import FArray
from ..angles import wrap
from ..errors import InvalidParameterError
from ..observation import Observation
from .camera import CAMERA_HEIGHT, ELEVATION_DEG, render_grid
from .laser import LASER_HEIGHT
from .world import World, cast_rays

__all__ = ["true_features", "true_observation"]



def _line_ids(world: World) -> NDArray[np.int64]:
    """Group segments lying on one straight line (collinear pieces of a wall)."""
    seg = world.segments
    m = seg.shape[0]
    d = seg[:, 2:] - seg[:, :2]
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    ids = np.arange(m)
    for i in range(m):
        for j in range(i):
            if abs(d[i, 0] * d[j, 1] - d[i, 1] * d[j, 0]) > 1e-6:
                continue
            w = seg[i, :2] - seg[j, :2]
            if abs(w[0] * d[j, 1] - w[1] * d[j, 0]) < 1e-6:
                ids[i] = ids[j]
                break
    return ids


def _circ_mean(a: FArray) -> float:
    return float(np.arctan2(np.sin(a).mean(), np.cos(a).mean()))


def _laser_truth(
    world: World,
    pose: tuple[float, float, float],
    *,
    max_range: float,
    height: float,
    step: float,
    jump_tol: float,
    min_line_len: float,
    corner_min_angle: float,
) -> dict[str, FArray]:
    x, y, th = pose
    n = round(2 * np.pi / step)
    bear = -np.pi + (np.arange(n) + 0.5) * (2 * np.pi / n)
    dist, seg, _ = cast_rays(world, (x, y), bear + th, z=height)
    far = ~(dist < max_range)
    seg = np.where(far, -1, seg)
    dist = np.where(far, np.inf, dist)
    hit = seg >= 0
    if not hit.any():
        empty = np.empty(0)
        return {"c": empty, "Ex": empty, "B": empty}
    P = np.column_stack(
        [x + np.where(hit, dist, 0) * np.cos(bear + th), y + np.where(hit, dist, 0) * np.sin(bear + th)]
    )
    nxt = np.roll(np.arange(n), -1)
    s0, s1 = seg, seg[nxt]
    both = hit & hit[nxt]
    gap = np.linalg.norm(P - P[nxt], axis=1)
    conn = np.zeros(n, dtype=bool)
    conn[both] = world.connected(s0[both], s1[both])
    jump = (hit != hit[nxt]) | (both & ~conn & (gap > jump_tol))  # between beam i and i + 1

    # Chains: maximal runs of hits without a jump; their length is summed along the hits.
    step_len = np.where(both & ~jump, gap, 0.0)
    lines = _line_ids(world)
    lid = np.where(hit, lines[np.where(hit, seg, 0)], -1)

    def run_length(i: int, direction: int, same_line: bool) -> float:
        # Length of the run of hits through beam i going backwards (-1) or forwards (+1).
        total, k = 0.0, i
        for _ in range(n):
            j = (k + direction) % n
            edge = k if direction > 0 else j  # the link between beams k and j is stored at min index
            if jump[edge] or not hit[j] or (same_line and lid[j] != lid[i]):
                break
            total += step_len[edge]
            k = j
            if total >= min_line_len:
                break
        return total

    corners: list[float] = []
    extremities: list[float] = []
    ends = world.segments.reshape(-1, 2, 2)
    for i in np.flatnonzero(jump):
        j = nxt[i]
        if hit[i] and (not hit[j] or dist[i] < dist[j]):
            near, direction = i, -1
        else:
            near, direction = j, +1
        if run_length(int(near), direction, False) < min_line_len:
            continue
        e = ends[seg[near]]
        k = int(np.argmin(np.linalg.norm(e - P[near], axis=1)))
        v = e[k]
        extremities.append(float(np.arctan2(v[1] - y, v[0] - x) - th))
    for i in np.flatnonzero(both & ~jump & (lid != lid[nxt])):
        j = nxt[i]
        a, b = world.segments[s0[i]], world.segments[s1[i]]
        da, db = a[2:] - a[:2], b[2:] - b[:2]
        da, db = da / np.linalg.norm(da), db / np.linalg.norm(db)
        cross = da[0] * db[1] - da[1] * db[0]
        ang = np.arcsin(min(abs(cross), 1.0))
        if ang < corner_min_angle:
            continue
        if run_length(int(i), -1, True) < min_line_len or run_length(int(j), +1, True) < min_line_len:
            continue
        w = b[:2] - a[:2]
        ta = (w[0] * db[1] - w[1] * db[0]) / cross
        v = a[:2] + ta * da
        corners.append(float(np.arctan2(v[1] - y, v[0] - x) - th))

    _, _, beacon_mat, _, _ = world.material_table()
    beacons: list[float] = []
    if hit.any():
        mat = np.full(n, -1)
        mat[hit] = world.surface_material(seg[hit], height)
        on_beacon = np.zeros(n, dtype=bool)
        on_beacon[hit] = beacon_mat[mat[hit]]
        for s in np.unique(seg[on_beacon]):
            sel = on_beacon & (seg == s)
            if sel.sum() >= 2:
                beacons.append(_circ_mean(bear[sel]))
    return {
        "c": np.sort(wrap(np.array(corners))),
        "Ex": np.sort(wrap(np.array(extremities))),
        "B": np.sort(wrap(np.array(beacons))),
    }


def _camera_truth(
    world: World,
    pose: tuple[float, float, float],
    *,
    camera_height: float,
    elevation_deg: tuple[float, float],
    step: float,
    row_step: float,
    ve_contrast: float,
    ve_min_extent: float,
    ve_merge: float,
    cp_min_size: float,
) -> dict[str, FArray]:
    n = round(2 * np.pi / step)
    bear: FArray = np.asarray(-np.pi + (np.arange(n) + 0.5) * (2 * np.pi / n), dtype=np.float64)
    e_lo, e_hi = np.deg2rad(elevation_deg[0]), np.deg2rad(elevation_deg[1])
    n_rows = max(round((e_hi - e_lo) / row_step), 2)
    elev = np.asarray(e_lo + (np.arange(n_rows) + 0.5) * (e_hi - e_lo) / n_rows, dtype=np.float64)
    r = render_grid(world, pose, bear, elev, camera_height=camera_height)
    img = np.minimum(r.albedo * r.shade[..., None], 1.0)  # an overexposed window is white
    diff = np.abs(img - np.roll(img, -1, axis=1)).max(axis=2)  # (rows, n): boundary after column j
    extent = (diff > ve_contrast).sum(axis=0) * (e_hi - e_lo) / n_rows
    is_edge = extent >= ve_min_extent
    edges: list[float] = []
    idx = np.flatnonzero(is_edge)
    if idx.size:
        b = -np.pi + (idx + 1) * (2 * np.pi / n)  # boundary bearings
        # Merge neighbouring boundaries (circularly) into one edge.
        groups: list[list[float]] = [[b[0]]]
        for k in range(1, idx.size):
            if idx[k] - idx[k - 1] <= max(round(ve_merge / step), 1):
                groups[-1].append(b[k])
            else:
                groups.append([b[k]])
        if len(groups) > 1 and (idx[0] + n - idx[-1]) <= max(round(ve_merge / step), 1):
            groups[0] = groups[0] + groups.pop()
        edges = [_circ_mean(np.array(g, dtype=np.float64)) for g in groups]

    cps: list[float] = []
    hues: list[float] = []
    for m_id, m in enumerate(world.materials):
        if not m.patch:
            continue
        mask = r.mat == m_id
        if not mask.any():
            continue
        width = mask.any(axis=0).sum() * step
        high = mask.sum(axis=0).max() * (e_hi - e_lo) / n_rows
        if width < cp_min_size or high < cp_min_size:
            continue
        cols = np.nonzero(mask)[1]
        cps.append(_circ_mean(bear[cols]))
        hues.append(m.hue_deg)
    order = np.argsort(wrap(np.array(cps))) if cps else np.empty(0, dtype=np.int64)
    return {
        "VE": np.sort(wrap(np.array(edges))),
        "CP": wrap(np.array(cps))[order],
        "CP_hue_deg": np.array(hues, dtype=np.float64)[order],
    }


def true_features(
    world: World,
    pose: tuple[float, float, float],
    *,
    max_range: float = 8.0,
    laser_height: float = LASER_HEIGHT,
    camera_height: float = CAMERA_HEIGHT,
    elevation_deg: tuple[float, float] = ELEVATION_DEG,
    resolution_deg: float = 0.1,
    jump_tol: float = 0.15,
    min_line_len: float = 0.2,
    corner_min_angle_deg: float = 30.0,
    ve_contrast: float = 0.05,
    ve_min_extent_deg: float = 6.0,
    ve_merge_deg: float = 1.0,
    cp_min_size_deg: float = 2.0,
) -> dict[str, FArray]:
    """Bearings of the features truly visible from ``pose`` (for evaluation only).

    Parameters
    ----------
    world : World
    pose : (x, y, theta)
        Robot pose, metres and radians.
    max_range : float
        Laser features farther than this (metres) are not visible.
    laser_height, camera_height : float
        Sensor heights, metres.
    elevation_deg : (low, high)
        Elevations the camera sees, degrees.
    resolution_deg : float
        Angular step of the dense scan and render, degrees.
    jump_tol : float
        Gap (metres) between neighbouring hits that makes a depth jump.
    min_line_len : float
        Shortest visible run (metres) that counts as a line for corners and extremities.
    corner_min_angle_deg : float
        Smallest angle between two lines that makes a corner, degrees.
    ve_contrast : float
        Colour step (image values in [0, 1], any channel) that makes an edge pixel.
    ve_min_extent_deg : float
        Smallest elevation extent of a vertical edge, degrees.
    ve_merge_deg : float
        Boundaries closer than this (degrees) are one edge.
    cp_min_size_deg : float
        Smallest visible width and height of a colour patch, degrees.

    Returns
    -------
    dict
        ``"c"``, ``"Ex"``, ``"B"``, ``"VE"``, ``"CP"``: sorted bearings, radians
        in ``[-pi, pi)``, robot frame, shape (n_type,); ``"CP_hue_deg"``: hue
        of each ``CP`` entry in degrees ``[0, 360)``, same order.
    """
    for name, v in (
        ("max_range", max_range),
        ("resolution_deg", resolution_deg),
        ("jump_tol", jump_tol),
        ("min_line_len", min_line_len),
        ("ve_contrast", ve_contrast),
    ):
        if not (np.isfinite(v) and v > 0):
            raise InvalidParameterError(f"{name} must be > 0, got {v!r}")
    p = (float(pose[0]), float(pose[1]), float(pose[2]))
    step = np.deg2rad(resolution_deg)
    out = _laser_truth(
        world,
        p,
        max_range=max_range,
        height=laser_height,
        step=step,
        jump_tol=jump_tol,
        min_line_len=min_line_len,
        corner_min_angle=np.deg2rad(corner_min_angle_deg),
    )
    out.update(
        _camera_truth(
            world,
            p,
            camera_height=camera_height,
            elevation_deg=elevation_deg,
            step=max(step, np.deg2rad(0.2)),
            row_step=np.deg2rad(0.5),
            ve_contrast=ve_contrast,
            ve_min_extent=np.deg2rad(ve_min_extent_deg),
            ve_merge=np.deg2rad(ve_merge_deg),
            cp_min_size=np.deg2rad(cp_min_size_deg),
        )
    )
    return out


def true_observation(
    world: World, pose: tuple[float, float, float], *, label: str | None = None, **kwargs: float
) -> Observation:
    """The ground truth of :func:`true_features` as a full-circle :class:`~fingerloc.observation.Observation`."""
    f = true_features(world, pose, **kwargs)  # type: ignore[arg-type]
    return Observation(
        ve=f["VE"],
        cp=f["CP"],
        cp_hue=f["CP_hue_deg"] % 360.0,
        ex=f["Ex"],
        c=f["c"],
        b=f["B"],
        label=label,
        pose=(float(pose[0]), float(pose[1]), float(pose[2])),
    )
