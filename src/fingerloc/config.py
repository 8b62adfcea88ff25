"""The knobs of a place map and its filters, with their defaults in one place.

A :class:`Config` is a small frozen object of three parts: how places are made
from a run (:class:`PlacesConfig`), how the filters are calibrated on the
mapping part (:class:`CalibrationConfig`) and how the pose filter runs
(:class:`PoseFilterConfig`). :func:`fingerloc.make_map` takes one and stores
it in the place database with what it learned, so that a map tracks with the
settings it was calibrated with. Change a setting with
:func:`dataclasses.replace` (or :meth:`Config.with_`), never by assignment::

    import fingerloc as fl
    cfg = fl.Config().with_(places={"spacing": 3.0}, pose_filter={"n_particles": 1000})

Units: metres, radians, probabilities in ``[0, 1]``; names ending in ``_m``
are metres.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

from .errors import InvalidParameterError

__all__ = ["CalibrationConfig", "Config", "PlacesConfig", "PoseFilterConfig"]


def _positive(owner: str, name: str, value: Any, *, zero: bool = False, inf: bool = False) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and not math.isnan(value)
    ok = ok and (value >= 0 if zero else value > 0) and (inf or math.isfinite(value))
    if not ok:
        bound = ">= 0" if zero else "> 0"
        raise InvalidParameterError(f"{owner}.{name} must be a finite number {bound}, got {value!r}")


def _probability(owner: str, name: str, value: Any) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value <= 1
    if not ok:
        raise InvalidParameterError(f"{owner}.{name} must be a probability in [0, 1], got {value!r}")


def _count(owner: str, name: str, value: Any, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise InvalidParameterError(f"{owner}.{name} must be an integer >= {low}, got {value!r}")


@dataclass(frozen=True, slots=True)
class PlacesConfig:
    """Places from a run's poses (:func:`fingerloc.pipeline.places.places_from_trajectory`).

    Attributes
    ----------
    spacing_m : float, default 2.0
        A mapping scan strictly farther than this from every place centre makes a new place.
    radius_m : float, default 1.0
        Scans within this distance (inclusive) of a centre train it (mapping part) or query it.
    mapping_part : float, default 0.5
        Fraction of the run, from its start, that maps (``until_s`` instead when set).
    until_s : float, optional
        The mapping part: the scans within this many seconds of the first.
    """

    spacing_m: float = 2.0
    radius_m: float = 1.0
    mapping_part: float = 0.5
    until_s: float | None = None

    def __post_init__(self) -> None:
        _positive("places", "spacing_m", self.spacing_m)
        _positive("places", "radius_m", self.radius_m)
        if not (isinstance(self.mapping_part, (int, float)) and 0 < self.mapping_part <= 1):
            raise InvalidParameterError(f"places.mapping_part must be a fraction in (0, 1], got {self.mapping_part!r}")
        if self.until_s is not None:
            _positive("places", "until_s", self.until_s, zero=True)


@dataclass(frozen=True, slots=True)
class CalibrationConfig:
    """What the calibration on the mapping part fits and tries (:func:`fingerloc.pipeline.calibration.calibrate_map`).

    Attributes
    ----------
    enabled : bool, default True
        Fit the likelihood scale ``beta`` on held-out training views (else ``beta = 1``,
        and nothing below is fitted).
    min_rows : int, default 10
        Held-out rows needed to fit ``beta`` from alternate visits; fewer: alternate scans.
    heading : bool, default True
        Fit the pose filter's heading model (the heading each view implies at its place).
    heading_reverse, heading_slope : bool, default True
        Let the heading model have a peak at the reverse heading, and a reliability that
        grows with the view's probability of the place.
    heading_temper_m : float, default 8.0
        The heading evidence counts fully after this much travel (its errors stay
        correlated longer than the place's); 0: tempered as the observations.
    tune : bool, default True
        Choose the pose filter's ``outlier`` (rho) and tempering distance along the mapping part.
    tune_with_heading : bool, default False
        Run that tuning with the heading evidence (as good without, in half the time).
    outliers : tuple of float, default (0.1, 0.3)
        The ``rho`` tried; the reliability fitted on the held-out rows is tried too.
    temper_m : tuple of float, default (2.0, 1.0, 4.0)
        The tempering distances tried (without tuning: the place spacing).
    outlier_fit : bool, default False
        Use the fitted reliability as ``rho`` without tuning (and ``off_place`` 0.1).
    scan : bool, default True
        Keep the mapping part's laser end points as a scan map and choose the
        power of their evidence (a run with ranges only).
    scan_gammas : tuple of float, default (1.0, 3.0, 10.0)
        Powers of the scan evidence tried after rho and the tempering (0, the filter
        without it, is tried first and wins ties).
    scan_gamma : float, optional
        A fixed power instead of the tuned one.
    scan_guard_m : float, default 1.0
        A fold's scan map holds no scan within this distance (along the run) of one
        of the fold's rows.
    scan_starts : int, default 1
        The scan power's tuning runs from this many starts along the mapping part.
    lost : bool, default True
        With the scan evidence: calibrate the lost rule on the chosen power's run.
    lost_quantile : float, default 0.05
        The lost threshold: this quantile of the scan fits where the filter was right.
    odometry_error : float, optional
        Factor of the simulated wheel-odometry errors of the tuning runs; default 1
        for CARMEN logs (whose poses are corrected ones), else 0.
    kidnap : float, optional
        The pose filter's kidnapping probability per observation; default
        ``1 / (n_train + 2)`` (Laplace's rule over the mapping part's observations).
    share_draws : bool, default True
        The tuning runs replay one record of random draws (the same results, faster).
    max_steps : int, optional, default 1000
        A mapping part longer than this many steps is calibrated on a sample of it:
        ``windows`` stretches spread evenly along it, together this long (their
        training views held out and scored by models of every other-fold view,
        the tuning runs along each stretch, pooled). ``None``: always all of it.
    windows : int, default 4
        The number of those stretches.
    """

    enabled: bool = True
    min_rows: int = 10
    heading: bool = True
    heading_reverse: bool = True
    heading_slope: bool = True
    heading_temper_m: float = 8.0
    tune: bool = True
    tune_with_heading: bool = False
    outliers: tuple[float, ...] = (0.1, 0.3)
    temper_m: tuple[float, ...] = (2.0, 1.0, 4.0)
    outlier_fit: bool = False
    scan: bool = True
    scan_gammas: tuple[float, ...] = (1.0, 3.0, 10.0)
    scan_gamma: float | None = None
    scan_guard_m: float = 1.0
    scan_starts: int = 1
    lost: bool = True
    lost_quantile: float = 0.05
    odometry_error: float | None = None
    kidnap: float | None = None
    share_draws: bool = True
    max_steps: int | None = 1000
    windows: int = 4

    def __post_init__(self) -> None:
        _count("calibration", "min_rows", self.min_rows, 1)
        if self.max_steps is not None:
            _count("calibration", "max_steps", self.max_steps, 2)
        _count("calibration", "windows", self.windows, 1)
        _positive("calibration", "heading_temper_m", self.heading_temper_m, zero=True)
        for v in self.outliers:
            _probability("calibration", "outliers", v)
        if not self.temper_m:
            raise InvalidParameterError("calibration.temper_m needs at least one distance")
        for v in self.temper_m:
            _positive("calibration", "temper_m", v)
        for v in self.scan_gammas:
            _positive("calibration", "scan_gammas", v, zero=True)
        if self.scan_gamma is not None:
            _positive("calibration", "scan_gamma", self.scan_gamma, zero=True)
        _positive("calibration", "scan_guard_m", self.scan_guard_m, zero=True)
        _count("calibration", "scan_starts", self.scan_starts, 1)
        _probability("calibration", "lost_quantile", self.lost_quantile)
        if self.odometry_error is not None:
            _positive("calibration", "odometry_error", self.odometry_error, zero=True)
        if self.kidnap is not None and not (isinstance(self.kidnap, (int, float)) and 0 <= self.kidnap < 1):
            raise InvalidParameterError(f"calibration.kidnap must be a probability in [0, 1), got {self.kidnap!r}")


@dataclass(frozen=True, slots=True)
class PoseFilterConfig:
    """How the filters run along a run (:class:`fingerloc.map.driver.PoseTracking`).

    Attributes
    ----------
    n_particles : int, default 3000
    alpha : float, default 1.0
        Additive smoothing of the place graph's transition counts.
    temper : bool, default True
        Weigh observations by the motion since the previous one.
    relocalize : bool, default True
        Run the place filter alongside: a kidnapped robot is looked for where it believes.
    start_at_first_observation : bool, default True
        Draw the particles from the first observation instead of carrying the start prior.
    gap_m : float, optional
        An odometry step longer than this re-initialises at the next observation.
    strategy : {"plain", "challenger", "reset", "augmented"}, default "plain"
        How an observation updates the belief (:mod:`fingerloc.map.driver`).
    challenger_switch_nats : float, default 3.0
        With ``strategy="challenger"``: the log Bayes factor that makes the switch.
    reset_nats : float, default 8.0
        With ``strategy="reset"``: the CUSUM threshold of sensor resetting.
    scan_fresh : int, default 10
        With the scan evidence, a (re)initialisation from the sensor draws this many
        times the particles.
    lost_after : int, default 1
        Observations in a row below the lost threshold before a re-draw.
    lost_statistic : {"best", "mean"}, default "best"
    lost_uniform : bool, default False
        A lost re-draw looks everywhere instead of where the place filter believes.
    lost_uniform_share : float, default 0.5
        A lost re-draw's prior is this share uniform over the places, the rest where the
        place filter believes (that filter saw the views that misled the particles).
    hold_margin : float, optional, default 0.05
        Between observations, keep the previous answer unless another place leads by this.
    tie_break : float, optional, default 0.02
        Between observations, near-ties within this go to the place filter's choice.
    """

    n_particles: int = 3000
    alpha: float = 1.0
    temper: bool = True
    relocalize: bool = True
    start_at_first_observation: bool = True
    gap_m: float | None = None
    strategy: str = "plain"
    challenger_switch_nats: float = 3.0
    reset_nats: float = 8.0
    scan_fresh: int = 10
    lost_after: int = 1
    lost_statistic: str = "best"
    lost_uniform: bool = False
    lost_uniform_share: float = 0.5
    hold_margin: float | None = 0.05
    tie_break: float | None = 0.02

    def __post_init__(self) -> None:
        _count("pose_filter", "n_particles", self.n_particles, 10)
        _positive("pose_filter", "alpha", self.alpha, zero=True)
        if self.gap_m is not None:
            _positive("pose_filter", "gap_m", self.gap_m)
        if self.strategy not in ("plain", "challenger", "reset", "augmented"):
            raise InvalidParameterError(
                f"pose_filter.strategy must be plain, challenger, reset or augmented, got {self.strategy!r}"
            )
        _positive("pose_filter", "challenger_switch_nats", self.challenger_switch_nats, zero=True)
        _positive("pose_filter", "reset_nats", self.reset_nats, zero=True)
        _count("pose_filter", "scan_fresh", self.scan_fresh, 1)
        _count("pose_filter", "lost_after", self.lost_after, 1)
        _probability("pose_filter", "lost_uniform_share", self.lost_uniform_share)
        if self.lost_statistic not in ("best", "mean"):
            raise InvalidParameterError(f"pose_filter.lost_statistic must be best or mean, got {self.lost_statistic!r}")
        for name in ("hold_margin", "tie_break"):
            v = getattr(self, name)
            if v is not None:
                _positive("pose_filter", name, v, zero=True, inf=name == "hold_margin")


_PARTS = {"places": PlacesConfig, "calibration": CalibrationConfig, "pose_filter": PoseFilterConfig}


@dataclass(frozen=True, slots=True)
class Config:
    """Every knob of a place map and its filters (module docstring).

    Attributes
    ----------
    places : PlacesConfig
    calibration : CalibrationConfig
    pose_filter : PoseFilterConfig
    """

    places: PlacesConfig = field(default_factory=PlacesConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    pose_filter: PoseFilterConfig = field(default_factory=PoseFilterConfig)

    def __post_init__(self) -> None:
        for name, cls in _PARTS.items():
            if not isinstance(getattr(self, name), cls):
                raise InvalidParameterError(f"config.{name} must be a {cls.__name__}, got {getattr(self, name)!r}")

    def with_(self, **parts: Mapping[str, Any]) -> Config:
        """A copy with some fields of some parts changed: ``cfg.with_(places={"spacing_m": 3.0})``."""
        new: dict[str, Any] = {}
        for name, changes in parts.items():
            if name not in _PARTS:
                raise InvalidParameterError(f"unknown config part {name!r} (known: {', '.join(_PARTS)})")
            new[name] = _replace(getattr(self, name), name, changes)
        return replace(self, **new)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready nested dict (tuples as lists)."""
        return {name: asdict(getattr(self, name)) for name in _PARTS}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Config:
        """Inverse of :meth:`to_json`; missing parts and fields take their defaults, unknown ones are an error."""
        if not isinstance(data, Mapping):
            raise InvalidParameterError(f"a stored config must be an object, got {type(data).__name__}")
        unknown = set(data) - set(_PARTS)
        if unknown:
            raise InvalidParameterError(f"unknown config part(s): {', '.join(sorted(unknown))}")
        parts = {name: _replace(part(), name, data.get(name) or {}) for name, part in _PARTS.items()}
        return cls(**parts)


def _replace(part: Any, name: str, changes: Mapping[str, Any]) -> Any:
    if not isinstance(changes, Mapping):
        raise InvalidParameterError(f"config.{name} must be an object, got {type(changes).__name__}")
    known = {f.name: f for f in fields(part)}
    bad = set(changes) - set(known)
    if bad:
        raise InvalidParameterError(f"unknown field(s) of config.{name}: {', '.join(sorted(bad))}")
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in changes.items()}
    try:
        return replace(part, **values)
    except TypeError as err:
        raise InvalidParameterError(f"invalid config.{name}: {err}") from err
