"""The office generator: rooms that resemble each other by a chosen amount.

One *template* office is drawn at random (room polygon, doors, furniture,
pillars, coloured posters, reflective beacons, sun patches); each office is the
template perturbed. ``similarity = 1`` gives identical rooms, ``similarity = 0``
independent ones: every element of the template is redrawn with probability
``1 - similarity`` and otherwise jittered by an amount proportional to
``1 - similarity``; extra elements appear and template ones vanish with
probability ``(1 - similarity) / 2`` each.

Colours: walls, floor, ceiling, furniture and door frames have HSV saturation
at most 0.25; only posters (``Material.patch``) are saturated (0.5-0.9).
"""

from __future__ import annotations

import colorsys
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..validation import check_random_state
from .world import PARTS, Material, World, point_in_polygon

__all__ = ["WORLDS", "make_office", "make_offices"]

_WALL_THICKNESS = 0.12  # metres: depth of a door frame
_DOOR_TOP = 2.05  # metres: height of a door opening
_FURN_GAP = 0.02  # metres between furniture and the wall it stands against
_SEAT_Z = 0.45  # metres: height of a chair's seat (below it, only the chair's column)
_CHAIR_POST = 0.06  # metres: width of a chair's column
_LEAF_SET_BACK = 0.04  # metres: how far a closed door's leaf sits back from the room-side face of the wall

#: Furniture kinds: (width range, depth range, height range), metres.
#: Door leaves: albedo (low saturation) and laser reflectivity.
_LEAF_MATS = [((0.66, 0.6, 0.5), 0.45), ((0.85, 0.85, 0.83), 0.55), ((0.5, 0.52, 0.55), 0.35)]

_FURNITURE = {
    "desk": ((1.2, 1.6), (0.7, 0.8), (0.72, 0.76)),
    "cabinet": ((0.8, 1.2), (0.4, 0.5), (1.8, 2.0)),
    "shelf": ((0.8, 1.0), (0.3, 0.4), (1.0, 2.0)),
    "drawers": ((0.4, 0.6), (0.45, 0.55), (0.6, 0.7)),
}
#: Furniture albedos (low saturation), laser reflectivity, gloss.
_FURN_MATS = [
    ((0.55, 0.56, 0.58), 0.35, 0.4),  # grey metal
    ((0.76, 0.68, 0.57), 0.45, 0.0),  # light wood
    ((0.85, 0.85, 0.82), 0.5, 0.1),  # white laminate
    ((0.30, 0.30, 0.32), 0.15, 0.2),  # dark grey
]


def _low_sat(rng: np.random.Generator, v: tuple[float, float], s_max: float) -> tuple[float, float, float]:
    h, s, val = rng.uniform(0, 1), rng.uniform(0, s_max), rng.uniform(*v)
    r, g, b = colorsys.hsv_to_rgb(h, s, val)
    return (float(r), float(g), float(b))


# ------------------------------------------------------------------ the spec
@dataclass
class _Spec:
    """An office before it becomes geometry: everything wall-relative so it can be perturbed."""

    width: float
    depth: float
    height: float
    notch: tuple[float, float] | None  # (width, depth) cut from the far corner (an L-shaped room) or None
    wall_rgb: tuple[float, float, float]
    wall_refl: float
    floor_rgb: tuple[float, float, float]
    frame_rgb: tuple[float, float, float]
    corridor_rgb: tuple[float, float, float]
    light_angle: float
    doors: list[dict[str, Any]]
    furniture: list[dict[str, Any]]
    pillars: list[dict[str, Any]]
    patches: list[dict[str, Any]]
    beacons: list[dict[str, Any]]
    suns: list[dict[str, Any]]
    windows: list[dict[str, Any]]
    lamps: list[dict[str, Any]]
    chairs: list[dict[str, Any]] = field(default_factory=list)
    # A later visit of the office (fingerloc.sim.sessions): people in the room, the daylight through
    # the windows (camera emission), and a floor-plan box (x0, y0, x1, y1, metres) around the
    # measurement point kept clear of moved chairs and of people.
    people: list[dict[str, Any]] = field(default_factory=list)
    window_emission: float = 1.3
    keep_out: tuple[float, float, float, float] | None = None


def _new_door(rng: np.random.Generator) -> dict[str, Any]:
    return {
        "wall": int(rng.integers(0, 6)),
        "u": float(rng.uniform(0.15, 0.85)),
        "width": float(rng.uniform(0.85, 1.0)),
        "corridor": float(rng.uniform(1.3, 2.5)),
        "leaf": bool(rng.uniform() < 0.5),
        "leaf_angle": float(rng.uniform(80.0, 100.0)),
        "hinge": int(rng.integers(0, 2)),
        "leaf_mat": int(rng.integers(0, len(_LEAF_MATS))),
    }


def _new_furniture(rng: np.random.Generator) -> dict[str, Any]:
    kind = str(rng.choice(list(_FURNITURE)))
    (w0, w1), (d0, d1), (h0, h1) = _FURNITURE[kind]
    return {
        "kind": kind,
        "wall": int(rng.integers(0, 6)),
        "u": float(rng.uniform(0.1, 0.9)),
        "width": float(rng.uniform(w0, w1)),
        "depth": float(rng.uniform(d0, d1)),
        "height": float(rng.uniform(h0, h1)),
        "mat": int(rng.integers(0, len(_FURN_MATS))),
    }


def _new_pillar(rng: np.random.Generator) -> dict[str, Any]:
    return {
        "wall": int(rng.integers(0, 6)),
        "u": float(rng.uniform(0.2, 0.8)),
        "size": float(rng.uniform(0.3, 0.45)),
        "free": bool(rng.uniform() < 0.3),
    }


