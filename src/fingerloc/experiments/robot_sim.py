"""The simulated robot experiment's protocol, worlds and measurements (see :mod:`fingerloc.experiments.robot`).

The paper's figures (Tables II-IV), the simulated worlds (:data:`WORLD_PROFILES`),
the protocol (:class:`RobotProtocol`), and the simulation of one trial's raw
sensor data and extracted features (:func:`simulate_trial`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..observation import Observation

__all__ = [
    "PAPER_K",
    "PAPER_TABLE2",
    "PAPER_TABLE3",
    "PAPER_TABLE4",
    "TABLE2_TYPES",
    "TABLE4_EXP",
    "TABLE4_FITTED",
    "TABLE4_NAMES",
    "TABLE4_TERMS",
    "WORLD_PROFILES",
    "Measurement",
    "RobotProtocol",
    "TrialData",
    "measurement_poses",
    "simulate_office",
    "simulate_trial",
]


#: Mixture components of the paper's Table IV columns.
PAPER_K: tuple[int, ...] = (3, 4, 5)
#: The paper's Table II: mean features per measurement of its robot.
PAPER_TABLE2: dict[str, float] = {"VE": 5.6, "Ex": 5.6, "CP": 2.7, "B": 3.9}
#: The paper's Table III: (right classification in [0, 1], mean rank).
PAPER_TABLE3: dict[str, tuple[float, float]] = {
    "minimum_energy": (0.624, 1.87),
    "global_alignment": (0.871, 1.21),
}
#: Term sets of the paper's Table IV rows, by JSON key.
TABLE4_TERMS: dict[str, tuple[str, ...]] = {
    "VE": ("VE",),
    "Ex": ("Ex",),
    "VE+Ex": ("VE", "Ex"),
    "VE+Ex+Fp": ("VE", "Ex", "Fp"),
}
#: Our extra Table IV row: the full program with per-term weights fit on the training views
#: (``PlaceModel(weights="fit")``); not in the paper.
TABLE4_FITTED = "VE+Ex+Fp-fit"
#: Our other extra Table IV row: the full program with the fingerprint's likelihood on the mixtures'
#: scale, ``P(Fp | loc) ∝ exp(-lambda cost)`` (``PlaceModel(fp_likelihood="exp")``, ``lambda`` fit
#: leave-one-out on the training views) instead of the paper's ``1 / (cost + 1)``; not in the paper.
TABLE4_EXP = "VE+Ex+Fp-exp"
#: Display names of the Table IV rows (ours and the paper's), in print order.
TABLE4_NAMES: dict[str, str] = {
    "VE": "VE only",
    "Ex": "Ex only",
    "VE+Ex": "VE & Ex",
    "VE+Ex+Fp": "VE, Ex & fingerprint",
    TABLE4_FITTED: "VE, Ex & fingerprint, term weights fit (not in the paper)",
    TABLE4_EXP: "VE, Ex & fingerprint, P(Fp) ∝ exp(-λ cost) (not in the paper)",
}
#: The paper's Table IV: row -> k -> (right classification in [0, 1], mean rank).
PAPER_TABLE4: dict[str, dict[int, tuple[float, float]]] = {
    "VE": {3: (0.421, 2.58), 4: (0.471, 2.47), 5: (0.556, 1.82)},
    "Ex": {3: (0.556, 1.65), 4: (0.511, 1.71), 5: (0.471, 1.71)},
    "VE+Ex": {3: (0.588, 2.00), 4: (0.667, 1.82), 5: (0.667, 1.67)},
    "VE+Ex+Fp": {3: (0.611, 1.78), 4: (0.706, 1.58), 5: (0.824, 1.23)},
}
#: Feature types counted in Table II (the paper's four, then corners).
TABLE2_TYPES: tuple[str, ...] = ("VE", "Ex", "CP", "B", "c")


#: The offices' likeness, the robot's sensors and its extractor settings per simulated world
#: (``RobotProtocol.world``). ``"paper"``: offices of one institute corridor (similarity 0.8:
#: same room grid and furniture), a softer, noisier camera image (the paper's 640x480 mirror
#: camera: defocus 1.5 px, pixel noise 2.5 %, JPEG 75) and a vertical-edge extractor that keeps
#: only long, strong edges (a run over 35 % of the elevation range or edge pixels over half of it,
#: a step of 0.15 in log luminance): calibrated to the paper's Table II; the test measurements are
#: taken at a later visit of the offices (``"session"``: :data:`~fingerloc.sim.sessions.PAPER_VISIT`:
#: chairs moved, a door closed, people in the room, other daylight, and the robot's heading off the
#: training visit's by an angle per office of 24 deg standard deviation), and the robot's extractors
#: miss and invent features as a real robot's do (``"perception"``:
#: :data:`~fingerloc.sim.perception.PAPER_ROBOT`: one feature in twenty lost, as many false ones
#: added); the heading and the perception errors are calibrated on the paper's Table III.
#: ``"paper-static"``: the same offices and robot with nothing changed between the training and the
#: test visit (no moved chairs, no people, the same heading). ``"paper-ideal"``: the ``"paper"``
#: world's offices and visits (:data:`~fingerloc.sim.sessions.OFFICE_DAY`) seen by a robot with the
#: simulator's perfect perception and the same heading at both visits (the world calibrated to
#: Table II only). ``"alike"``: the original generator and settings, with the library's default
#: extractor (for comparison with earlier runs). ``"offices"`` names the office generator
#: (:data:`fingerloc.sim.WORLDS`); ``"calibrated_on"`` the paper's tables the world was fit to
#: (``"table2"``, ``"table3"``): nothing was fit to Table IV.
def _profiles() -> dict[str, dict[str, Any]]:
    from ..sim.perception import PAPER_ROBOT
    from ..sim.sessions import OFFICE_DAY, PAPER_VISIT

    paper: dict[str, Any] = {
        "offices": "paper",
        "similarity": 0.8,
        "blur": 1.5,
        "noise": 0.025,
        "jpeg_quality": 75,
        "extractor": {"min_extent": 0.35, "min_support": 0.5, "min_contrast": 0.15},
    }
    return {
        "paper": {
            **paper,
            "session": PAPER_VISIT.to_dict(),
            "perception": PAPER_ROBOT.to_dict(),
            "calibrated_on": ["table2", "table3"],
        },
        "paper-static": {**paper, "session": None, "perception": PAPER_ROBOT.to_dict(), "calibrated_on": ["table2"]},
        "paper-ideal": {**paper, "session": OFFICE_DAY.to_dict(), "perception": None, "calibrated_on": ["table2"]},
        "alike": {
            "offices": "alike",
            "similarity": 0.5,
            "blur": 0.7,
            "noise": 0.015,
            "jpeg_quality": 85,
            "extractor": {},
            "session": None,
            "perception": None,
            "calibrated_on": [],
        },
    }


WORLD_PROFILES: dict[str, dict[str, Any]] = _profiles()


@dataclass(frozen=True, slots=True)
class RobotProtocol:
    """Settings of the simulated robot experiment (defaults: the paper's protocol).

    Parameters
    ----------
    n_offices : int, default 10
    n_train, n_test : int, default 8 and 2
        Training and test measurements per office.
    train_radius_m : (float, float), default (0.4, 0.7)
        Range of the training circle's radius, metres.
    test_radius_m : float, default 0.4
        Test measurements lie within this distance of the measurement point, metres.
    heading_jitter_deg : float, default 2
        Standard deviation of the heading error of a "same heading" pose, degrees.
    min_clearance_m : float, default 0.3
        Least distance from a pose to an obstacle, metres (closer poses are redrawn).
    similarity : float or None
        How alike the offices are (:func:`fingerloc.sim.make_offices`); None:
        the world's (:data:`WORLD_PROFILES`: 0.8 for ``"paper"``, 0.5 for ``"alike"``).
    n_beams : int, default 720
        Laser beams over 360 deg.
    omni_size : (int, int), default (640, 480)
        Size of the raw omnidirectional image, pixels.
    panorama_width : int, default 720
        Columns of the unwarped panorama (0.5 deg each).
    jpeg_quality : int or None, optional
        JPEG round trip of the camera image; default the world's sensor
        profile (:data:`WORLD_PROFILES`: 75 for ``"paper"``, 85 for ``"alike"``).
    world : {"paper", "paper-static", "paper-ideal", "alike"}, default "paper"
        The office generator (:data:`fingerloc.sim.WORLDS`), the matching
        sensor profile, the robot's perception errors and what changes
        between the training and the test visit (:data:`WORLD_PROFILES`).
        ``"paper"`` is calibrated to the paper's Tables II and III, its test
        measurements taken at a later visit (chairs moved, doors, people,
        daylight, the robot's heading); ``"paper-static"`` the same with
        nothing changed between visits; ``"paper-ideal"`` the ``"paper"``
        world seen with the simulator's perfect perception and the same
        heading at both visits; ``"alike"`` is the original generator.
    ks : tuple of int, default (3, 4, 5)
        Mixture components to evaluate.
    random_heading : bool, default True
        Also run the random-heading row.
    """

    n_offices: int = 10
    n_train: int = 8
    n_test: int = 2
    train_radius_m: tuple[float, float] = (0.4, 0.7)
    test_radius_m: float = 0.4
    heading_jitter_deg: float = 2.0
    min_clearance_m: float = 0.3
    similarity: float | None = None
    n_beams: int = 720
    omni_size: tuple[int, int] = (640, 480)
    panorama_width: int = 720
    jpeg_quality: int | None = None
    ks: tuple[int, ...] = PAPER_K
    random_heading: bool = True
    world: str = "paper"

    @property
    def offices(self) -> str:
        """The office generator of the world (:data:`fingerloc.sim.WORLDS`)."""
        return str(WORLD_PROFILES[self.world].get("offices", self.world))

    @property
    def session_change(self) -> Any:
        """What changes between the training and the test visit (a :class:`~fingerloc.sim.sessions.SessionChange`), or None."""
        from ..sim.sessions import SessionChange

        d = WORLD_PROFILES[self.world].get("session")
        return None if d is None else SessionChange(**d)

    @property
    def perception(self) -> Any:
        """The robot's perception errors (a :class:`~fingerloc.sim.perception.PerceptionNoise`), or None."""
        from ..sim.perception import PerceptionNoise

        d = WORLD_PROFILES[self.world].get("perception")
        return None if d is None else PerceptionNoise(**d)

    @property
    def office_similarity(self) -> float:
        """The similarity of the offices used: ``similarity``, else the world's (:data:`WORLD_PROFILES`)."""
        return float(WORLD_PROFILES[self.world]["similarity"] if self.similarity is None else self.similarity)

    def __post_init__(self) -> None:
        for name in ("n_offices", "n_train", "n_test"):
            v = getattr(self, name)
            low = 2 if name == "n_offices" else 1
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise InvalidParameterError(f"{name} must be an integer >= {low}, got {v!r}")
        lo, hi = (float(v) for v in self.train_radius_m)
        if not (0 <= lo <= hi and math.isfinite(hi)):
            raise InvalidParameterError(f"train_radius_m must satisfy 0 <= low <= high, got {self.train_radius_m!r}")
        if not (math.isfinite(self.test_radius_m) and self.test_radius_m >= 0):
            raise InvalidParameterError(f"test_radius_m must be >= 0 metres, got {self.test_radius_m!r}")
        if not (math.isfinite(self.heading_jitter_deg) and self.heading_jitter_deg >= 0):
            raise InvalidParameterError(f"heading_jitter_deg must be >= 0, got {self.heading_jitter_deg!r}")
        if self.world not in WORLD_PROFILES:
            raise InvalidParameterError(f"world must be one of {', '.join(WORLD_PROFILES)}, got {self.world!r}")
        if not self.ks or any(isinstance(k, bool) or not isinstance(k, int) or k < 1 for k in self.ks):
            raise InvalidParameterError(f"ks must be positive integers, got {self.ks!r}")


@dataclass(frozen=True, slots=True, eq=False)
class Measurement:
    """One simulated measurement: where it was taken and what the extractors found.

    Attributes
    ----------
    office : int
        Office index.
    role : {"train", "test", "test-random-heading"}
    pose : (x, y, theta)
        True pose, metres and radians (world frame).
    observation : Observation
        Features extracted from the raw data, changed by the robot's perception errors
        (:attr:`RobotProtocol.perception`), labelled with the office's name.
    scan, panorama, omni : optional
        The raw data (:class:`~fingerloc.sensors.Scan`, the unwarped
        :class:`~fingerloc.sensors.Panorama`, the :class:`~fingerloc.sim.OmniImage`),
        kept only when asked (``keep_raw``).
    extracted : Observation, optional
        What the extractors found on the raw data, before the robot's perception errors
        (``observation`` is after them); kept with the raw data.
    """

    office: int
    role: str
    pose: tuple[float, float, float]
    observation: Observation
    scan: Any = None
    panorama: Any = None
    omni: Any = None
    extracted: Any = None


def _free(world: Any, xy: tuple[float, float], clearance: float) -> bool:
    p = np.array([xy], dtype=np.float64)
    return bool(world.contains(p)[0]) and float(world.clearance(p)[0]) >= clearance


def measurement_poses(
    world: Any, protocol: RobotProtocol, rng: np.random.Generator
) -> tuple[list[tuple[float, float, float]], list[tuple[float, float, float]]]:
    """Training and test poses of one office (see the module docstring).

    Returns
    -------
    train, test : list of (x, y, theta)
        Metres and radians, world frame.
    """
    ax, ay = world.anchor
    jitter = math.radians(protocol.heading_jitter_deg)
    lo, hi = protocol.train_radius_m
    turn = float(rng.uniform(0, 2 * math.pi))

    def draw(angle: float | None, r_lo: float, r_hi: float) -> tuple[float, float, float]:
        for attempt in range(200):
            a = float(rng.uniform(0, 2 * math.pi)) if angle is None or attempt >= 20 else angle
            # uniform over the area of the annulus r_lo..r_hi
            r = math.sqrt(float(rng.uniform(r_lo**2, r_hi**2)))
            xy = (ax + r * math.cos(a), ay + r * math.sin(a))
            if _free(world, xy, protocol.min_clearance_m):
                return (xy[0], xy[1], float(rng.normal(0.0, jitter)) if jitter > 0 else 0.0)
        return (ax, ay, 0.0)  # the anchor itself is free by construction

    n = protocol.n_train
    train = [draw(turn + 2 * math.pi * i / n, lo, hi) for i in range(n)]
    test = [draw(None, 0.0, protocol.test_radius_m) for _ in range(protocol.n_test)]
    return train, test


def _measure(
    world: Any,
    pose: tuple[float, float, float],
    protocol: RobotProtocol,
    rng: np.random.Generator,
) -> tuple[Observation, Any, Any, Any]:
    """Simulate the raw sensors at ``pose`` and extract the features."""
    from .. import sim
    from ..features.vision import observation_from_views, unwarp_omni

    profile = WORLD_PROFILES[protocol.world]
    jpeg = profile["jpeg_quality"] if protocol.jpeg_quality is None else protocol.jpeg_quality
    scan = sim.simulate_scan(world, pose, n_beams=protocol.n_beams, random_state=rng)
    scale = protocol.omni_size[0] / 640.0  # the simulator's default mirror ring, scaled to the image
    im = sim.render_omni(
        world,
        pose,
        size=protocol.omni_size,
        radii=(60.0 * scale, 230.0 * scale),
        jpeg_quality=jpeg,
        blur=profile["blur"],
        noise=profile["noise"],
        random_state=rng,
    )
    # OmniImage: bearing = forward - phi (clockwise) or phi - forward (counter-clockwise)
    offset = im.forward_angle if im.clockwise else -im.forward_angle
    pano = unwarp_omni(
        im.image,
        im.center,
        im.radii[0],
        im.radii[1],
        bearing_offset=offset,
        mirror=im.clockwise,
        width=protocol.panorama_width,
    )
    obs = observation_from_views(scan=scan, panorama=pano, label=world.name, **profile["extractor"])
    return obs, scan, pano, im


def simulate_office(
    world: Any,
    office: int,
    protocol: RobotProtocol,
    seed: int | Sequence[int],
    keep_raw: bool = False,
    test_world: Any = None,
    heading_offset: float = 0.0,
) -> list[Measurement]:
    """Every measurement of one office: training, test and (optionally) random-heading test.

    The features of each measurement are those the extractors find on the simulated raw data,
    then changed by the robot's perception errors (``protocol.perception``, drawn from a stream
    of their own: the poses and raw data do not depend on them).

    Parameters
    ----------
    world : fingerloc.sim.World
        The office at the training visit (the poses are drawn in it).
    office : int
        Index stored in each :class:`Measurement`.
    protocol : RobotProtocol
    seed : int or sequence of int
        Seed of the poses and the sensor noise.
    keep_raw : bool
        Keep the scan, panorama and donut image of every measurement.
    test_world : fingerloc.sim.World, optional
        The office at the test visit (:func:`fingerloc.sim.sessions.make_office_sessions`),
        where the test and random-heading measurements are taken; default ``world``.
    heading_offset : float, default 0
        The robot's heading at the test visit relative to the training visit, radians: added
        to the heading of every test pose (not to the random-heading ones).
    """
    from ..sim.perception import perceive

    rng = np.random.default_rng(seed)
    later = world if test_world is None else test_world
    train, test = measurement_poses(world, protocol, rng)
    test = [(x, y, th + float(heading_offset)) for x, y, th in test]
    jobs = [("train", p) for p in train] + [("test", p) for p in test]
    if protocol.random_heading:
        # headings from their own stream, so that the training and test measurements (Tables II-IV)
        # are the same with and without the random-heading rows
        turn = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        jobs += [("test-random-heading", (x, y, float(turn.uniform(-math.pi, math.pi)))) for x, y, _ in test]
    perception = protocol.perception
    # the perception errors from a stream of their own (child 0 turns the random headings)
    errors = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[1])
    out = []
    for role, pose in jobs:
        found, scan, pano, im = _measure(world if role == "train" else later, pose, protocol, rng)
        obs = found if perception is None else perceive(found, perception, errors)
        if keep_raw:
            out.append(Measurement(office, role, pose, obs, scan, pano, im, found))
        else:
            out.append(Measurement(office, role, pose, obs))
    return out


def _simulate_office_job(
    args: tuple[Any, int, RobotProtocol, tuple[int, ...], bool, Any, float],
) -> list[Measurement]:
    return simulate_office(*args)


@dataclass(slots=True)
class TrialData:
    """One trial's simulated data (and what the demo draws).

    ``worlds``: the offices at the training visit; ``test_worlds``: at the test visit (the
    same objects when nothing changes between visits; empty in data made before visits were
    modelled, meaning the same).
    """

    worlds: list[Any]
    measurements: list[Measurement]
    test_worlds: list[Any] = field(default_factory=list)

    def observations(self, role: str) -> list[Observation]:
        """Observations of the measurements with this role, in office order."""
        return [m.observation for m in self.measurements if m.role == role]


def simulate_trial(
    protocol: RobotProtocol,
    seed: int | Sequence[int],
    *,
    keep_raw: bool | Sequence[int] = False,
    executor: Executor | None = None,
) -> TrialData:
    """Generate the offices of one trial and simulate every measurement.

    Parameters
    ----------
    protocol : RobotProtocol
    seed : int or sequence of int
        Seed of the offices, poses and sensor noise.
    keep_raw : bool or sequence of int
        Keep the raw sensor data of every measurement (True) or of the
        measurements of these offices.
    executor : concurrent.futures.Executor, optional
        Simulate the offices in parallel on it (results are identical).
    """
    from .. import sim
    from ..sim.sessions import make_office_sessions

    ss = np.random.SeedSequence(seed)
    office_seq, *meas_seqs = ss.spawn(protocol.n_offices + 1)
    # The changes between visits draw from a child of their own (the next one spawned), so that the
    # offices, poses and sensor noise are those of the same seed without the changes.
    (visit_seq,) = ss.spawn(1)
    # the robot's heading at the test visit: one offset per office, from the child after that
    (heading_seq,) = ss.spawn(1)
    kwargs: dict[str, Any] = {"random_state": np.random.default_rng(office_seq), "world": protocol.offices}
    kwargs["similarity"] = protocol.office_similarity
    change = protocol.session_change
    if change is None:
        worlds = sim.make_offices(protocol.n_offices, **kwargs)
        later = list(worlds)
    else:
        pairs = make_office_sessions(
            protocol.n_offices, change=change, change_random_state=np.random.default_rng(visit_seq), **kwargs
        )
        worlds, later = [a for a, _ in pairs], [b for _, b in pairs]
    sd = math.radians(change.heading_offset_deg) if change is not None else 0.0
    offsets = sd * np.random.default_rng(heading_seq).standard_normal(protocol.n_offices)
    keep = set(range(protocol.n_offices)) if keep_raw is True else set() if keep_raw is False else set(keep_raw)
    jobs = [
        (w, i, protocol, tuple(int(v) for v in meas_seqs[i].generate_state(4)), i in keep, later[i], float(offsets[i]))
        for i, w in enumerate(worlds)
    ]
    if executor is None:
        per_office = [_simulate_office_job(j) for j in jobs]
    else:
        per_office = list(executor.map(_simulate_office_job, jobs))
    return TrialData(worlds=worlds, measurements=[m for ms in per_office for m in ms], test_worlds=later)
