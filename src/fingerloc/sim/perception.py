"""What a real robot's perception gets wrong that the simulated raw sensors do not.

The simulator renders the raw laser scan and omnidirectional image, and the
feature extractors run on them; on these renders the extractors find the same
features at nearly the same bearings from one pose to the next (bearing
errors of 0.1-0.2 deg, ``fingerloc bench features``). A real robot's
extractors are less steady: a vertical edge washed out by glare or a monitor's
reflection, a corner lost in clutter, a beacon hidden by a cable, and features
that are not there at all (a reflection on glass, a chair leg, a passer-by's
edge). :class:`PerceptionNoise` adds these errors to the features the
extractors found, one measurement at a time:

1. **Missed features**: each feature found is kept with the detection
   probability of its sensor (``camera_detection`` for vertical edges and
   colour patches, ``laser_detection`` for corners, extremities and beacons).
2. **Bearing noise**: each kept feature's bearing moves by a Gaussian of
   ``camera_bearing_deg`` or ``laser_bearing_deg`` (degrees, standard deviation).
3. **Spurious features**: a Poisson number of false features of each type
   (``spurious``: mean count per measurement), at uniform bearings; a false
   colour patch has a uniform hue.

Walls, ranges and every other field of the observation are kept.

:data:`PAPER_ROBOT` holds the values calibrated on the paper's Table III
(string matching alone); its reasoning is given there and in docs/METHOD.md
(§5, "The simulated robot, calibrated").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..observation import Observation

__all__ = ["CAMERA_TYPES", "LASER_TYPES", "PAPER_ROBOT", "PerceptionNoise", "perceive"]

#: Feature types of the camera and of the laser (:class:`~fingerloc.observation.Observation` fields).
CAMERA_TYPES: tuple[str, ...] = ("ve", "cp")
LASER_TYPES: tuple[str, ...] = ("c", "ex", "b")
_TYPES = CAMERA_TYPES + LASER_TYPES


@dataclass(frozen=True, slots=True)
class PerceptionNoise:
    """Errors of a real robot's feature extractors, added to the features found on the simulated raw data.

    Parameters
    ----------
    camera_detection, laser_detection : float in [0, 1], default 1
        Probability that a feature the extractor found is kept: vertical
        edges and colour patches (camera); corners, extremities and beacons (laser).
    camera_bearing_deg, laser_bearing_deg : float, default 0
        Standard deviation of the extra Gaussian bearing error of a kept feature, degrees.
    spurious : mapping of str to float, optional
        Mean number of false features per measurement (Poisson), by
        :class:`~fingerloc.observation.Observation` field: ``"ve"``, ``"cp"``,
        ``"c"``, ``"ex"``, ``"b"``; missing types get none.
    """

    camera_detection: float = 1.0
    laser_detection: float = 1.0
    camera_bearing_deg: float = 0.0
    laser_bearing_deg: float = 0.0
    spurious: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("camera_detection", "laser_detection"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, int | float) and 0.0 <= float(v) <= 1.0):
                raise InvalidParameterError(f"{name} must be a probability in [0, 1], got {v!r}")
        for name in ("camera_bearing_deg", "laser_bearing_deg"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise InvalidParameterError(f"{name} must be >= 0 degrees, got {v!r}")
        spur = dict(self.spurious)
        for k, v in spur.items():
            if k not in _TYPES:
                raise InvalidParameterError(f"spurious: unknown feature type {k!r} (one of {', '.join(_TYPES)})")
            if isinstance(v, bool) or not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise InvalidParameterError(f"spurious[{k!r}] must be a mean count >= 0, got {v!r}")
        object.__setattr__(self, "spurious", {k: float(spur.get(k, 0.0)) for k in _TYPES})

    @property
    def is_null(self) -> bool:
        """True when nothing is changed (every feature kept where it was found, none added)."""
        return (
            self.camera_detection == 1.0
            and self.laser_detection == 1.0
            and self.camera_bearing_deg == 0.0
            and self.laser_bearing_deg == 0.0
            and not any(self.spurious.values())
        )

    def expected_count(self, kind: str, found: float) -> float:
        """Mean count of type ``kind`` after the errors, given ``found`` per measurement before them."""
        p = self.camera_detection if kind in CAMERA_TYPES else self.laser_detection
        return p * found + self.spurious.get(kind, 0.0)

    def to_dict(self) -> dict[str, Any]:
        """The settings as a JSON-ready dict."""
        return {
            "camera_detection": self.camera_detection,
            "laser_detection": self.laser_detection,
            "camera_bearing_deg": self.camera_bearing_deg,
            "laser_bearing_deg": self.laser_bearing_deg,
            "spurious": dict(self.spurious),
        }


#: The paper's robot, calibrated on its Table III together with the later visit's heading
#: (:data:`fingerloc.sim.sessions.PAPER_VISIT`): one feature in twenty lost per sensor, and as many
#: false ones as lost on average (5 % of the simulated robot's mean count of each type per
#: measurement: vertical edges 5.7, colour patches 2.6, corners 6.1, extremities 6.2, beacons 4.2),
#: so that Table II does not move; no extra bearing noise (the rendered sensors already give the
#: bearing errors of a 640x480 mirror camera and a 0.5 deg laser, and a real camera's mirror
#: calibration error is the same in every image, which matching does not see).
PAPER_ROBOT = PerceptionNoise(
    camera_detection=0.95,
    laser_detection=0.95,
    camera_bearing_deg=0.0,
    laser_bearing_deg=0.0,
    spurious={"ve": 0.28, "cp": 0.13, "c": 0.30, "ex": 0.31, "b": 0.21},
)


def perceive(obs: Observation, noise: PerceptionNoise, rng: np.random.Generator) -> Observation:
    """The observation ``obs`` as a robot with these perception errors reports it.

    Parameters
    ----------
    obs : Observation
        Features the extractors found (bearings in radians).
    noise : PerceptionNoise
    rng : numpy.random.Generator
        Draws, per type in the order ve, cp, c, ex, b: one uniform and one normal
        per feature found, then the spurious count and its bearings (and hues),
        whatever the settings, so that two settings see the same random numbers.

    Returns
    -------
    Observation
        A new observation; ``obs`` itself when ``noise`` changes nothing.
    """
    if noise.is_null:
        return obs
    out: dict[str, Any] = {}
    for kind in _TYPES:
        camera = kind in CAMERA_TYPES
        p = noise.camera_detection if camera else noise.laser_detection
        sd = math.radians(noise.camera_bearing_deg if camera else noise.laser_bearing_deg)
        a = np.asarray(getattr(obs, kind), dtype=np.float64)
        keep = rng.uniform(size=a.size) < p
        moved = a + sd * rng.standard_normal(a.size)
        n_false = int(rng.poisson(noise.spurious[kind]))
        false = rng.uniform(-math.pi, math.pi, size=n_false)
        out[kind] = np.concatenate([moved[keep], false])
        if kind == "cp":
            hue = np.asarray(obs.cp_hue, dtype=np.float64)
            out["cp_hue"] = np.concatenate([hue[keep], rng.uniform(0.0, 360.0, size=n_false)])
    return replace(obs, **out)