def _new_patch(rng: np.random.Generator) -> dict[str, Any]:
    z0 = float(rng.uniform(0.9, 1.3))
    return {
        "wall": int(rng.integers(0, 6)),
        "u": float(rng.uniform(0.1, 0.9)),
        "width": float(rng.uniform(0.35, 1.0)),
        "z0": z0,
        "z1": z0 + float(rng.uniform(0.4, 0.9)),
        "hue": float(rng.uniform(0, 360)),
        "sat": float(rng.uniform(0.5, 0.9)),
        "val": float(rng.uniform(0.45, 0.85)),
    }


def _new_beacon(rng: np.random.Generator) -> dict[str, Any]:
    return {
        "wall": int(rng.integers(0, 6)),
        "u": float(rng.uniform(0.05, 0.95)),
        "width": float(rng.uniform(0.05, 0.08)),
    }


def _new_window(rng: np.random.Generator) -> dict[str, Any]:
    return {
        "wall": int(rng.integers(0, 6)),
        "u": float(rng.uniform(0.2, 0.8)),
        "width": float(rng.uniform(0.8, 1.6)),
        "z0": float(rng.uniform(0.8, 1.0)),
        "z1": float(rng.uniform(2.0, 2.3)),
    }


def _new_lamp(rng: np.random.Generator) -> dict[str, Any]:
    return {
        "u": float(rng.uniform(0.2, 0.8)),
        "v": float(rng.uniform(0.2, 0.8)),
        "hx": float(rng.uniform(0.15, 0.6)),
        "hy": float(rng.uniform(0.15, 0.6)),
        "gain": float(rng.uniform(0.3, 0.8)),
    }


def _new_chair(rng: np.random.Generator) -> dict[str, Any]:
    return {
        "wall": int(rng.integers(0, 6)),
        "u": float(rng.uniform(0.1, 0.9)),
        "off": float(rng.uniform(0.35, 0.8)),
        "size": float(rng.uniform(0.42, 0.5)),
        "back": float(rng.uniform(0.85, 1.05)),
        "mat": int(rng.integers(0, len(_FURN_MATS))),
    }


def _new_sun(rng: np.random.Generator) -> dict[str, Any]:
    return {
        "u": float(rng.uniform(0.1, 0.9)),
        "v": float(rng.uniform(0.1, 0.9)),
        "hx": float(rng.uniform(0.3, 0.9)),
        "hy": float(rng.uniform(0.3, 0.9)),
        "z": float(rng.uniform(0.0, 1.5)),
        "hz": float(rng.uniform(0.5, 1.5)),
        "gain": float(rng.choice([1.0, -1.0]) * rng.uniform(0.15, 0.5)),
    }


_NEW = {
    "doors": _new_door,
    "furniture": _new_furniture,
    "pillars": _new_pillar,
    "patches": _new_patch,
    "beacons": _new_beacon,
    "suns": _new_sun,
    "windows": _new_window,
    "lamps": _new_lamp,
    "chairs": _new_chair,
}
#: Element counts (low, high) of the ``"alike"`` world, the original generator.
_COUNTS = {
    "doors": (1, 2),
    "furniture": (3, 6),
    "pillars": (0, 1),
    "patches": (4, 6),
    "beacons": (4, 6),
    "suns": (0, 2),
    "windows": (0, 1),
    "lamps": (1, 3),
}
#: Element counts of the ``"paper"`` world (see :data:`WORLDS`): fewer posters,
#: more beacons, fewer pieces of furniture, and office chairs standing in the room.
_COUNTS_PAPER = {
    "doors": (1, 2),
    "furniture": (3, 4),
    "pillars": (0, 1),
    "patches": (2, 4),
    "beacons": (4, 6),
    "suns": (0, 2),
    "windows": (0, 1),
    "lamps": (1, 3),
    "chairs": (2, 4),
}
#: The office generators: name -> element counts.
WORLDS: dict[str, dict[str, tuple[int, int]]] = {"alike": _COUNTS, "paper": _COUNTS_PAPER}


def _new_spec(rng: np.random.Generator, world: str = "alike") -> _Spec:
    width, depth = float(rng.uniform(3.8, 6.5)), float(rng.uniform(3.2, 5.5))
    notch = (
        (float(rng.uniform(0.8, 0.4 * width)), float(rng.uniform(0.8, 0.4 * depth))) if rng.uniform() < 0.35 else None
    )
    counts = WORLDS[world]
    lists: dict[str, Any] = {
        k: [_NEW[k](rng) for _ in range(int(rng.integers(lo, hi + 1)))] for k, (lo, hi) in counts.items()
    }
    lists.setdefault("chairs", [])
    return _Spec(
        width=width,
        depth=depth,
        height=float(rng.uniform(2.5, 3.0)),
        notch=notch,
        wall_rgb=_low_sat(rng, (0.72, 0.92), 0.12),
        wall_refl=float(rng.uniform(0.35, 0.6)),
        floor_rgb=_low_sat(rng, (0.3, 0.6), 0.2),
        frame_rgb=_low_sat(rng, (0.25, 0.6), 0.2),
        corridor_rgb=_low_sat(rng, (0.55, 0.8), 0.1),
        light_angle=float(rng.uniform(-np.pi, np.pi)),
        **lists,
    )


