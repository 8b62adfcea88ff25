"""The paper's robot experiment (Tables II-IV) in simulation (docs/METHOD.md §5).

Protocol (Tapus et al. 2004, section V-B, as restated in docs/METHOD.md §5), with the
robot replaced by :mod:`fingerloc.sim`:

* ten offices alike (:func:`fingerloc.sim.make_offices`), each with a
  measurement point (the office's ``anchor``). The default world, ``"paper"``,
  is calibrated so that the extractors find about as many features per
  measurement as the paper's Table II (see :data:`WORLD_PROFILES`: office
  chairs, fewer posters, more beacons, a softer camera image, an edge extractor
  that keeps only long edges, offices of one corridor at similarity 0.8), and
  its test measurements are taken at a later visit of the offices
  (:func:`fingerloc.sim.make_office_sessions`: chairs moved, doors closed,
  people in the room, other daylight); ``"paper-static"`` is the same world
  with nothing changed between the visits; ``"alike"`` is the original
  generator, far richer in edges;
* per office, eight **training** measurements on a circle around that point,
  radius drawn in ``train_radius_m`` (40-70 cm), at eight evenly spaced angles
  (the whole ring turned by a random angle), and two **test** measurements
  inside the circle (radius below ``test_radius_m``, 40 cm);
* the same heading throughout (the world's x axis), up to a small Gaussian
  error ``heading_jitter_deg`` as a real robot would have; a pose closer than
  ``min_clearance_m`` to an obstacle is redrawn;
* at every pose the simulator produces the **raw** sensor data: a 360 deg scan
  of two 180 deg heads (ranges, intensities) and the donut image of the
  omnidirectional camera (equiangular mirror, lighting changes, sun patches,
  pixel noise, JPEG). The feature extractors of :mod:`fingerloc.features` run
  on these alone: laser corners ``c``, extremities ``Ex`` and beacons ``B``;
  the donut is unwarped with :func:`~fingerloc.features.vision.unwarp_omni`
  from its mirror geometry, then vertical edges ``VE`` and colour patches
  ``CP``. The simulator's ground truth is never used.

What is measured, per trial (new offices, poses and noise each trial):

* **Table II**: mean number of features of each type per measurement.
* **Table III**: string matching alone. Each test fingerprint is compared
  with the 80 training fingerprints; a place scores the least cost over its
  eight; the place of least cost wins. Minimum energy
  (:func:`~fingerloc.align.minimum_energy_costs`, Lamon et al. 2001) against
  global alignment (:func:`~fingerloc.align.alignment_costs`).
* **Table IV**: the Bayesian program (:class:`~fingerloc.model.PlaceModel`,
  ``fp_likelihood="paper"``) with the terms VE, Ex, VE & Ex and VE & Ex & Fp,
  for k = 3, 4, 5 mixture components. One model with every term is fit per
  k; a term set's posterior is the sum of its terms' log-likelihoods (each
  term's mixtures do not depend on the other terms, so this equals fitting
  one model per term set).
* **Random heading** (beyond the paper, docs/METHOD.md §6): the two test
  measurements of each office are taken again at the same positions with a
  uniformly random heading. String matching uses the cyclic alignment (every
  rotation); the full program first estimates, for each place, the heading
  from the best cyclic alignment against that place's training fingerprints
  (:meth:`~fingerloc.model.PlaceModel.headings`), turns the observation back
  by it, then scores the mixture terms; ``Fp`` is the cyclic cost.

Right classification is the share of test measurements whose true place
ranks first; the rank of the true place counts ties against (two places tied
for first both get rank 2). Each figure is the mean over trials; the spread is
the standard deviation over trials, and every cell has a 95 % confidence
interval: Student t over the trials' figures with two trials or more, or, for
one trial (the demo), a Wilson interval of the share over its test queries and
a Student t interval of the mean rank over them.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._types import FArray
from ..errors import InvalidParameterError
from ..metrics import min_per_place, true_place_ranks
from ..metrics import true_place_ranks as rank_of_truth
from ..observation import Observation

__all__ = [
    "CI_LEVEL",
    "PAPER_K",
    "PAPER_TABLE2",
    "PAPER_TABLE3",
    "PAPER_TABLE4",
    "TABLE4_FITTED",
    "TABLE4_NAMES",
    "TABLE4_TERMS",
    "WORLD_PROFILES",
    "Measurement",
    "RobotProtocol",
    "RobotResult",
    "TrialData",
    "default_workers",
    "evaluate_trial",
    "measurement_poses",
    "rank_of_truth",
    "run_robot",
    "simulate_office",
    "simulate_trial",
    "simulation_pool",
    "small_protocol",
    "t_interval",
    "wilson_interval",
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
#: Display names of the Table IV rows (ours and the paper's), in print order.
TABLE4_NAMES: dict[str, str] = {
    "VE": "VE only",
    "Ex": "Ex only",
    "VE+Ex": "VE & Ex",
    "VE+Ex+Fp": "VE, Ex & fingerprint",
    TABLE4_FITTED: "VE, Ex & fingerprint, term weights fit (not in the paper)",
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
#: (``RobotProtocol.world``). ``"paper"``: calibrated to the paper's Table II (docs/RESULTS.md,
#: "Robot experiment, calibrated to Table II"): offices of one institute corridor (similarity
#: 0.8: same room grid and furniture), a softer, noisier camera image (the paper's 640x480
#: mirror camera: defocus 1.5 px, pixel noise 2.5 %, JPEG 75) and a vertical-edge extractor
#: that keeps only long, strong edges (a run over 35 % of the elevation range or edge pixels
#: over half of it, a step of 0.15 in log luminance); the test measurements are taken at a later
#: visit of the offices (``"session"``: :class:`fingerloc.sim.sessions.SessionChange` settings,
#: :data:`~fingerloc.sim.sessions.OFFICE_DAY`: chairs moved, a door closed, people in the room,
#: other daylight). ``"paper-static"``: the same offices and sensors with nothing changed between
#: the training and the test measurements (the ``"paper"`` world before the visits were
#: modelled). ``"alike"``: the original generator and settings, with the library's default
#: extractor (for comparison with earlier runs). ``"offices"`` names the office generator
#: (:data:`fingerloc.sim.WORLDS`).
def _profiles() -> dict[str, dict[str, Any]]:
    from ..sim.sessions import OFFICE_DAY

    paper: dict[str, Any] = {
        "offices": "paper",
        "similarity": 0.8,
        "blur": 1.5,
        "noise": 0.025,
        "jpeg_quality": 75,
        "extractor": {"min_extent": 0.35, "min_support": 0.5, "min_contrast": 0.15},
    }
    return {
        "paper": {**paper, "session": OFFICE_DAY.to_dict()},
        "paper-static": {**paper, "session": None},
        "alike": {
            "offices": "alike",
            "similarity": 0.5,
            "blur": 0.7,
            "noise": 0.015,
            "jpeg_quality": 85,
            "extractor": {},
            "session": None,
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
    world : {"paper", "paper-static", "alike"}, default "paper"
        The office generator (:data:`fingerloc.sim.WORLDS`), the matching
        sensor profile and what changes between the training and the test
        visit (:data:`WORLD_PROFILES`). ``"paper"`` is calibrated to the
        paper's Table II, its test measurements taken at a later visit
        (chairs moved, doors, people, daylight); ``"paper-static"`` the same
        with nothing changed between visits; ``"alike"`` is the original
        generator.
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
        Features extracted from the raw data, labelled with the office's name.
    scan, panorama, omni : optional
        The raw data (:class:`~fingerloc.sensors.Scan`, the unwarped
        :class:`~fingerloc.sensors.Panorama`, the :class:`~fingerloc.sim.OmniImage`),
        kept only when asked (``keep_raw``).
    """

    office: int
    role: str
    pose: tuple[float, float, float]
    observation: Observation
    scan: Any = None
    panorama: Any = None
    omni: Any = None


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
) -> list[Measurement]:
    """Every measurement of one office: training, test and (optionally) random-heading test.

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
    """
    rng = np.random.default_rng(seed)
    later = world if test_world is None else test_world
    train, test = measurement_poses(world, protocol, rng)
    jobs = [("train", p) for p in train] + [("test", p) for p in test]
    if protocol.random_heading:
        # headings from their own stream, so that the training and test measurements (Tables II-IV)
        # are the same with and without the random-heading rows
        turn = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        jobs += [("test-random-heading", (x, y, float(turn.uniform(-math.pi, math.pi)))) for x, y, _ in test]
    out = []
    for role, pose in jobs:
        obs, scan, pano, im = _measure(world if role == "train" else later, pose, protocol, rng)
        if keep_raw:
            out.append(Measurement(office, role, pose, obs, scan, pano, im))
        else:
            out.append(Measurement(office, role, pose, obs))
    return out


