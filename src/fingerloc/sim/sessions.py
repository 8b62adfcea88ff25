"""Two visits of the same offices: what changes in a real office between a training run and a test run.

The paper's robot measured each office ten times (eight training, two test
measurements). A real office does not stay put between two visits hours apart
(another time of day, or another day): its occupants have moved their chairs,
closed a door, are sitting at their desk or standing in the room, and the
daylight is different. :func:`make_office_sessions` draws the offices of
:func:`~fingerloc.sim.make_offices` (the training visit, identical to
``make_offices`` with the same seed) and, from a second random stream, the
same offices at the test visit, changed as :class:`SessionChange` says. The
room, walls, furniture, posters, beacons and windows do not change.

The magnitudes (:data:`OFFICE_DAY`) were chosen from the physical reasoning
below, written down before any result of Tables III and IV was looked at
(docs/RESULTS.md, "What changes between the training and the test visit").
The robot experiment's default, :data:`PAPER_VISIT`, adds one quantity that
was calibrated on Table III instead (docs/METHOD.md §5): the robot's heading
at the test visit, off the training visit's by an angle per office
(``heading_offset_deg``, 24 deg standard deviation), as when an operator sets
the orientation by eye at each visit.

- **Chairs** (``chair_moved`` 0.8, ``chair_shift_m`` 0.3, ``chair_pull_m``
  0.2): office chairs roll on casters; whoever sits on one pushes it back,
  turns it, leaves it elsewhere at the desk. Between two visits hours apart
  nearly every chair that is used has moved (four in five), within the
  occupant's workspace: about 0.3 m along the desk and 0.2 m towards or away
  from it (standard deviations). A chair never comes within ``keep_clear_m``
  of the measurement point (the robot's operator would move it aside); one
  that fits nowhere else is taken to be pushed under a desk (dropped).
- **Doors** (``door_closed`` 0.2, ``leaf_swing_deg`` 10): institute office
  doors stay open while the occupant works and are closed while they are
  away, at a meeting, or on the phone; one visit in five finds an open door
  closed. A door that stays open is pushed to a slightly different angle
  (10 deg standard deviation, clipped to 50-100 deg).
- **People** (``seated_person`` 0.4, ``standing_person`` 0.25): surveys of
  office desk use commonly report desks occupied about 40-60 % of working
  hours (a figure from memory, not checked against a source), so
  at the test visit an occupant sits on one of the chairs with probability
  0.4 (torso and head up to 1.25-1.45 m, lower legs in front of the chair);
  with probability 0.25 someone stands in the room (a colleague, a visitor
  watching the robot): two legs up to 0.85 m and a body up to 1.6-1.9 m,
  anywhere free at least ``keep_clear_m`` from the measurement point. Their
  clothes are drawn from ordinary colours (tops HSV saturation up to 0.6,
  value 0.15-0.8; trousers saturation up to 0.3, value 0.1-0.45): a bright
  top may well look like a colour patch, as it would to the real robot.
- **Daylight and lamps** (``new_sun``, ``lamp_switched`` 0.3,
  ``window_emission`` 0.8-2.0): at another time of day the sun patches and
  shadows on walls and floor are elsewhere or gone (drawn afresh, 0-2), a
  window is a dimmer or brighter light source (its camera emission, 1.3 at
  the training visit, drawn in 0.8-2.0: an overcast afternoon to a low sun),
  and a ceiling lamp that was on may be off (three in ten).
- Not changed here: the camera's exposure and white balance, which
  :func:`~fingerloc.sim.render_omni` already draws afresh for every image
  (``lighting``: exposure with 25 % log-standard deviation, 6 % colour
  cast, a 15 % brightness gradient over bearing).

The robot's operator, who places the robot by hand at each measurement, is
not simulated: the paper says nothing of where they stood. Nothing is added at
the training visit (it stays the office calibrated to the paper's Table II),
so people appear at the test visit only: a one-sided simplification.
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..validation import check_random_state
from .offices import _DOOR_TOP, _NEW, _SEAT_Z, WORLDS, _build, _check_world, _polygon, _Spec, _spec_list
from .world import PARTS, World

__all__ = ["OFFICE_DAY", "PAPER_VISIT", "SessionChange", "describe_visit", "make_office_sessions", "next_visit_spec"]


@dataclass(frozen=True, slots=True)
class SessionChange:
    """What differs in an office between the training visit and the test visit.

    Parameters
    ----------
    chair_moved : float in [0, 1]
        Probability that a chair has moved.
    chair_shift_m, chair_pull_m : float
        Standard deviation of a moved chair's shift along its wall and towards or away
        from it, metres.
    door_closed : float in [0, 1]
        Probability that a door open at the training visit is closed.
    leaf_swing_deg : float
        Standard deviation of the change of an open door leaf's angle, degrees.
    seated_person, standing_person : float in [0, 1]
        Probability that someone sits on one of the chairs, and that someone stands in the room.
    lamp_switched : float in [0, 1]
        Probability that a ceiling lamp on at the training visit is off.
    new_sun : bool
        Draw the sun patches and shadows afresh (another time of day).
    window_emission : (low, high)
        Range of the windows' camera emission at the test visit (1.3 at the training visit).
    keep_clear_m : float
        Half side of the square around the measurement point that moved chairs and people
        stay out of, metres.
    heading_offset_deg : float, default 0
        Standard deviation of the robot's heading at the test visit relative to the training
        visit, one offset per office, degrees: the operator sets the robot's orientation by eye
        at each visit. The office itself does not depend on it (:func:`make_office_sessions`
        ignores it); the robot experiment turns the test poses by it.
    """

    chair_moved: float = 0.8
    chair_shift_m: float = 0.3
    chair_pull_m: float = 0.2
    door_closed: float = 0.2
    leaf_swing_deg: float = 10.0
    seated_person: float = 0.4
    standing_person: float = 0.25
    lamp_switched: float = 0.3
    new_sun: bool = True
    window_emission: tuple[float, float] = (0.8, 2.0)
    keep_clear_m: float = 0.75
    heading_offset_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("chair_moved", "door_closed", "seated_person", "standing_person", "lamp_switched"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0.0 <= float(v) <= 1.0):
                raise InvalidParameterError(f"{name} must be a probability in [0, 1], got {v!r}")
        for name in ("chair_shift_m", "chair_pull_m", "leaf_swing_deg", "keep_clear_m", "heading_offset_deg"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and np.isfinite(v) and v >= 0):
                raise InvalidParameterError(f"{name} must be >= 0, got {v!r}")
        lo, hi = (float(v) for v in self.window_emission)
        if not 0.0 <= lo <= hi <= 5.0:
            raise InvalidParameterError(f"window_emission must be (low, high) in [0, 5], got {self.window_emission!r}")
        object.__setattr__(self, "window_emission", (lo, hi))

    def to_dict(self) -> dict[str, Any]:
        """The settings as a JSON-ready dict."""
        d = asdict(self)
        d["window_emission"] = list(self.window_emission)
        return d


#: What changes in an office between two visits (the module docstring gives the reasoning).
OFFICE_DAY = SessionChange()

#: The robot experiment's default change between visits: :data:`OFFICE_DAY`, and the robot's
#: heading at the test visit off the training visit's by 24 deg (standard deviation, one offset per
#: office), calibrated on the paper's Table III together with the robot's perception errors
#: (:data:`fingerloc.sim.perception.PAPER_ROBOT`; docs/METHOD.md §5).
PAPER_VISIT = replace(OFFICE_DAY, heading_offset_deg=24.0)


def _clothes(rng: np.random.Generator) -> dict[str, Any]:
    import colorsys

    top = colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0, 0.6), rng.uniform(0.15, 0.8))
    leg = colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0, 0.3), rng.uniform(0.1, 0.45))
    return {"top_rgb": [float(v) for v in top], "leg_rgb": [float(v) for v in leg]}


def next_visit_spec(
    spec: _Spec, change: SessionChange, rng: np.random.Generator, anchor: tuple[float, float], world: str
) -> _Spec:
    """The office ``spec`` at a later visit: chairs, doors, people and light changed by ``change``.

    ``anchor`` (metres) is the measurement point of the training visit: moved chairs and
    people keep out of a square of half side ``change.keep_clear_m`` around it.
    """
    s = replace(spec, **{k: copy.deepcopy(getattr(spec, k)) for k in ("doors", "chairs", "lamps", "suns", "people")})
    poly = _polygon(s)
    n = poly.shape[0]
    lengths = [float(np.hypot(*(poly[(i + 1) % n] - poly[i]))) for i in range(n)]
    for ch in s.chairs:
        if rng.uniform() < change.chair_moved:
            length = lengths[int(ch["wall"]) % n]
            ch["u"] = float(np.clip(ch["u"] + change.chair_shift_m * rng.normal() / length, 0.03, 0.97))
            ch["off"] = float(np.clip(ch["off"] + change.chair_pull_m * rng.normal(), 0.3, 1.6))
    for d in s.doors:
        if rng.uniform() < change.door_closed:
            d["closed"] = True
        elif d.get("leaf", False):
            d["leaf_angle"] = float(np.clip(d["leaf_angle"] + change.leaf_swing_deg * rng.normal(), 50.0, 100.0))
    s.lamps = [lp for lp in s.lamps if rng.uniform() >= change.lamp_switched]
    if change.new_sun:
        lo, hi = WORLDS[world]["suns"]
        s.suns = [_NEW["suns"](rng) for _ in range(int(rng.integers(lo, hi + 1)))]
    s.window_emission = float(rng.uniform(*change.window_emission))
    people: list[dict[str, Any]] = []
    if s.chairs and rng.uniform() < change.seated_person:
        people.append(
            {
                "kind": "seated",
                "chair": int(rng.integers(0, len(s.chairs))),
                "top": float(rng.uniform(1.25, 1.45)),
                **_clothes(rng),
            }
        )
    if rng.uniform() < change.standing_person:
        people.append(
            {
                "kind": "standing",
                "candidates": [[float(u), float(v)] for u, v in rng.uniform(0.1, 0.9, size=(40, 2))],
                "facing": float(rng.uniform(-np.pi, np.pi)),
                "height": float(rng.uniform(1.6, 1.9)),
                **_clothes(rng),
            }
        )
    s.people = people
    k = change.keep_clear_m
    s.keep_out = (anchor[0] - k, anchor[1] - k, anchor[0] + k, anchor[1] + k)
    return s


def make_office_sessions(
    n: int,
    *,
    similarity: float = 0.5,
    random_state: int | np.random.Generator | None = None,
    world: str = "alike",
    change: SessionChange | None = OFFICE_DAY,
    change_random_state: int | np.random.Generator | None = None,
) -> list[tuple[World, World]]:
    """``n`` offices at the training visit and at the test visit.

    Parameters
    ----------
    n, similarity, random_state, world
        As in :func:`~fingerloc.sim.make_offices`: the training visits are exactly the
        offices ``make_offices`` gives with these arguments.
    change : SessionChange or None, default :data:`OFFICE_DAY`
        What differs at the test visit; None: nothing (the test visit is the same
        :class:`World` object).
    change_random_state : int or numpy.random.Generator, optional
        Seed or generator of the changes (a stream of its own, so that the training
        visits do not depend on ``change``).

    Returns
    -------
    list of (World, World)
        (training visit, test visit) per office, both named ``office-i``; the test visit
        keeps the training visit's ``anchor`` (the measurement point).
    """
    specs = _spec_list(n, similarity, random_state, _check_world(world))
    train = [_build(sp, f"office-{i}") for i, sp in enumerate(specs)]
    if change is None:
        return [(w, w) for w in train]
    crng = check_random_state(change_random_state)
    out = []
    for i, (sp, w) in enumerate(zip(specs, train, strict=True)):
        later = _build(next_visit_spec(sp, change, crng, w.anchor, world), f"office-{i}")
        out.append((w, replace(later, anchor=w.anchor)))
    return out


def describe_visit(before: World, after: World) -> str:
    """What differs between two visits of one office (:func:`make_office_sessions`), in words.

    Counts from the geometry: chairs moved (or gone), people seated and standing, closed
    doors, ceiling lamps off, whether the sun patches and the windows' brightness differ.
    """
    part_b, part_a = before.part, after.part
    chair, person, leaf = (PARTS.index(n) for n in ("chair", "person", "door_leaf"))
    n_chairs = int((part_b == chair).sum() // 8)
    old = {tuple(v) for v in before.segments[part_b == chair]}
    kept = sum(tuple(v) in old for v in after.segments[part_a == chair]) // 8
    z = after.z_range
    seated = int(((part_a == person) & np.isclose(z[:, 0], _SEAT_Z + 0.05)).sum() // 4)
    standing = int(((part_a == person) & np.isclose(z[:, 0], 0.85)).sum() // 4)
    closed = int(((part_a == leaf) & np.isclose(z[:, 1], _DOOR_TOP)).sum()) - int(
        ((part_b == leaf) & np.isclose(before.z_range[:, 1], _DOOR_TOP)).sum()
    )

    def lamps(w: World) -> int:
        return int(np.isclose(w.sun[:, 2], w.height).sum()) if w.sun.size else 0

    out = []
    if n_chairs > kept:
        out.append(f"{n_chairs - kept} of {n_chairs} chair{'s' if n_chairs > 1 else ''} moved")
    for n, what in ((seated, "seated"), (standing, "standing")):
        if n:
            out.append(f"{'one person' if n == 1 else f'{n} people'} {what}")
    if closed > 0:
        out.append(f"{'a door' if closed == 1 else f'{closed} doors'} closed")
    off = lamps(before) - lamps(after)
    if off > 0:
        out.append(f"{off} of {lamps(before)} ceiling lamps off")
    sun_b = before.sun[before.sun[:, 2] != before.height] if before.sun.size else before.sun
    sun_a = after.sun[after.sun[:, 2] != after.height] if after.sun.size else after.sun
    if sun_b.shape != sun_a.shape or not np.allclose(sun_b, sun_a):
        out.append("other sun patches")
    win_b = [m.emission for m in before.materials if m.emission > 0]
    win_a = [m.emission for m in after.materials if m.emission > 0]
    if (before.decal_material >= 0).any() and abs(win_b[0] - win_a[0]) >= 0.05 and any(
        after.materials[int(m)].emission > 0 for m in after.decal_material[after.decal_material >= 0]
    ):
        out.append(f"window brightness {win_b[0]:.1f} -> {win_a[0]:.1f}")
    return ", ".join(out) if out else "nothing changed"