def _jitter(x: dict[str, Any], amount: float, rng: np.random.Generator) -> dict[str, Any]:
    """Move an element's continuous parameters by ``amount`` (0 = none, 1 = large)."""
    out = dict(x)
    scale = {
        "u": 0.25,
        "width": 0.15,
        "depth": 0.1,
        "height": 0.1,
        "corridor": 0.4,
        "size": 0.05,
        "z0": 0.15,
        "z1": 0.15,
        "hue": 45.0,
        "sat": 0.1,
        "val": 0.1,
        "v": 0.25,
        "hx": 0.2,
        "hy": 0.2,
        "z": 0.3,
        "hz": 0.3,
        "off": 0.15,
        "back": 0.05,
    }
    for k, s in scale.items():
        if k in out:
            out[k] = float(out[k] + amount * s * rng.normal())
    if "u" in out:
        out["u"] = float(np.clip(out["u"], 0.03, 0.97))
    if "v" in out:
        out["v"] = float(np.clip(out["v"], 0.05, 0.95))
    if "hue" in out:
        out["hue"] = float(out["hue"] % 360.0)
    for k in ("sat", "val"):
        if k in out:
            out[k] = float(np.clip(out[k], 0.5 if k == "sat" else 0.4, 0.92))
    if "off" in out:
        out["off"] = float(np.clip(out["off"], 0.3, 1.2))
    for k in ("width", "depth", "size", "hx", "hy", "hz", "corridor"):
        if k in out:
            out[k] = float(max(out[k], 0.04 if k == "width" else 0.2))
    if "z0" in out:
        out["z1"] = float(max(out["z1"], out["z0"] + 0.3))
    return out


def _perturb(t: _Spec, similarity: float, rng: np.random.Generator, world: str = "alike") -> _Spec:
    q = 1.0 - similarity
    fresh = _new_spec(rng, world)
    s = replace(t)
    if rng.uniform() < q:
        s.width, s.depth, s.notch = fresh.width, fresh.depth, fresh.notch
    else:
        s.width = float(np.clip(t.width * (1 + 0.1 * q * rng.normal()), 3.5, 7.0))
        s.depth = float(np.clip(t.depth * (1 + 0.1 * q * rng.normal()), 3.0, 6.0))
    for name in ("wall_rgb", "floor_rgb", "frame_rgb", "corridor_rgb", "wall_refl", "height", "light_angle"):
        if rng.uniform() < q:
            setattr(s, name, getattr(fresh, name))
    for key in WORLDS[world]:
        items = []
        for item in getattr(t, key):
            r = rng.uniform()
            if r < q / 2:
                continue  # vanished
            items.append(_NEW[key](rng) if r < q else _jitter(item, q, rng))
        n_extra = int(rng.uniform() < q / 2) + int(rng.uniform() < q / 4)
        items += [_NEW[key](rng) for _ in range(n_extra)]
        if key == "doors" and not items:
            items = [_new_door(rng)]
        setattr(s, key, items)
    return s


# --------------------------------------------------------------- geometry
class _Builder:
    def __init__(self) -> None:
        self.seg: list[tuple[float, float, float, float]] = []
        self.z: list[tuple[float, float]] = []
        self.mat: list[int] = []
        self.dz: list[tuple[float, float]] = []
        self.dm: list[int] = []
        self.part: list[int] = []
        self.materials: list[Material] = []

    def material(self, m: Material) -> int:
        self.materials.append(m)
        return len(self.materials) - 1

    def add(
        self,
        p0: np.ndarray,
        p1: np.ndarray,
        z: tuple[float, float],
        mat: int,
        part: str,
        decal: tuple[float, float, int] | None = None,
    ) -> None:
        if np.hypot(*(p1 - p0)) < 1e-6:
            return
        self.seg.append((float(p0[0]), float(p0[1]), float(p1[0]), float(p1[1])))
        self.z.append(z)
        self.mat.append(mat)
        self.part.append(PARTS.index(part))
        if decal is None:
            self.dz.append((np.nan, np.nan))
            self.dm.append(-1)
        else:
            self.dz.append((decal[0], decal[1]))
            self.dm.append(decal[2])


def _overlaps(a: tuple[float, float], b: tuple[float, float], margin: float = 0.0) -> bool:
    return a[0] < b[1] + margin and b[0] < a[1] + margin


def _crosses_polygon(p0: np.ndarray, p1: np.ndarray, poly: np.ndarray) -> bool:
    """True when segment p0-p1 touches or crosses an edge of the polygon, or lies inside it."""
    r = p1 - p0
    for k in range(poly.shape[0]):
        q, s2 = poly[k], poly[(k + 1) % poly.shape[0]] - poly[k]
        den = r[0] * s2[1] - r[1] * s2[0]
        if abs(den) < 1e-12:
            continue
        w = q - p0
        t = (w[0] * s2[1] - w[1] * s2[0]) / den
        u = (w[0] * r[1] - w[1] * r[0]) / den
        if -1e-9 <= t <= 1 + 1e-9 and -1e-9 <= u <= 1 + 1e-9:
            return True
    return bool(point_in_polygon(poly, ((p0 + p1) / 2)[None, :])[0])


def _polygon(spec: _Spec) -> np.ndarray:
    w, d = spec.width, spec.depth
    if spec.notch is None:
        return np.array([(0, 0), (w, 0), (w, d), (0, d)], dtype=float)
    nw, nd = spec.notch
    return np.array([(0, 0), (w, 0), (w, d - nd), (w - nw, d - nd), (w - nw, d), (0, d)], dtype=float)


#: A box on the floor plan: ``x0, y0, x1, y1``, metres.
_Box = tuple[float, float, float, float]
#: A stretch of a wall: ``(wall index, lo, hi)``, metres along the wall from its first vertex.
_Span = tuple[int, float, float]