def _simulate_office_job(args: tuple[Any, int, RobotProtocol, tuple[int, ...], bool, Any]) -> list[Measurement]:
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
    keep = set(range(protocol.n_offices)) if keep_raw is True else set() if keep_raw is False else set(keep_raw)
    jobs = [
        (w, i, protocol, tuple(int(v) for v in meas_seqs[i].generate_state(4)), i in keep, later[i])
        for i, w in enumerate(worlds)
    ]
    if executor is None:
        per_office = [_simulate_office_job(j) for j in jobs]
    else:
        per_office = list(executor.map(_simulate_office_job, jobs))
    return TrialData(worlds=worlds, measurements=[m for ms in per_office for m in ms], test_worlds=later)


# ---------------------------------------------------------------------------- evaluation


def _cell(ranks: NDArray[np.int64]) -> tuple[float, float]:
    return float(np.mean(ranks == 1)), float(np.mean(ranks))


#: Two-sided coverage of the confidence intervals.
CI_LEVEL = 0.95


def t_interval(values: ArrayLike, level: float = CI_LEVEL) -> tuple[float, float] | None:
    """Student-t confidence interval of the mean of ``values`` (None for fewer than two values).

    Parameters
    ----------
    values : array_like, shape (n,)
        Independent measurements (one per trial, or one per query).
    level : float
        Coverage, e.g. 0.95.

    Returns
    -------
    (low, high) or None
        ``mean -+ t_{(1 + level) / 2, n - 1} s / sqrt(n)``, ``s`` the sample standard deviation.
    """
    from scipy.stats import t as student_t

    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.size < 2:
        return None
    m = float(v.mean())
    h = float(student_t.ppf(0.5 + level / 2, v.size - 1)) * float(v.std(ddof=1)) / math.sqrt(v.size)
    return (m - h, m + h)


