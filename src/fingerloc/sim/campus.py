"""A campus of many simulated places, fast: rooms and corridors seen by a 360 deg laser and a camera.

The office simulator (:func:`fingerloc.sim.make_offices` with
:func:`fingerloc.sim.simulate_scan` and the feature extractors) takes tens of
milliseconds a view; a campus of 100,000 places needs something a hundred
times faster. This module draws simpler places and derives their features
from the geometry directly, vectorised over thousands of views at once:

* **a place** is a rectangular room (80 %: 2.5-9 m a side) or a corridor
  (20 %: 1.6-2.6 m wide, 8-25 m long), with 1-2 door openings (through which
  the laser sees a wall 1.5-10 m further), 0-4 pieces of furniture standing
  against the walls (boxes 0.6-2 m long, up to 0.8 m deep), 0-2 retro-reflective
  beacons on its walls (30 % of places), 2-5 vertical edges and 1-4 colour
  patches on its walls (posters, doors, shelves) for the camera;
* **a view** is taken at a pose on a circle of 0.4-0.7 m radius around the
  place's anchor (training views) or inside it (queries), with a random
  heading, as in the paper's protocol; 0-2 people or chairs (0.3-0.5 m wide,
  0.8-3 m away) occlude part of it;
* **the laser** casts ``n_beams`` beams over the full circle (the paper's
  robot had two 180 deg heads), ranges with 1 cm + 1 % noise. Its features
  come from which surface each beam hits: a run of beams on one surface at
  least 0.3 m long is a wall segment (``W``, with its length and the range of
  its middle beam); two runs that meet without a depth jump make a corner
  (``c``); a depth jump (more than 0.3 m + 5 %) ends the nearer run in an
  extremity (``Ex``); a beacon seen unoccluded within 8 m is a ``B``;
* **the camera** (full circle) sees vertical edges (``VE``: room corners, door
  frames, furniture edges, the edges on the walls) and colour patches
  (``CP``, with their hue) that nothing occludes.

Feature bearings get 0.5 deg (laser) or 1.5 deg (camera) of noise; every
feature is missed with probability 0.1. Places resemble each other the way
rooms of one campus do (same kinds of rooms, furniture and doors), not by
construction from a template: localizing among them is hard (the ``laser2d``
preset ranks the right place first for about half of the queries among
1,000 places).

Places come in chunks of :data:`CHUNK` drawn from one seeded generator per
chunk, so place ``p`` is the same whatever range of places is asked for, and
the first ``N`` places of a larger campus are the campus of ``N`` places.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .._types import FArray, IArray
from ..angles import TWO_PI, wrap
from ..errors import InvalidParameterError
from ..observation import FULL_FOV, Observation

__all__ = ["CHUNK", "CampusChunk", "campus_chunks", "campus_observations"]

#: Places drawn from one generator (the unit of determinism).
CHUNK = 1000
#: Most boxes (furniture), doors, beacons, wall edges and colour patches a place has.
_BOXES, _DOORS, _BEACONS, _EDGES, _PATCHES = 4, 2, 2, 5, 4
#: Laser: largest range, metres; depth-jump and corner thresholds.
_MAX_RANGE = 30.0
_JUMP_M, _JUMP_REL = 0.3, 0.05
_MIN_WALL_M = 0.3
_MIN_RUN_BEAMS = 3
_BEACON_RANGE_M = 8.0
_MISS = 0.1
_LASER_NOISE_DEG, _CAMERA_NOISE_DEG = 0.5, 1.5


@dataclass(frozen=True, slots=True)
class CampusChunk:
    """The views of a range of places.

    Attributes
    ----------
    first : int
        Index of the chunk's first place (labels are ``place-<index>``).
    train, queries : list of Observation
        ``n_train`` training views and ``n_queries`` query views per place, place by place, labelled.
    """

    first: int
    train: list[Observation]
    queries: list[Observation]


def campus_observations(
    n_places: int,
    *,
    n_train: int = 3,
    n_queries: int = 1,
    n_beams: int = 360,
    camera: bool = False,
    random_heading: bool = True,
    seed: int = 20040426,
) -> tuple[list[Observation], list[Observation]]:
    """Training and query views of the first ``n_places`` places of the campus (module docstring).

    Returns
    -------
    train, queries : list of Observation
        ``n_train`` and ``n_queries`` labelled views a place, place by place.
    """
    train: list[Observation] = []
    queries: list[Observation] = []
    for ch in campus_chunks(
        n_places, n_train=n_train, n_queries=n_queries, n_beams=n_beams, camera=camera, random_heading=random_heading, seed=seed
    ):
        train += ch.train
        queries += ch.queries
    return train, queries


def campus_chunks(
    n_places: int,
    *,
    n_train: int = 3,
    n_queries: int = 1,
    n_beams: int = 360,
    camera: bool = False,
    random_heading: bool = True,
    seed: int = 20040426,
    start: int = 0,
) -> Iterator[CampusChunk]:
    """The places ``start .. n_places - 1`` of the campus, :data:`CHUNK` at a time (one chunk in memory at once).

    Parameters
    ----------
    n_places : int
        One past the last place.
    n_train, n_queries : int
        Views a place on the training circle and inside it.
    n_beams : int
        Laser beams over the full circle (360: 1 deg, as the SICK scanners of the shared logs).
    camera : bool
        Also the camera's features (vertical edges, colour patches): the paper's robot. Without, a
        laser-only robot (the ``laser2d`` preset's); the laser features are the same either way.
    random_heading : bool
        Each view with its own random heading (a robot that does not know its heading); False:
        every view at heading 0, the paper's protocol (its mixtures of bearings need it).
    seed : int
        Seed of the campus.
    start : int
        First place; a multiple of :data:`CHUNK`.
    """
    if isinstance(n_places, bool) or not isinstance(n_places, int) or n_places < 1:
        raise InvalidParameterError(f"n_places must be an integer >= 1, got {n_places!r}")
    if n_train < 1 or n_queries < 0:
        raise InvalidParameterError(f"n_train must be >= 1 and n_queries >= 0, got {n_train!r} and {n_queries!r}")
    if n_beams < 90:
        raise InvalidParameterError(f"n_beams must be >= 90, got {n_beams!r}")
    if start % CHUNK or start < 0:
        raise InvalidParameterError(f"start must be a multiple of {CHUNK}, got {start!r}")
    for first in range(start, n_places, CHUNK):
        rng = np.random.default_rng([seed, first // CHUNK])
        places = _draw_places(rng, CHUNK)
        count = min(CHUNK, n_places - first)
        views = n_train + n_queries
        pid = np.repeat(np.arange(CHUNK), views)
        is_train = np.tile(np.arange(views) < n_train, CHUNK)
        poses = _draw_poses(rng, places, pid, is_train)
        if not random_heading:
            poses[:, 2] = 0.0
        labels = [f"place-{first + int(p)}" if p < count else None for p in pid]
        obs = _observe(rng, places, pid, poses, n_beams, camera, labels)
        train = [o for o, t in zip(obs, is_train, strict=True) if o is not None and t]
        qs = [o for o, t in zip(obs, is_train, strict=True) if o is not None and not t]
        yield CampusChunk(first, train, qs)


# -- places --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Places:
    """Geometry of ``n`` places, each in its own frame (room ``[0, W] x [0, H]``)."""

    size: FArray  # (n, 2): W, H
    anchor: FArray  # (n, 2)
    boxes: FArray  # (n, _BOXES, 4): x0, y0, x1, y1 (empty box: x0 > x1)
    doors: FArray  # (n, _DOORS, 4): wall (0 right, 1 top, 2 left, 3 bottom), lo, hi along the wall, depth behind
    beacons: FArray  # (n, _BEACONS, 3): x, y, present
    edges: FArray  # (n, _EDGES, 3): x, y, present (vertical edges on the walls)
    patches: FArray  # (n, _PATCHES, 4): x, y, hue_deg, present


def _wall_point(size: FArray, wall: IArray, u: FArray) -> FArray:
    """Points at fraction ``u`` along wall ``wall`` of rooms of ``size``; shape ``(..., 2)``."""
    w, h = size[..., 0], size[..., 1]
    x = np.select([wall == 0, wall == 1, wall == 2], [w, u * w, np.zeros_like(u)], u * w)
    y = np.select([wall == 0, wall == 1, wall == 2], [u * h, h, u * h], np.zeros_like(u))
    return np.stack([x, y], axis=-1)


def _draw_places(rng: np.random.Generator, n: int) -> _Places:
    corridor = rng.random(n) < 0.2
    room = rng.uniform(2.5, 9.0, (n, 2))
    cw, cl = rng.uniform(1.6, 2.6, n), rng.uniform(8.0, 25.0, n)
    flip = rng.random(n) < 0.5
    size = np.where(corridor[:, None], np.stack([np.where(flip, cl, cw), np.where(flip, cw, cl)], 1), room)
    # anchor: at least 1.6 m from the walls where the room allows, else the middle of that axis
    margin = np.minimum(1.6, size / 2)
    anchor = margin + rng.random((n, 2)) * (size - 2 * margin)
    # furniture against the walls, never within 0.3 m of the training circle (0.7 m)
    boxes = np.zeros((n, _BOXES, 4))
    boxes[..., 0], boxes[..., 2] = 1.0, 0.0  # empty
    n_box = np.where(corridor, rng.integers(0, 2, n), rng.integers(0, _BOXES + 1, n))
    wall = rng.integers(0, 4, (n, _BOXES))
    length = rng.uniform(0.6, 2.0, (n, _BOXES))
    depth = rng.uniform(0.4, 0.8, (n, _BOXES))
    along = rng.random((n, _BOXES))
    w, h = size[:, 0:1], size[:, 1:2]
    ax, ay = anchor[:, 0:1], anchor[:, 1:2]
    room_to_anchor = np.select([wall == 0, wall == 1, wall == 2], [w - ax, h - ay, ax], ay)
    depth = np.minimum(depth, room_to_anchor - 1.0)
    wall_len = np.where(wall % 2 == 0, h, w)
    length = np.minimum(length, wall_len * 0.6)
    lo = along * (wall_len - length)
    ok = (np.arange(_BOXES)[None, :] < n_box[:, None]) & (depth >= 0.3)
    x0 = np.select([wall == 0, wall == 2], [w - depth, np.zeros_like(depth)], lo)
    x1 = np.select([wall == 0, wall == 2], [w, depth], lo + length)
    y0 = np.select([wall == 1, wall == 3], [h - depth, np.zeros_like(depth)], lo)
    y1 = np.select([wall == 1, wall == 3], [h, depth], lo + length)
    boxes[ok] = np.stack([x0, y0, x1, y1], -1)[ok]
    # doors: openings in the walls, with the far side 1.5-10 m behind
    doors = np.zeros((n, _DOORS, 4))
    dwall = rng.integers(0, 4, (n, _DOORS))
    dlen = np.where(dwall % 2 == 0, size[:, 1:2], size[:, 0:1])
    width = np.minimum(rng.uniform(0.9, 1.2, (n, _DOORS)), dlen * 0.4)
    dlo = 0.1 * dlen + rng.random((n, _DOORS)) * (0.8 * dlen - width)
    has_door = np.arange(_DOORS)[None, :] < rng.integers(1, _DOORS + 1, n)[:, None]
    doors[..., 0] = dwall
    doors[..., 1] = np.where(has_door, dlo, -1.0)
    doors[..., 2] = np.where(has_door, dlo + width, -1.0)
    doors[..., 3] = rng.uniform(1.5, 10.0, (n, _DOORS))

    def on_walls(k: int) -> FArray:
        return _wall_point(size[:, None, :], rng.integers(0, 4, (n, k)), rng.uniform(0.05, 0.95, (n, k)))

    beacons = np.concatenate([on_walls(_BEACONS), np.zeros((n, _BEACONS, 1))], -1)
    with_beacon = rng.random(n) < 0.3
    beacons[..., 2] = with_beacon[:, None] & (np.arange(_BEACONS)[None, :] < rng.integers(1, _BEACONS + 1, n)[:, None])
    edges = np.concatenate([on_walls(_EDGES), np.zeros((n, _EDGES, 1))], -1)
    edges[..., 2] = np.arange(_EDGES)[None, :] < rng.integers(2, _EDGES + 1, n)[:, None]
    patches = np.concatenate([on_walls(_PATCHES), rng.uniform(0, 360, (n, _PATCHES, 1)), np.zeros((n, _PATCHES, 1))], -1)
    patches[..., 3] = np.arange(_PATCHES)[None, :] < rng.integers(1, _PATCHES + 1, n)[:, None]
    return _Places(size, anchor, boxes, doors, beacons, edges, patches)


def _draw_poses(rng: np.random.Generator, places: _Places, pid: IArray, is_train: NDArray[np.bool_]) -> FArray:
    """Poses ``(x, y, theta)`` of the views, shape ``(V, 3)``: on the circle (training) or inside it (queries)."""
    v = pid.size
    radius = np.repeat(rng.uniform(0.4, 0.7, places.size.shape[0]), np.bincount(pid))[:v]
    r = np.where(is_train, radius * rng.uniform(0.95, 1.05, v), radius * np.sqrt(rng.random(v)))
    a = rng.uniform(-math.pi, math.pi, v)
    xy = places.anchor[pid] + r[:, None] * np.stack([np.cos(a), np.sin(a)], 1)
    return np.column_stack([xy, rng.uniform(-math.pi, math.pi, v)])


# -- sensing ---------------------------------------------------------------------------------------


def _cast(places: _Places, pid: IArray, origin: FArray, angle: FArray) -> tuple[FArray, IArray, FArray]:
    """Rays from ``origin[v]`` (``(V, 2)``) at world angles ``angle`` (``(V, B)``): range, surface id, hit point.

    Surface ids: 0-3 the room's walls (right, top, left, bottom); 4 + 4 * box + side a box's sides;
    20 + door the wall seen through a door.
    """
    dx, dy = np.cos(angle), np.sin(angle)
    ox, oy = origin[:, 0:1], origin[:, 1:2]
    w, h = places.size[pid, 0:1], places.size[pid, 1:2]
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(dx > 0, (w - ox) / dx, np.where(dx < 0, -ox / dx, np.inf))
        ty = np.where(dy > 0, (h - oy) / dy, np.where(dy < 0, -oy / dy, np.inf))
    t = np.minimum(tx, ty)
    sid = np.where(tx <= ty, np.where(dx > 0, 0, 2), np.where(dy > 0, 1, 3)).astype(np.int64)
    # a wall hit inside a door opening goes through, to a wall ``depth`` further along the wall's normal
    px, py = ox + t * dx, oy + t * dy
    along = np.where(sid % 2 == 0, py, px)
    normal = np.where(sid % 2 == 0, np.abs(dx), np.abs(dy))
    for d in range(_DOORS):
        door = places.doors[pid, d]
        inside = (sid == door[:, 0:1].astype(np.int64)) & (along >= door[:, 1:2]) & (along <= door[:, 2:3])
        t = np.where(inside, t + door[:, 3:4] / np.maximum(normal, 0.15), t)
        sid = np.where(inside, 20 + d, sid)
    for k in range(_BOXES):
        b = places.boxes[pid, k]
        x0, y0, x1, y1 = b[:, 0:1], b[:, 1:2], b[:, 2:3], b[:, 3:4]
        with np.errstate(divide="ignore", invalid="ignore"):
            ax0, ax1 = (x0 - ox) / dx, (x1 - ox) / dx
            ay0, ay1 = (y0 - oy) / dy, (y1 - oy) / dy
        nx, fx = np.fmin(ax0, ax1), np.fmax(ax0, ax1)
        ny, fy = np.fmin(ay0, ay1), np.fmax(ay0, ay1)
        near = np.fmax(nx, ny)
        hit = (x0 < x1) & (near <= np.fmin(fx, fy)) & (near > 1e-6) & (near < t)
        side = np.where(nx >= ny, np.where(dx > 0, 2, 0), np.where(dy > 0, 3, 1))  # the box side facing the ray
        t = np.where(hit, near, t)
        sid = np.where(hit, 4 + 4 * k + side, sid)
    t = np.minimum(t, _MAX_RANGE)
    return t, sid, np.stack([ox + t * dx, oy + t * dy], -1)


def _visible(places: _Places, pid: IArray, poses: FArray, points: FArray, present: NDArray[np.bool_]) -> tuple[FArray, NDArray[np.bool_]]:
    """Bearings (robot frame) of ``points`` (``(V, k, 2)``) and whether each is present and unoccluded."""
    d = points - poses[:, None, :2]
    dist = np.hypot(d[..., 0], d[..., 1])
    ang = np.arctan2(d[..., 1], d[..., 0])
    r, _, _ = _cast(places, pid, poses[:, :2], ang)
    seen = present & (r >= dist - 0.05)
    return wrap(ang - poses[:, 2:3]), seen


def _observe(
    rng: np.random.Generator,
    places: _Places,
    pid: IArray,
    poses: FArray,
    n_beams: int,
    camera: bool,
    labels: list[str | None],
) -> list[Observation | None]:
    """The views at ``poses`` (``labels[i]`` None: drawn but not built, so that the draws stay the same)."""
    v = pid.size
    beam: FArray = np.asarray(-math.pi + (np.arange(n_beams) + 0.5) * (TWO_PI / n_beams), dtype=np.float64)  # robot frame
    ang = poses[:, 2:3] + beam[None, :]
    r, sid, pts = _cast(places, pid, poses[:, :2], ang)
    # people and chairs: 0-2 occluders a view, 0.3-0.5 m wide, 0.8-3 m away
    for _ in range(2):
        there = rng.random(v) < 0.4
        dist = rng.uniform(0.8, 3.0, v)
        centre = rng.uniform(-math.pi, math.pi, v)
        half = np.arctan(rng.uniform(0.15, 0.25, v) / dist)
        off = np.abs(wrap(beam[None, :] - centre[:, None]))
        cover = there[:, None] & (off <= half[:, None]) & (r > dist[:, None])
        r = np.where(cover, dist[:, None], r)
        sid = np.where(cover, 30 + _, sid)
        world = poses[:, 2:3] + beam[None, :]
        pts = np.where(cover[..., None], poses[:, None, :2] + r[..., None] * np.stack([np.cos(world), np.sin(world)], -1), pts)
    laser = _laser_features(r, sid, pts, beam)
    noisy_r = r + rng.normal(0.0, 1.0, r.shape) * (0.01 + 0.01 * r)
    noisy_r = np.clip(noisy_r, 0.02, _MAX_RANGE)
    # point features: beacons (laser), vertical edges and colour patches (camera)
    b_ang, b_seen = _visible(places, pid, poses, places.beacons[pid, :, :2], places.beacons[pid, :, 2] > 0)
    b_seen &= np.hypot(*(places.beacons[pid, :, :2] - poses[:, None, :2]).transpose(2, 0, 1)) <= _BEACON_RANGE_M
    corners = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.0, 0.0]])[None] * places.size[pid][:, None, :]
    frames = np.concatenate(
        [_wall_point(places.size[pid][:, None, :], places.doors[pid, :, 0].astype(np.int64), places.doors[pid, :, c] / np.where(places.doors[pid, :, 0] % 2 == 0, places.size[pid, 1:2], places.size[pid, 0:1])) for c in (1, 2)],
        axis=1,
    )  # fmt: skip
    frames_ok = np.concatenate([places.doors[pid, :, 1] >= 0] * 2, axis=1)
    bx = places.boxes[pid]
    box_corners = np.stack([bx[..., [0, 1]], bx[..., [2, 1]], bx[..., [2, 3]], bx[..., [0, 3]]], 2).reshape(v, -1, 2)
    box_ok = np.repeat(bx[..., 0] < bx[..., 2], 4, axis=1)
    ve_pts = np.concatenate([corners, frames, box_corners, places.edges[pid, :, :2]], axis=1)
    ve_ok = np.concatenate([np.ones((v, 4), dtype=bool), frames_ok, box_ok, places.edges[pid, :, 2] > 0], axis=1)
    ve_ang, ve_seen = _visible(places, pid, poses, ve_pts, ve_ok)
    cp_ang, cp_seen = _visible(places, pid, poses, places.patches[pid, :, :2], places.patches[pid, :, 3] > 0)
    cp_hue = places.patches[pid, :, 2]

    def noisy(a: FArray, sd_deg: float) -> FArray:
        return wrap(a + rng.normal(0.0, math.radians(sd_deg), a.shape))

    def kept(seen: NDArray[np.bool_]) -> NDArray[np.bool_]:
        return seen & (rng.random(seen.shape) >= _MISS)

    b_ang, b_seen = noisy(b_ang, _LASER_NOISE_DEG), kept(b_seen)
    ve_ang, ve_seen = noisy(ve_ang, _CAMERA_NOISE_DEG), kept(ve_seen)
    cp_ang, cp_seen = noisy(cp_ang, _CAMERA_NOISE_DEG), kept(cp_seen)
    c_view, c_ang, e_view, e_ang, w_view, w_ang, w_len, w_rng = laser
    c_keep = rng.random(c_ang.size) >= _MISS
    e_keep = rng.random(e_ang.size) >= _MISS
    w_keep = rng.random(w_ang.size) >= _MISS / 2
    c_ang, e_ang, w_ang = noisy(c_ang, _LASER_NOISE_DEG), noisy(e_ang, _LASER_NOISE_DEG), noisy(w_ang, _LASER_NOISE_DEG)
    w_len = w_len * rng.uniform(0.95, 1.05, w_len.size)
    w_rng = w_rng * rng.uniform(0.98, 1.02, w_rng.size)
    cs = np.searchsorted(c_view, np.arange(v + 1))
    es = np.searchsorted(e_view, np.arange(v + 1))
    ws = np.searchsorted(w_view, np.arange(v + 1))
    beam_ro = _read_only(beam)
    out: list[Observation | None] = []
    for i in range(v):
        if labels[i] is None:
            out.append(None)
            continue
        wk = w_keep[ws[i] : ws[i + 1]]
        walls = w_ang[ws[i] : ws[i + 1]][wk]
        order = np.argsort(walls, kind="stable")
        feats = {
            "ex": np.sort(e_ang[es[i] : es[i + 1]][e_keep[es[i] : es[i + 1]]]),
            "c": np.sort(c_ang[cs[i] : cs[i + 1]][c_keep[cs[i] : cs[i + 1]]]),
            "b": np.sort(b_ang[i][b_seen[i]]),
            "w": walls[order],
            "w_length": w_len[ws[i] : ws[i + 1]][wk][order],
            "w_range": w_rng[ws[i] : ws[i + 1]][wk][order],
        }
        if camera:
            cp, hue = cp_ang[i][cp_seen[i]], cp_hue[i][cp_seen[i]]
            by = np.lexsort((hue, cp))
            feats.update(ve=np.sort(ve_ang[i][ve_seen[i]]), cp=cp[by], cp_hue=hue[by])
        pose = (float(poses[i, 0]), float(poses[i, 1]), float(poses[i, 2]))
        out.append(_observation(feats, noisy_r[i], beam_ro, pose, labels[i]))
    return out


def _read_only(a: FArray) -> FArray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    a.setflags(write=False)
    return a


def _observation(
    feats: dict[str, FArray], ranges: FArray, beam: FArray, pose: tuple[float, float, float], label: str | None
) -> Observation:
    """An observation of arrays already in :class:`~fingerloc.observation.Observation`'s final form.

    Bearings wrapped and sorted (colour patches by bearing then hue, wall lengths and ranges in their
    walls' order), ranges finite and positive: what ``Observation.__post_init__`` would make of them
    (``tests/test_sim_campus.py`` compares the two), without its checks, which cost more than
    drawing the view. Empty feature types share one empty array; every view shares the beam bearings.
    """
    obs = Observation._checked(
        {k: _read_only(a) for k, a in feats.items() if a.size}, fov=FULL_FOV, label=label, pose=pose, timestamp=None, source=None
    )
    object.__setattr__(obs, "ranges", _read_only(ranges))
    object.__setattr__(obs, "range_bearings", beam)
    return obs


def _laser_features(
    r: FArray, sid: IArray, pts: FArray, beam: FArray
) -> tuple[IArray, FArray, IArray, FArray, IArray, FArray, FArray, FArray]:
    """Corners, extremities and wall segments of every view from the surface each beam hits.

    Returns, each sorted by view: ``(c_view, c_bearing, e_view, e_bearing, w_view, w_bearing, w_length, w_range)``.
    """
    v, n = r.shape
    nxt = np.roll(np.arange(n), -1)
    change = sid != sid[:, nxt]  # a boundary between beam b and b + 1 (circularly)
    vv, bb = np.nonzero(change)
    # runs: from the beam after a boundary to the next boundary of the same view (circularly)
    count = np.bincount(vv, minlength=v)
    first_of_view = np.concatenate([[0], np.cumsum(count)[:-1]])
    nxt_k = np.arange(vv.size) + 1
    last = nxt_k == np.repeat(first_of_view + count, count)
    nxt_k[last] = np.repeat(first_of_view, count)[last]
    start = (bb + 1) % n
    end = bb[nxt_k]  # inclusive
    length_beams = (end - start) % n + 1
    mid = (start + (length_beams - 1) // 2) % n
    seg_len = np.hypot(*(pts[vv, start] - pts[vv, end]).T)
    wall = (length_beams >= _MIN_RUN_BEAMS) & (seg_len >= _MIN_WALL_M)
    # boundaries: beam bb (end of the run before) and bb + 1 (start of the run k)
    prev_k = np.empty_like(nxt_k)
    prev_k[nxt_k] = np.arange(vv.size)
    ra, rb = r[vv, bb], r[vv, (bb + 1) % n]
    jump = np.abs(ra - rb) > _JUMP_M + _JUMP_REL * np.minimum(ra, rb)
    long_before = length_beams[prev_k] >= _MIN_RUN_BEAMS
    long_after = length_beams >= _MIN_RUN_BEAMS
    between = beam[bb] + math.pi / n  # bearing midway between the two beams
    corner = ~jump & long_before & long_after & (sid[vv, bb] < 20) & (sid[vv, (bb + 1) % n] < 20)
    ext_a = jump & (ra < rb) & long_before  # the run before ends nearer: its last beam
    ext_b = jump & (rb < ra) & long_after
    e_view = np.concatenate([vv[ext_a], vv[ext_b]])
    e_ang = np.concatenate([beam[bb[ext_a]], beam[(bb[ext_b] + 1) % n]])
    order = np.argsort(e_view, kind="stable")
    return (
        vv[corner],
        wrap(between[corner]),
        e_view[order],
        e_ang[order],
        vv[wall],
        beam[mid[wall]],
        seg_len[wall],
        r[vv[wall], mid[wall]],
    )