@dataclass
class _Office:
    """An office being built from its :class:`_Spec`: the room, its materials and what stands where.

    Positions along a wall (``lo``, ``hi``, ``a``, ``c``) are metres from the wall's first
    vertex; offsets from a wall are metres along its inward normal; heights are metres.
    """

    spec: _Spec
    poly: np.ndarray  # room polygon, shape (n, 2), counter-clockwise, metres
    length: list[float]  # length of each wall, metres
    b: _Builder = field(default_factory=_Builder)
    # Material indices into ``b.materials``.
    wall_m: int = -1
    frame_m: int = -1
    corr_m: int = -1
    beacon_m: int = -1
    window_m: int = -1
    leaf_m: list[int] = field(default_factory=list)
    furn_m: list[int] = field(default_factory=list)
    # Per wall: door openings (lo, hi, corridor distance), where furniture/pillars stand (lo, hi),
    # decals (lo, hi, z0, z1, material).
    doors: dict[int, list[tuple[float, float, float]]] = field(default_factory=dict)
    blocked: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    decals: dict[int, list[tuple[float, float, float, float, int]]] = field(default_factory=dict)
    # Open door leaves: (wall, lo, hi, angle in degrees, hinge side 0/1, leaf material choice).
    leaves: list[tuple[int, float, float, float, int, int]] = field(default_factory=list)
    # Floor-plan keep-out boxes: doorways and the footprints of what is already placed.
    taken: list[_Box] = field(default_factory=list)
    # Placed furniture: (wall, lo, hi, depth, height, material); pillars: (wall, lo, hi, inset);
    # chairs: (wall, lo, hi, offset from the wall, top of the back, material).
    furniture: list[tuple[int, float, float, float, float, int]] = field(default_factory=list)
    pillars: list[tuple[int, float, float, float]] = field(default_factory=list)
    chairs: list[tuple[int, float, float, float, float, int]] = field(default_factory=list)
    # Closed doors: (wall, lo, hi, leaf material choice); people: boxes (centre x, y, facing in
    # radians, width, depth, z_lo, z_hi, material), metres.
    closed: list[tuple[int, float, float, int]] = field(default_factory=list)
    people: list[tuple[float, float, float, float, float, float, float, int]] = field(default_factory=list)

    @property
    def n(self) -> int:
        """Number of walls (polygon vertices)."""
        return int(self.poly.shape[0])

    @property
    def height(self) -> float:
        """Ceiling height, metres."""
        return self.spec.height


def _new_office(spec: _Spec) -> _Office:
    """Start building ``spec``: its polygon, wall lengths (metres) and empty per-wall lists."""
    poly = _polygon(spec)
    n = poly.shape[0]
    length = [float(np.hypot(*(poly[(i + 1) % n] - poly[i]))) for i in range(n)]
    return _Office(
        spec=spec,
        poly=poly,
        length=length,
        doors={i: [] for i in range(n)},
        blocked={i: [] for i in range(n)},
        decals={i: [] for i in range(n)},
    )


def _add_materials(o: _Office) -> None:
    """Register the office's fixed materials (walls, frames, corridor, beacons, windows, leaves, furniture).

    Sets the ``*_m`` material indices of ``o``; poster materials are added later, one per poster.
    """
    s, b = o.spec, o.b
    o.wall_m = b.material(Material(s.wall_rgb, s.wall_refl))
    o.frame_m = b.material(Material(s.frame_rgb, 0.3, gloss=0.2))
    o.corr_m = b.material(Material(s.corridor_rgb, 0.45))
    o.beacon_m = b.material(Material((0.72, 0.72, 0.74), 1.5, beacon=True))
    o.window_m = b.material(Material((0.93, 0.95, 1.0), 0.3, emission=s.window_emission))  # daylight: overexposed
    o.leaf_m = [b.material(Material(rgb, refl)) for rgb, refl in _LEAF_MATS]
    o.furn_m = [b.material(Material(rgb, refl, gloss=gl)) for rgb, refl, gl in _FURN_MATS]


def _place(o: _Office, wall: int, u: float, width: float, margin: float) -> _Span | None:
    """Put an element ``width`` metres wide centred at fraction ``u`` of wall ``wall`` (taken modulo
    the number of walls), shifted to keep ``margin`` metres from both ends.

    Returns ``(wall index, lo, hi)`` in metres along the wall, or None when it does not fit.
    """
    i = wall % o.n
    lo = u * o.length[i] - width / 2
    lo = float(np.clip(lo, margin, o.length[i] - margin - width))
    hi = lo + width
    if lo < margin - 1e-9 or hi > o.length[i] - margin + 1e-9:
        return None
    return i, lo, hi


def _inside(o: _Office, box: _Box) -> bool:
    """True when the floor-plan box (metres) lies inside the room (corners tested 1 cm inward)."""
    c = np.array([(box[0], box[1]), (box[2], box[1]), (box[0], box[3]), (box[2], box[3])])
    c = c + np.sign(np.array([(1, 1), (-1, 1), (1, -1), (-1, -1)])) * 0.01
    return bool(point_in_polygon(o.poly, c).all())


def _free_of_doors(o: _Office, i: int, lo: float, hi: float, margin: float = 0.05) -> bool:
    """True when ``lo..hi`` (metres along wall ``i``) keeps ``margin`` metres from every door on it."""
    return not any(_overlaps((lo, hi), (a, c), margin) for a, c, _ in o.doors[i])


def _footprint(o: _Office, i: int, lo: float, hi: float, off0: float, off1: float) -> _Box:
    """The floor-plan bounding box (metres) of ``lo..hi`` along wall ``i`` between offsets
    ``off0`` and ``off1`` metres inward from it."""
    p0 = o.poly[i]
    t = (o.poly[(i + 1) % o.n] - p0) / o.length[i]
    nin = np.array([-t[1], t[0]])
    q = np.array([p0 + s * t + off * nin for s in (lo, hi) for off in (off0, off1)])
    return float(q[:, 0].min()), float(q[:, 1].min()), float(q[:, 0].max()), float(q[:, 1].max())