def wilson_interval(successes: int, n: int, level: float = CI_LEVEL) -> tuple[float, float] | None:
    """Wilson score interval of a proportion ``successes / n`` (None for ``n == 0``).

    ``(p + z^2/2n -+ z sqrt(p (1 - p) / n + z^2 / 4n^2)) / (1 + z^2 / n)`` with ``z`` the
    normal quantile of ``(1 + level) / 2``; unlike the normal approximation it stays inside
    [0, 1] and is not empty at 0 % or 100 %.
    """
    from scipy.stats import norm

    if n <= 0:
        return None
    z = float(norm.ppf(0.5 + level / 2))
    p = successes / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


@dataclass(slots=True)
class TrialEvaluation:
    """Figures of one trial, plus what the demo shows.

    Attributes
    ----------
    features : dict
        Feature type -> mean count per measurement (Table II).
    cells : dict
        Path tuple (e.g. ``("table4", "VE+Ex+Fp", "5")``) -> (top1 in [0, 1], mean rank).
    classes : list of str
        Place names, columns of ``posterior``.
    truth : ndarray of int, shape (n_test,)
        True place of each test measurement.
    posterior : ndarray, shape (n_test, P)
        Full program's posterior (largest k) on the test measurements.
    heading_error_deg : ndarray
        Absolute heading error of the random-heading test measurements (true place), degrees.
    model, models : PlaceModel, dict
        The full program (terms VE, Ex, Fp) fit with the largest k, and with each k
        (k -> model); dropped by :func:`run_robot` to keep results small.
    ranks : dict
        Path -> rank of the true place for each test query, shape (n_test,) (what ``cells`` averages).
    counts : dict
        Feature type -> count per measurement, shape (n_measurements,) (what ``features`` averages).
    features_by_visit : dict
        ``"train"`` / ``"test"`` -> feature type -> mean count per measurement of that visit.
    """

    features: dict[str, float]
    cells: dict[tuple[str, ...], tuple[float, float]]
    ranks: dict[tuple[str, ...], NDArray[np.int64]] = field(default_factory=dict)
    counts: dict[str, NDArray[np.int64]] = field(default_factory=dict)
    classes: list[str] = field(default_factory=list)
    truth: NDArray[np.int64] = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    posterior: FArray = field(default_factory=lambda: np.empty((0, 0)))
    heading_error_deg: FArray = field(default_factory=lambda: np.empty(0))
    model: Any = None
    models: dict[int, Any] = field(default_factory=dict)
    features_by_visit: dict[str, dict[str, float]] = field(default_factory=dict)


