"""Odometry: increments between poses, dead reckoning, the filter's motion noise and a simulated wheel odometry.

Poses are ``(x, y, theta)`` in a fixed frame (metres, radians); an increment
``(dx, dy, dtheta)`` is the motion from one pose to the next in the robot
frame of the first (``dx`` forward, ``dy`` left).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from .._types import FArray
from ..angles import wrap
from ..errors import InvalidParameterError
from ..validation import check_random_state
from ._checks import finite as _finite

__all__ = [
    "MotionNoise",
    "OdometryError",
    "OdometrySimulator",
    "as_poses",
    "compose_increments",
    "corrupt_increments",
    "odometry_increments",
    "simulate_odometry",
    "wheel_odometry",
]


def as_poses(poses: Any) -> FArray:
    """``poses`` as a checked float array of shape (n, 3) (x m, y m, theta rad), finite."""
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InvalidParameterError(f"poses must have shape (n, 3) (x m, y m, theta rad), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InvalidParameterError("poses must be finite")
    return p


def odometry_increments(poses: Any) -> FArray:
    """Odometry increments between consecutive poses, in the robot frame of the earlier pose.

    Parameters
    ----------
    poses : array_like, shape (n, 3)
        ``x``, ``y`` (metres) and heading ``theta`` (radians), in any fixed frame.

    Returns
    -------
    ndarray, shape (max(n - 1, 0), 3)
        Row ``t``: ``dx`` (forward, m), ``dy`` (left, m), ``dtheta`` (rad, in
        ``[-pi, pi)``) from pose ``t`` to pose ``t + 1``.
        :func:`compose_increments` inverts it.
    """
    p = as_poses(poses)
    if p.shape[0] < 2:
        return np.zeros((0, 3))
    d = np.diff(p[:, :2], axis=0)
    c, s = np.cos(p[:-1, 2]), np.sin(p[:-1, 2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], wrap(np.diff(p[:, 2]))])


def compose_increments(start: Any, increments: Any) -> FArray:
    """Dead reckoning: the poses reached from ``start`` by ``increments``, shape (n + 1, 3)."""
    s = as_poses(np.asarray(start, dtype=np.float64).reshape(1, 3))[0]
    inc = np.asarray(increments, dtype=np.float64).reshape(-1, 3)
    out = np.empty((inc.shape[0] + 1, 3))
    out[0] = s
    for t, (dx, dy, dth) in enumerate(inc):
        x, y, th = out[t]
        out[t + 1] = (x + math.cos(th) * dx - math.sin(th) * dy, y + math.sin(th) * dx + math.cos(th) * dy,
                      float(wrap(th + dth)))  # fmt: skip
    return out


@dataclass(frozen=True, slots=True)
class MotionNoise:
    """The filter's motion model: one-sigma errors of an odometry increment.

    Per step, each particle moves by ``dx (1 + e1) + n1``, ``dy (1 + e2) + n2``
    (``e ~ N(0, translation)``, ``n ~ N(0, translation_floor + translation *
    distance)``) and turns by ``dtheta + N(0, rotation_floor +
    rotation_per_metre * distance + rotation * |dtheta|)``.

    Attributes
    ----------
    translation : float, default 0.05
        Relative error of the travelled distance.
    translation_floor : float, default 0.02
        Metres per step, even when standing still.
    rotation : float, default 0.1
        Relative error of a turn.
    rotation_per_metre : float, default 0.03
        Radians of heading error per metre travelled.
    rotation_floor : float, default 0.02
        Radians per step.
    """

    translation: float = 0.05
    translation_floor: float = 0.02
    rotation: float = 0.1
    rotation_per_metre: float = 0.03
    rotation_floor: float = 0.02

    def __post_init__(self) -> None:
        for name in ("translation", "translation_floor", "rotation", "rotation_per_metre", "rotation_floor"):
            _finite(name, getattr(self, name))


@dataclass(frozen=True, slots=True)
class OdometryError:
    """Errors of a simulated wheel odometry (:func:`simulate_odometry`), one sigma unless said.

    The defaults describe a plain differential-drive indoor robot: a 2 %
    systematic scale error of the distance, 5 % random error per step, 5 % of
    each turn, 0.01 rad per metre of random heading drift and a systematic
    heading drift of 0.005 rad (0.3 deg) per metre. They are the kind of error
    the filter's :class:`MotionNoise` is meant to cover.
    """

    scale: float = 0.02
    translation: float = 0.05
    rotation: float = 0.05
    drift_per_metre: float = 0.01
    bias_per_metre: float = 0.005

    def scaled(self, factor: float) -> OdometryError:
        """Every error times ``factor`` (>= 0; 0 = an exact odometry)."""
        f = _finite("factor", factor)
        return OdometryError(*(f * getattr(self, x.name) for x in fields(self)))

    def __post_init__(self) -> None:
        for name in ("translation", "rotation", "drift_per_metre"):
            _finite(name, getattr(self, name))
        for name in ("scale", "bias_per_metre"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v <= -1.0:
                raise InvalidParameterError(f"{name} must be a finite number > -1, got {v!r}")


def simulate_odometry(
    poses: Any, error: OdometryError | None = None, *, random_state: int | np.random.Generator | None = 0
) -> FArray:
    """Odometry increments of a trajectory with simulated wheel-odometry errors, shape (n - 1, 3).

    For logs whose only poses are corrected ones (the shared CARMEN logs: their
    ``ODOM`` lines are corrected too), the exact increments would be an
    odometry without error; this corrupts them with ``error`` (default
    :class:`OdometryError`), seeded. Each increment draws its three normal
    errors (distance, turn, drift) in step order, so that a stream of poses
    corrupted one step at a time (:class:`OdometrySimulator`) gets the same
    increments.
    """
    return corrupt_increments(odometry_increments(poses), OdometryError() if error is None else error,
                              check_random_state(random_state))  # fmt: skip


def corrupt_increments(increments: Any, error: OdometryError, rng: np.random.Generator) -> FArray:
    """Increments with simulated wheel-odometry errors, shape (n, 3); three normal draws per increment, in order.

    Increment ``(dx, dy, dtheta)`` over a distance ``d``: ``(dx, dy)`` times
    ``(1 + scale)(1 + translation z1)``, and ``dtheta + rotation |dtheta| z2
    + drift_per_metre d z3 + bias_per_metre d`` (wrapped); ``z1, z2, z3``
    standard normal (:class:`OdometryError`).
    """
    inc = np.asarray(increments, dtype=np.float64).reshape(-1, 3)
    z = rng.standard_normal((inc.shape[0], 3))
    dist = np.hypot(inc[:, 0], inc[:, 1])
    out = inc.copy()
    out[:, :2] *= (1.0 + error.scale) * (1.0 + error.translation * z[:, :1])
    out[:, 2] = wrap(
        inc[:, 2] + error.rotation * np.abs(inc[:, 2]) * z[:, 1] + error.drift_per_metre * dist * z[:, 2]
        + error.bias_per_metre * dist
    )  # fmt: skip
    return out


class OdometrySimulator:
    """Simulated wheel-odometry errors one increment at a time: the increments of :func:`wheel_odometry`.

    Fed the increments of a run in order, :meth:`corrupt` returns what
    ``wheel_odometry(poses, error_factor, random_state=seed)`` gives for the
    whole run, row by row (for a streaming replay of a log whose poses are
    corrected ones).

    Parameters
    ----------
    error_factor : float
        Times every error of :class:`OdometryError` (0: the increments unchanged).
    seed : int, default 0
    """

    def __init__(self, error_factor: float, seed: int = 0) -> None:
        self.error = OdometryError().scaled(_finite("error_factor", error_factor))
        self.exact = float(error_factor) == 0
        self.seed = int(seed)
        self.reset()

    def reset(self) -> None:
        """The first increment's draws again."""
        self._rng = np.random.default_rng(self.seed)

    def corrupt(self, increment: Any) -> FArray:
        """One increment ``(dx, dy, dtheta)`` with its simulated errors, shape (3,)."""
        inc = np.asarray(increment, dtype=np.float64).reshape(1, 3)
        return inc[0].copy() if self.exact else corrupt_increments(inc, self.error, self._rng)[0]


def wheel_odometry(poses: Any, error_factor: float = 1.0, *, random_state: int | np.random.Generator | None = 0) -> FArray:
    """The increments a wheel odometry would report along ``poses``, shape (n - 1, 3).

    ``error_factor`` 0: the poses' exact increments (:func:`odometry_increments`);
    otherwise :func:`simulate_odometry` with ``OdometryError().scaled(error_factor)``.
    """
    f = _finite("error_factor", error_factor)
    if f == 0:
        return odometry_increments(poses)
    return simulate_odometry(poses, OdometryError().scaled(f), random_state=random_state)