def _clash(box: _Box, others: list[_Box]) -> bool:
    """True when the floor-plan box overlaps any of ``others`` (all metres)."""
    return any(box[0] < o[2] and o[0] < box[2] and box[1] < o[3] and o[1] < box[3] for o in others)


def _place_doors(o: _Office) -> None:
    """Cut the spec's doors into the walls (skipping those that do not fit or come within 0.3 m
    of another), note their open leaves, and keep a box reaching about one metre into the room in
    front of each doorway free (``o.taken``)."""
    for dd in o.spec.doors:
        p = _place(o, dd["wall"], dd["u"], dd["width"], 0.25)
        if p is None or any(_overlaps((p[1], p[2]), (a, c), 0.3) for a, c, _ in o.doors[p[0]]):
            continue
        o.doors[p[0]].append((p[1], p[2], dd["corridor"]))
        if dd.get("closed", False):
            o.closed.append((p[0], p[1], p[2], int(dd["leaf_mat"])))
        elif dd.get("leaf", False):
            o.leaves.append((p[0], p[1], p[2], float(dd["leaf_angle"]), int(dd["hinge"]), int(dd["leaf_mat"])))
    o.taken = [_footprint(o, i, a - 0.25, c + 0.25, 0.0, 1.05) for i in range(o.n) for a, c, _ in o.doors[i]]


def _place_furniture(o: _Office) -> None:
    """Stand each piece of furniture against its wall, at the wanted spot or shifted by up to
    0.35 of the wall, clear of doors, other furniture and pillars; drop those that fit nowhere.

    Fills ``o.furniture`` with ``(wall, lo, hi, depth, height, material)`` (metres).
    """
    for f in o.spec.furniture:
        found = None
        for du in (0.0, 0.1, -0.1, 0.2, -0.2, 0.35, -0.35):
            p = _place(o, f["wall"], float(np.clip(f["u"] + du, 0.0, 1.0)), f["width"], 0.05)
            if (
                p is None
                or not _free_of_doors(o, p[0], p[1], p[2], 0.15)
                or any(_overlaps((p[1], p[2]), x) for x in o.blocked[p[0]])
            ):
                continue
            box = _footprint(o, p[0], p[1], p[2], 0.0, _FURN_GAP + f["depth"])
            if not _clash(box, o.taken) and _inside(o, box):
                found = p, box
                break
        if found is None:
            continue
        p, box = found
        o.taken.append(box)
        o.blocked[p[0]].append((p[1] - 0.03, p[2] + 0.03))
        o.furniture.append((p[0], p[1], p[2], f["depth"], f["height"], o.furn_m[f["mat"] % len(o.furn_m)]))


def _place_pillars(o: _Office) -> None:
    """Put each pillar against its wall (or 0.9 m in front of it when ``free``), skipping those
    that would touch a door or anything already placed.

    Fills ``o.pillars`` with ``(wall, lo, hi, inset)`` (metres).
    """
    for pl in o.spec.pillars:
        p = _place(o, pl["wall"], pl["u"], pl["size"], 0.3)
        if (
            p is None
            or not _free_of_doors(o, p[0], p[1], p[2], 0.2)
            or any(_overlaps((p[1], p[2]), x, 0.1) for x in o.blocked[p[0]])
        ):
            continue
        inset = 0.9 if pl["free"] else 0.0
        box = _footprint(o, p[0], p[1], p[2], inset - 0.05, inset + pl["size"] + 0.05)
        if _clash(box, o.taken) or not _inside(o, box):
            continue
        o.taken.append(box)
        o.blocked[p[0]].append((p[1] - 0.05, p[2] + 0.05))
        o.pillars.append((p[0], p[1], p[2], inset))


def _place_chairs(o: _Office) -> None:
    """Stand each office chair free in the room, near its wall spot, shifted along the wall and
    further in until its footprint is clear; drop those that fit nowhere.

    Fills ``o.chairs`` with ``(wall, lo, hi, offset from the wall, top of the back, material)`` (metres).
    """
    if o.spec.keep_out is not None:
        o.taken.append(o.spec.keep_out)
    for ch in o.spec.chairs:
        size = float(ch["size"])
        found = None
        for du, doff in itertools.product((0.0, 0.12, -0.12, 0.25, -0.25), (0.0, 0.4, 0.8)):
            p = _place(o, ch["wall"], float(np.clip(ch["u"] + du, 0.0, 1.0)), size, 0.1)
            if p is None:
                continue
            off = float(ch["off"]) + doff
            box = _footprint(o, p[0], p[1], p[2], off, off + size)
            if not _clash(box, o.taken) and _inside(o, box):
                found = p, off, box
                break
        if found is None:
            continue
        p, off, box = found
        o.taken.append(box)
        o.chairs.append((p[0], p[1], p[2], off, float(ch["back"]), o.furn_m[ch["mat"] % len(o.furn_m)]))