def evaluate_trial(data: TrialData, protocol: RobotProtocol, *, random_state: int = 0) -> TrialEvaluation:
    """Tables II-IV (and the random-heading row) of one simulated trial.

    Parameters
    ----------
    data : TrialData
    protocol : RobotProtocol
    random_state : int
        Seed of the mixtures' initialisation.
    """
    from ..align import alignment_costs, minimum_energy_costs
    from ..fingerprint import make_fingerprint
    from ..model import PlaceModel

    all_obs = [m.observation for m in data.measurements if m.role in ("train", "test")]
    counts = {t: np.array([o.bearings(t).size for o in all_obs], dtype=np.int64) for t in TABLE2_TYPES}
    features = {t: float(np.mean(c)) for t, c in counts.items()}
    by_visit = {
        role: {t: float(np.mean([o.bearings(t).size for o in data.observations(role)])) for t in TABLE2_TYPES}
        for role in ("train", "test")
    }
    train = data.observations("train")
    test = data.observations("test")
    classes = [w.name for w in data.worlds]
    col = {c: j for j, c in enumerate(classes)}
    owner = np.array([col[str(o.label)] for o in train], dtype=np.int64)
    truth = np.array([col[str(o.label)] for o in test], dtype=np.int64)
    cells: dict[tuple[str, ...], tuple[float, float]] = {}
    ranks: dict[tuple[str, ...], NDArray[np.int64]] = {}

    def record(key: tuple[str, ...], scores: Any, true_cols: NDArray[np.int64]) -> None:
        r = true_place_ranks(scores, true_cols)
        ranks[key] = r
        cells[key] = _cell(r)

    # Table III: string matching alone, nearest place by least cost
    train_fp = [make_fingerprint(o) for o in train]
    test_fp = [make_fingerprint(o) for o in test]
    me = min_per_place(minimum_energy_costs(test_fp, train_fp), owner, len(classes))
    ga = min_per_place(alignment_costs(test_fp, train_fp), owner, len(classes))
    record(("table3", "minimum_energy"), -me, truth)
    record(("table3", "global_alignment"), -ga, truth)

    # Table IV: the Bayesian program, one model per k, term sets by summing terms
    posterior = np.empty((0, 0))
    model: Any = None
    models: dict[int, Any] = {}
    for k in protocol.ks:
        model = PlaceModel(k, terms=("VE", "Ex", "Fp"), random_state=random_state).fit(train)
        models[k] = model
        if list(model.classes_) != classes:
            raise RuntimeError("PlaceModel changed the order of the places")  # pragma: no cover
        ll = model.term_log_likelihoods(test)
        for row, terms in TABLE4_TERMS.items():
            joint = sum(ll[t] for t in terms)
            record(("table4", row, str(k)), joint, truth)
        posterior = model.predict_proba(test)
        fitted = PlaceModel(k, terms=("VE", "Ex", "Fp"), weights="fit", random_state=random_state).fit(train)
        record(("table4", TABLE4_FITTED, str(k)), fitted.predict_log_proba(test), truth)

    # Random heading: cyclic matching, per-place heading estimate for the mixture terms
    heading_err = np.empty(0)
    if protocol.random_heading:
        rtest = data.observations("test-random-heading")
        rtruth = np.array([col[str(o.label)] for o in rtest], dtype=np.int64)
        rfp = [make_fingerprint(o) for o in rtest]
        gc = min_per_place(alignment_costs(rfp, train_fp, cyclic=True), owner, len(classes))
        record(("random_heading", "global_alignment"), -gc, rtruth)
        poses = [m.pose for m in data.measurements if m.role == "test-random-heading"]
        for k in protocol.ks:
            cm = PlaceModel(k, terms=("VE", "Ex", "Fp"), cyclic=True, random_state=random_state).fit(train)
            fp_ll = cm.term_log_likelihoods(rtest)["Fp"]
            # The mixtures alone (the same fit as cm's: one batch over the same places and terms), for the
            # observations turned back by each place's heading: one call for all places, no Fp recomputed.
            mixtures = PlaceModel(k, terms=("VE", "Ex"), random_state=random_state).fit(train)
            mog = np.zeros_like(fp_ll)
            head = np.full((len(rtest), len(classes)), np.nan)
            turned: list[Observation] = []
            for j, name in enumerate(classes):
                h = cm.headings(rtest, [name] * len(rtest))
                head[:, j] = h
                turned += [o.rotated(-math.radians(v)) if np.isfinite(v) else o for o, v in zip(rtest, h, strict=True)]
            ll = mixtures.term_log_likelihoods(turned)
            n_r = len(rtest)
            for j in range(len(classes)):
                rows = slice(j * n_r, (j + 1) * n_r)
                mog[:, j] = ll["VE"][rows, j] + ll["Ex"][rows, j]
            record(("random_heading", "VE+Ex+Fp", str(k)), mog + fp_ll, rtruth)
            if k == protocol.ks[-1]:
                # the robot's heading relative to the training heading (about 0): heading_deg = -theta... see below
                est = head[np.arange(len(rtest)), rtruth]
                true_turn = np.array([p[2] for p in poses])
                # query bearings = stored bearings - theta, so the estimate should be -theta (mod 360)
                err = np.rad2deg(np.abs(np.angle(np.exp(1j * (np.deg2rad(est) + true_turn)))))
                heading_err = err
    return TrialEvaluation(
        features=features,
        features_by_visit=by_visit,
        cells=cells,
        ranks=ranks,
        counts=counts,
        classes=classes,
        truth=truth,
        posterior=posterior,
        heading_error_deg=heading_err,
        model=model,
        models=models,
    )


# ---------------------------------------------------------------------------- many trials


@contextmanager
def simulation_pool(workers: int) -> Iterator[Executor | None]:
    """A process pool of ``workers`` processes for :func:`simulate_trial` (None for one: run in place)."""
    if workers <= 1:
        yield None
        return
    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as ex:
        yield ex


def default_workers() -> int:
    """Processes used to simulate: the usable cores, at most 4."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        n = os.cpu_count() or 1
    return max(1, min(n, 4))


@dataclass(slots=True)
class RobotResult:
    """Figures of every trial, and their means and spreads.

    Attributes
    ----------
    protocol : RobotProtocol
    seed : int
    trials : list of TrialEvaluation
    """

    protocol: RobotProtocol
    seed: int
    trials: list[TrialEvaluation]

    def feature_stats(self) -> dict[str, tuple[float, float]]:
        """Feature type -> (mean, standard deviation over trials) of the count per measurement."""
        out = {}
        for t in TABLE2_TYPES:
            v = np.array([tr.features[t] for tr in self.trials])
            out[t] = (float(v.mean()), _std(v))
        return out

    def feature_stats_by_visit(self) -> dict[str, dict[str, float]]:
        """``"train"`` / ``"test"`` -> feature type -> mean count per measurement over trials (Table II per visit)."""
        if not all(tr.features_by_visit for tr in self.trials):
            return {}
        return {
            role: {t: float(np.mean([tr.features_by_visit[role][t] for tr in self.trials])) for t in TABLE2_TYPES}
            for role in ("train", "test")
        }

    def cell_stats(self) -> dict[tuple[str, ...], tuple[float, float, float, float]]:
        """Path -> (top1 mean, top1 std, mean-rank mean, mean-rank std) over trials."""
        out = {}
        for key in self.trials[0].cells:
            v = np.array([tr.cells[key] for tr in self.trials])
            out[key] = (float(v[:, 0].mean()), _std(v[:, 0]), float(v[:, 1].mean()), _std(v[:, 1]))
        return out

    def ci_method(self) -> str:
        """How :meth:`feature_ci` and :meth:`cell_ci` are computed, in words."""
        if len(self.trials) >= 2:
            return f"{CI_LEVEL:.0%} Student-t interval of the mean over {len(self.trials)} trials"
        return (
            f"one trial: {CI_LEVEL:.0%} Wilson interval of the right-classification share over the test queries, "
            "Student-t interval of the mean rank over the queries and of the counts over the measurements"
        )

    def feature_ci(self) -> dict[str, tuple[float, float] | None]:
        """Feature type -> 95 % confidence interval of the mean count per measurement.

        Over trials (Student t on the per-trial means) with two or more trials; with one
        trial, over its measurements.
        """
        out: dict[str, tuple[float, float] | None] = {}
        for t in TABLE2_TYPES:
            if len(self.trials) >= 2:
                out[t] = t_interval([tr.features[t] for tr in self.trials])
            else:
                out[t] = t_interval(self.trials[0].counts.get(t, np.empty(0)))
        return out

    def cell_ci(self) -> dict[tuple[str, ...], tuple[tuple[float, float] | None, tuple[float, float] | None]]:
        """Path -> (95 % interval of the right-classification share, 95 % interval of the mean rank).

        Over trials (Student t on the per-trial figures) with two or more trials; with one
        trial, over its test queries (Wilson for the share, Student t for the rank).
        """
        out = {}
        for key in self.trials[0].cells:
            if len(self.trials) >= 2:
                v = np.array([tr.cells[key] for tr in self.trials])
                out[key] = (t_interval(v[:, 0]), t_interval(v[:, 1]))
            else:
                r = self.trials[0].ranks.get(key, np.empty(0, dtype=np.int64))
                out[key] = (wilson_interval(int((r == 1).sum()), int(r.size)), t_interval(r))
        # a share lies in [0, 1] and a rank in [1, places]: clip the t intervals to what can be
        n_places = max(len(self.trials[0].classes), 1)
        return {key: (_clip(a, 0.0, 1.0), _clip(r, 1.0, float(n_places))) for key, (a, r) in out.items()}

    def heading_error_deg(self) -> float | None:
        """Median absolute heading error of the random-heading measurements (true place), degrees."""
        errs = np.concatenate([tr.heading_error_deg for tr in self.trials]) if self.trials else np.empty(0)
        errs = errs[np.isfinite(errs)]
        return float(np.median(errs)) if errs.size else None

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``fingerloc reproduce robot --json`` (top1 in [0, 1]).

        ``table2`` counts every training and test measurement; ``table2_by_visit`` the
        training (``"train"``) and test (``"test"``) measurements apart, whose offices
        differ in the ``"paper"`` world (``protocol.sensor_profile.session``).
        """
        cells = self.cell_stats()
        main: dict[str, Any] = {}
        spread: dict[str, Any] = {}
        for key, (t1, t1s, mr, mrs) in cells.items():
            _put(main, key, {"top1": t1, "mean_rank": mr})
            _put(spread, key, {"top1": t1s, "mean_rank": mrs})
        fs = self.feature_stats()
        out: dict[str, Any] = {"table2": {t: m for t, (m, _) in fs.items()}}
        out["table3"] = main["table3"]
        out["table4"] = main["table4"]
        if "random_heading" in main:
            out["random_heading"] = main["random_heading"]
            out["random_heading"]["heading_error_deg"] = self.heading_error_deg()
        by_visit = self.feature_stats_by_visit()
        if by_visit:
            out["table2_by_visit"] = by_visit
        spread["table2"] = {t: s for t, (_, s) in fs.items()}
        out["spread"] = spread
        ci: dict[str, Any] = {"table2": {t: _pair(v) for t, v in self.feature_ci().items()}}
        for key, (a, r) in self.cell_ci().items():
            _put(ci, key, {"top1": _pair(a), "mean_rank": _pair(r)})
        out["ci95"] = ci
        out["paper"] = {
            "table2": dict(PAPER_TABLE2),
            "table3": {m: {"top1": a, "mean_rank": r} for m, (a, r) in PAPER_TABLE3.items()},
            "table4": {
                row: {str(k): {"top1": a, "mean_rank": r} for k, (a, r) in ks.items()}
                for row, ks in PAPER_TABLE4.items()
            },
        }
        p = self.protocol
        out["protocol"] = {
            "trials": len(self.trials),
            "seed": self.seed,
            "n_offices": p.n_offices,
            "n_train": p.n_train,
            "n_test": p.n_test,
            "train_radius_m": list(p.train_radius_m),
            "test_radius_m": p.test_radius_m,
            "heading_jitter_deg": p.heading_jitter_deg,
            "similarity": p.office_similarity,
            "n_beams": p.n_beams,
            "omni_size": list(p.omni_size),
            "panorama_width": p.panorama_width,
            "jpeg_quality": WORLD_PROFILES[p.world]["jpeg_quality"] if p.jpeg_quality is None else p.jpeg_quality,
            "world": p.world,
            "sensor_profile": WORLD_PROFILES[p.world],
            "ks": list(p.ks),
            "spread": "standard deviation over trials",
            "ci95": self.ci_method() + " (null where undefined)",
        }
        return out