def _place_people(o: _Office) -> None:
    """Put the spec's people in the room (a later visit, :mod:`fingerloc.sim.sessions`).

    A ``"seated"`` person sits on one of the placed chairs (``chair``, modulo their number;
    skipped when there is none): a torso and head block from the seat up to ``top`` metres, and
    the lower legs in front of the chair, on the side away from its wall. A ``"standing"``
    person stands at the first of ``candidates`` (fractions of the room's bounding box) where a
    0.6 m square around them is inside the room and clear of everything placed (and of the
    spec's ``keep_out`` box): two legs 0.13 m square up to 0.85 m, and a body 0.44 x 0.26 m up
    to ``height``, turned by ``facing`` (radians). Fills ``o.people`` with boxes.
    """
    lo_xy, hi_xy = o.poly.min(axis=0), o.poly.max(axis=0)
    for pp in o.spec.people:
        top_m = o.b.material(Material(tuple(pp["top_rgb"]), 0.35))
        leg_m = o.b.material(Material(tuple(pp["leg_rgb"]), 0.3))
        if pp["kind"] == "seated":
            if not o.chairs:
                continue
            wi, lo, hi, off, _, _ = o.chairs[int(pp["chair"]) % len(o.chairs)]
            w = _wall_frame(o, wi)
            size = hi - lo
            facing = float(np.arctan2(w.nin[1], w.nin[0]))
            c = w.at((lo + hi) / 2, off + size / 2)
            o.people.append((float(c[0]), float(c[1]), facing, 0.38, 0.24, _SEAT_Z + 0.05, float(pp["top"]), top_m))
            shin = w.at((lo + hi) / 2, off + size + 0.11)
            o.people.append((float(shin[0]), float(shin[1]), facing, 0.32, 0.12, 0.0, _SEAT_Z + 0.05, leg_m))
            continue
        for u, v in pp["candidates"]:
            c = lo_xy + np.array([u, v]) * (hi_xy - lo_xy)
            box = (float(c[0] - 0.3), float(c[1] - 0.3), float(c[0] + 0.3), float(c[1] + 0.3))
            if _clash(box, o.taken) or not _inside(o, box):
                continue
            o.taken.append(box)
            f = float(pp["facing"])
            side = np.array([-np.sin(f), np.cos(f)])
            for sgn in (-1.0, 1.0):
                leg = c + sgn * 0.1 * side
                o.people.append((float(leg[0]), float(leg[1]), f, 0.13, 0.13, 0.0, 0.85, leg_m))
            o.people.append((float(c[0]), float(c[1]), f, 0.44, 0.26, 0.85, float(pp["height"]), top_m))
            break


def _first_fit(
    o: _Office, wall: int, u: float, width: float, ok: Callable[[_Office, int, float, float], bool]
) -> _Span | None:
    """The wanted spot, else the nearest of a few shifted ones along the same wall, else the next walls.

    Returns the first ``(wall index, lo, hi)`` (metres along the wall) that ``ok`` accepts, or None.
    """
    for dw in range(o.n):
        for du in (0.0, 0.12, -0.12, 0.25, -0.25, 0.4, -0.4):
            p = _place(o, wall + dw, float(np.clip(u + du, 0.0, 1.0)), width, 0.1)
            if p is not None and ok(o, *p):
                return p
    return None


def _patch_ok(o: _Office, i: int, lo: float, hi: float) -> bool:
    """Whether a poster or window may hang at ``lo..hi`` (metres along wall ``i``): off doors and other decals."""
    return _free_of_doors(o, i, lo, hi) and not any(_overlaps((lo, hi), (a, c), 0.1) for a, c, *_ in o.decals[i])


def _beacon_ok(o: _Office, i: int, lo: float, hi: float) -> bool:
    """Whether a beacon may go at ``lo..hi`` (metres along wall ``i``): off doors, furniture, pillars and decals."""
    return (
        _free_of_doors(o, i, lo, hi, 0.1)
        and not any(_overlaps((lo, hi), x, 0.1) for x in o.blocked[i])
        and not any(_overlaps((lo, hi), (a, c), 0.15) for a, c, *_ in o.decals[i])
    )


def _place_decals(o: _Office) -> None:
    """Hang posters (one new saturated material each), beacons (0.1-0.9 m up) and windows on the walls.

    Fills ``o.decals`` with ``(lo, hi, z0, z1, material)`` per wall (metres).
    """
    H = o.height
    for pt in o.spec.patches:
        p = _first_fit(o, pt["wall"], pt["u"], pt["width"], _patch_ok)
        if p is None:
            continue
        r, g, bb = colorsys.hsv_to_rgb(pt["hue"] / 360.0, pt["sat"], pt["val"])
        m = o.b.material(Material((float(r), float(g), float(bb)), 0.4, patch=True))
        o.decals[p[0]].append((p[1], p[2], pt["z0"], min(pt["z1"], H - 0.1), m))
    for bc in o.spec.beacons:
        p = _first_fit(o, bc["wall"], bc["u"], bc["width"], _beacon_ok)
        if p is None:
            continue
        o.decals[p[0]].append((p[1], p[2], 0.1, 0.9, o.beacon_m))
    for wd in o.spec.windows:
        p = _first_fit(o, wd["wall"], wd["u"], wd["width"], _patch_ok)
        if p is None:
            continue
        o.decals[p[0]].append((p[1], p[2], wd["z0"], min(wd["z1"], H - 0.15), o.window_m))


@dataclass(frozen=True)
class _WallFrame:
    """Wall ``i``'s frame: first vertex ``p0`` (metres), unit direction ``t``, inward normal ``nin``."""

    i: int
    p0: np.ndarray
    t: np.ndarray
    nin: np.ndarray
    length: float  # metres

    def at(self, s: float, off: float = 0.0) -> np.ndarray:
        """The floor-plan point ``s`` metres along the wall and ``off`` metres inward from it."""
        return self.p0 + s * self.t + off * self.nin


def _wall_frame(o: _Office, i: int) -> _WallFrame:
    """The frame of wall ``i`` (the polygon is counter-clockwise, so the left normal points inward)."""
    p0, p1 = o.poly[i], o.poly[(i + 1) % o.n]
    L = o.length[i]
    t = (p1 - p0) / L
    return _WallFrame(i=i, p0=p0, t=t, nin=np.array([-t[1], t[0]]), length=L)


def _add_wall_segments(o: _Office, w: _WallFrame) -> None:
    """The wall itself, cut at doors and decals: full-height pieces (carrying their decal) and lintels over doors."""
    doors, decals = o.doors[w.i], o.decals[w.i]
    cuts = {0.0, w.length}
    for a, c, _ in doors:
        cuts |= {a, c}
    for a, c, *_ in decals:
        cuts |= {a, c}
    for a, c in itertools.pairwise(sorted(cuts)):
        mid = (a + c) / 2
        if any(da <= mid <= dc for da, dc, _ in doors):
            o.b.add(w.at(a), w.at(c), (_DOOR_TOP, o.height), o.wall_m, "lintel")
            continue
        dec = next(((z0, z1, m) for da, dc, z0, z1, m in decals if da <= mid <= dc), None)
        o.b.add(w.at(a), w.at(c), (0.0, o.height), o.wall_m, "wall", dec)


def _add_door_segments(o: _Office, w: _WallFrame) -> None:
    """Each door's frame sides (``_WALL_THICKNESS`` deep) and the corridor wall seen through it."""
    for a, c, cd in o.doors[w.i]:
        for s in (a, c):
            o.b.add(w.at(s), w.at(s, -_WALL_THICKNESS), (0.0, _DOOR_TOP), o.frame_m, "door_frame")
        # Frame head and the corridor wall seen through the door.
        # The corridor must stay outside the room (an L-shaped room wraps around its notch).
        for dist, ext in ((cd, 1.5), (cd, 0.5), (min(cd, 0.9), 0.3)):
            q0, q1 = w.at(a - ext, -dist), w.at(c + ext, -dist)
            if not _crosses_polygon(q0, q1, o.poly):
                o.b.add(q0, q1, (0.0, o.height), o.corr_m, "corridor")
                break


def _add_closed_segments(o: _Office, w: _WallFrame) -> None:
    """Closed doors of this wall: the leaf fills the opening, set ``_LEAF_SET_BACK`` metres into the frame."""
    for wi, a, c, lm in o.closed:
        if wi == w.i:
            q0, q1 = w.at(a, -_LEAF_SET_BACK), w.at(c, -_LEAF_SET_BACK)
            o.b.add(q0, q1, (0.0, _DOOR_TOP), o.leaf_m[lm], "door_leaf")


def _add_leaf_segments(o: _Office, w: _WallFrame) -> None:
    """Open door leaves on this wall, each swung into the room by its angle (degrees) about its hinge."""
    for wi, a, c, angle, hinge, lm in o.leaves:
        if wi != w.i:
            continue
        phi = np.deg2rad(angle)
        along = np.cos(phi) * (w.t if hinge == 0 else -w.t) + np.sin(phi) * w.nin
        root = w.at(a if hinge == 0 else c)
        o.b.add(root, root + (c - a - 0.02) * along, (0.0, _DOOR_TOP - 0.02), o.leaf_m[lm], "door_leaf")


def _add_furniture_segments(o: _Office, w: _WallFrame) -> None:
    """The three exposed sides of each piece of furniture standing against this wall."""
    for wi, lo, hi, depth, height, m in o.furniture:
        if wi != w.i:
            continue
        q = [w.at(lo, _FURN_GAP), w.at(lo, _FURN_GAP + depth), w.at(hi, _FURN_GAP + depth), w.at(hi, _FURN_GAP)]
        for k in range(3):
            o.b.add(q[k], q[k + 1], (0.0, height), m, "furniture")


def _add_pillar_segments(o: _Office, w: _WallFrame) -> None:
    """Full-height pillars of this wall: three sides against the wall, four when standing free."""
    for wi, lo, hi, inset in o.pillars:
        if wi != w.i:
            continue
        size = hi - lo
        q = [w.at(lo, inset), w.at(lo, inset + size), w.at(hi, inset + size), w.at(hi, inset)]
        for k in range(3 if inset == 0.0 else 4):
            o.b.add(q[k], q[(k + 1) % 4], (0.0, o.height), o.wall_m, "pillar")


def _add_chair_segments(o: _Office, w: _WallFrame) -> None:
    """Office chairs placed from this wall: a seat-and-back block from ``_SEAT_Z`` up on a thin column."""
    for wi, lo, hi, off, back, m in o.chairs:
        if wi != w.i:
            continue
        size = hi - lo
        q = [w.at(lo, off), w.at(lo, off + size), w.at(hi, off + size), w.at(hi, off)]
        for k in range(4):
            o.b.add(q[k], q[(k + 1) % 4], (_SEAT_Z, back), m, "chair")
        centre = w.at((lo + hi) / 2, off + size / 2)
        r = _CHAIR_POST / 2
        post = [centre + np.array(v) for v in ((-r, -r), (r, -r), (r, r), (-r, r))]
        for k in range(4):
            o.b.add(post[k], post[(k + 1) % 4], (0.0, _SEAT_Z), m, "chair")


def _add_person_segments(o: _Office) -> None:
    """Each person's boxes as four vertical segments (width across ``facing``, depth along it)."""
    for cx, cy, f, width, depth, z0, z1, m in o.people:
        fwd = np.array([np.cos(f), np.sin(f)]) * depth / 2
        side = np.array([-np.sin(f), np.cos(f)]) * width / 2
        c = np.array([cx, cy])
        q = [c - fwd - side, c + fwd - side, c + fwd + side, c - fwd + side]
        for k in range(4):
            o.b.add(q[k], q[(k + 1) % 4], (z0, z1), m, "person")


def _add_segments(o: _Office) -> None:
    """Turn everything placed into vertical segments, wall by wall (the order fixes segment indices)."""
    for i in range(o.n):
        w = _wall_frame(o, i)
        _add_wall_segments(o, w)
        _add_door_segments(o, w)
        _add_closed_segments(o, w)
        _add_leaf_segments(o, w)
        _add_furniture_segments(o, w)
        _add_pillar_segments(o, w)
        _add_chair_segments(o, w)
    _add_person_segments(o)