def _std(v: FArray) -> float:
    return float(v.std(ddof=1)) if v.size > 1 else 0.0


def _clip(v: tuple[float, float] | None, lo: float, hi: float) -> tuple[float, float] | None:
    return None if v is None else (min(max(v[0], lo), hi), min(max(v[1], lo), hi))


def _pair(v: tuple[float, float] | None) -> list[float] | None:
    return None if v is None else [float(v[0]), float(v[1])]


def _put(d: dict[str, Any], key: tuple[str, ...], value: Any) -> None:
    for part in key[:-1]:
        d = d.setdefault(part, {})
    d[key[-1]] = value


def run_robot(
    *,
    trials: int = 10,
    seed: int = 0,
    protocol: RobotProtocol | None = None,
    workers: int | None = None,
    on_trial: Callable[[int], None] | None = None,
    scheduler: str | None = None,
) -> RobotResult:
    """Run the simulated robot experiment ``trials`` times (new offices each) and collect the figures.

    Parameters
    ----------
    trials : int, default 10
    seed : int, default 0
        Trial ``t`` uses the seed sequence ``(seed, t)``: results do not depend on ``workers``.
    protocol : RobotProtocol, optional
    workers : int, optional
        Processes. Default (None): a local process pool of :func:`default_workers`
        processes, each running whole trials. Given (two or more, with two or more
        trials): a Dask ``LocalCluster`` of that many processes, one task per trial
        (:func:`fingerloc.parallel.run_tasks`). With one trial the offices are
        simulated in parallel on a process pool. 1: in this process. The figures do
        not depend on it.
    on_trial : callable(done), optional
        Called after each trial.
    scheduler : str, optional
        Address of an existing Dask cluster (``tcp://host:8786``): one task per
        trial on it (not with ``workers``). The figures are those of the serial run.
    """
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise InvalidParameterError(f"trials must be a positive integer, got {trials!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise InvalidParameterError(f"seed must be an integer >= 0, got {seed!r}")
    p = protocol if protocol is not None else RobotProtocol()
    if scheduler is not None or (workers is not None and workers >= 2 and trials >= 2):
        from ..parallel import run_tasks

        # one Dask task per trial; each trial carries its seed sequence (seed, t)
        done = None if on_trial is None else on_trial
        results = run_tasks(_trial_job, [(p, seed, t) for t in range(trials)], workers=workers,
                            scheduler=scheduler, on_done=done)  # fmt: skip
        return RobotResult(protocol=p, seed=seed, trials=results)
    n_workers = default_workers() if workers is None else int(workers)
    results = []
    if n_workers >= 2 and trials >= 2:
        # Whole trials in parallel (simulate and evaluate in one process each): no process waits
        # for another, and each trial's figures are the same as when run alone.
        with simulation_pool(min(n_workers, trials)) as ex:
            assert ex is not None
            jobs = [(p, seed, t) for t in range(trials)]
            for t, ev in enumerate(ex.map(_trial_job, jobs)):
                results.append(ev)
                if on_trial is not None:
                    on_trial(t + 1)
        return RobotResult(protocol=p, seed=seed, trials=results)
    with simulation_pool(n_workers) as ex:
        for t in range(trials):
            results.append(_trial_job((p, seed, t), executor=ex))
            if on_trial is not None:
                on_trial(t + 1)
    return RobotResult(protocol=p, seed=seed, trials=results)


def _trial_job(args: tuple[RobotProtocol, int, int], executor: Executor | None = None) -> TrialEvaluation:
    """Simulate and evaluate trial ``t`` (seed sequence ``(seed, t)``); the model is dropped to keep results small."""
    p, seed, t = args
    data = simulate_trial(p, (seed, t), executor=executor)
    ev = evaluate_trial(data, p, random_state=seed * 1000 + t)
    ev.model = None
    ev.models = {}
    return ev


def small_protocol(**changes: Any) -> RobotProtocol:
    """A fast protocol for tests and smoke runs: fewer offices, small images."""
    base = RobotProtocol(n_offices=4, n_train=4, n_test=2, omni_size=(320, 240), panorama_width=360, ks=(3,))
    return replace(base, **changes)