def _light_boxes(o: _Office) -> np.ndarray:
    """Sun patches and ceiling lamps as light boxes ``cx, cy, cz, hx, hy, hz, gain`` (metres), shape (k, 7)."""
    sun = []
    lo_xy, hi_xy = o.poly.min(axis=0), o.poly.max(axis=0)
    for sn in o.spec.suns:
        cx = lo_xy[0] + sn["u"] * (hi_xy[0] - lo_xy[0])
        cy = lo_xy[1] + sn["v"] * (hi_xy[1] - lo_xy[1])
        sun.append((cx, cy, sn["z"], sn["hx"], sn["hy"], sn["hz"], float(np.clip(sn["gain"], -0.6, 0.8))))
    for lp in o.spec.lamps:  # ceiling lamps: bright panels on the ceiling
        cx = lo_xy[0] + lp["u"] * (hi_xy[0] - lo_xy[0])
        cy = lo_xy[1] + lp["v"] * (hi_xy[1] - lo_xy[1])
        sun.append((cx, cy, o.height, lp["hx"], lp["hy"], 0.05, float(np.clip(lp["gain"], 0.0, 1.0))))
    return np.array(sun).reshape(-1, 7)


def _to_world(o: _Office, name: str) -> World:
    """The finished :class:`World` named ``name``, with its anchor point set."""
    b = o.b
    world = World(
        segments=np.array(b.seg),
        z_range=np.array(b.z),
        material=np.array(b.mat),
        materials=tuple(b.materials),
        decal_z=np.array(b.dz),
        decal_material=np.array(b.dm),
        part=np.array(b.part),
        height=o.height,
        floor_rgb=o.spec.floor_rgb,
        ceiling_rgb=(0.9, 0.9, 0.88),
        light_angle=o.spec.light_angle,
        sun=_light_boxes(o),
        room=o.poly,
        name=name,
    )
    return replace(world, anchor=_anchor(world))


def _build(spec: _Spec, name: str) -> World:
    """Turn ``spec`` into a :class:`World` named ``name`` (deterministic: draws no random numbers)."""
    o = _new_office(spec)
    _add_materials(o)
    _place_doors(o)
    _place_furniture(o)
    _place_pillars(o)
    _place_chairs(o)
    _place_people(o)
    _place_decals(o)
    _add_segments(o)
    return _to_world(o, name)


def _anchor(world: World) -> tuple[float, float]:
    """A free point near the room's centre: clearance from obstacles as large as possible up to 1.2 m."""
    lo, hi = world.room.min(axis=0), world.room.max(axis=0)
    xs, ys = np.meshgrid(np.arange(lo[0], hi[0], 0.1), np.arange(lo[1], hi[1], 0.1))
    pts = np.column_stack([xs.ravel(), ys.ravel()])
    pts = pts[world.contains(pts)]
    clear = world.clearance(pts)
    centre = world.room.mean(axis=0)
    score = np.minimum(clear, 1.2) - 0.1 * np.linalg.norm(pts - centre, axis=1)
    best = pts[int(np.argmax(score))]
    return float(best[0]), float(best[1])


def _check_world(world: str) -> str:
    if world not in WORLDS:
        raise InvalidParameterError(f"world must be one of {', '.join(WORLDS)}, got {world!r}")
    return world


def make_office(
    *, random_state: int | np.random.Generator | None = None, name: str = "office", world: str = "alike"
) -> World:
    """One random office (a template drawn afresh); ``world`` as in :func:`make_offices`."""
    return _build(_new_spec(check_random_state(random_state), _check_world(world)), name)


def make_offices(
    n: int,
    *,
    similarity: float = 0.5,
    random_state: int | np.random.Generator | None = None,
    world: str = "alike",
) -> list[World]:
    """Generate ``n`` offices that resemble each other.

    Parameters
    ----------
    n : int
        Number of offices, at least 1.
    similarity : float in [0, 1], default 0.5
        How alike the offices are: 1 gives identical rooms (the shared
        template), 0 independent random rooms. Each template element (door,
        piece of furniture, pillar, poster, beacon, sun patch, room size,
        colours) is redrawn with probability ``1 - similarity``, dropped with
        probability ``(1 - similarity) / 2``, otherwise jittered by an amount
        proportional to ``1 - similarity``.
    random_state : int or numpy.random.Generator, optional
        Seed or generator; the same seed gives the same offices.
    world : {"alike", "paper"}, default "alike"
        The generator (:data:`WORLDS`). ``"alike"``: the original offices,
        rich in furniture and posters. ``"paper"``: offices furnished as the
        paper's robot saw them (Table II): two to four posters, four to six
        retro-reflective beacons, three or four pieces of furniture, and two to
        four office chairs standing in the room, which hide the lower part of
        whatever is behind them from the camera and, with their column, cut
        the laser's view. The same offices at a later visit (chairs moved,
        people, doors, daylight): :func:`fingerloc.sim.make_office_sessions`.

    Returns
    -------
    list of World
        Named ``office-0`` ... ``office-{n-1}``.
    """
    specs = _spec_list(n, similarity, random_state, _check_world(world))
    return [_build(sp, f"office-{i}") for i, sp in enumerate(specs)]


def _spec_list(n: int, similarity: float, random_state: int | np.random.Generator | None, world: str) -> list[_Spec]:
    """The specs of :func:`make_offices` (a template, then ``n`` perturbed copies), checked."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise InvalidParameterError(f"n must be a positive integer, got {n!r}")
    if not (isinstance(similarity, int | float) and 0.0 <= float(similarity) <= 1.0):
        raise InvalidParameterError(f"similarity must be in [0, 1], got {similarity!r}")
    rng = check_random_state(random_state)
    template = _new_spec(rng, world)
    return [_perturb(template, float(similarity), rng, world) for _ in range(int(n))]
