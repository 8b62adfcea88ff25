"""Does it fit? Observations, runs and maps checked against each other before an answer is given.

A place map answers for the sensor it was made from, in the frame it was
made in. Each function here takes what it compares (a loaded map or model,
observations, poses), returns the doubts as a list of one-line warnings (the
answer can still be given; the command line prints each as ``warning: ...``)
and raises :class:`~fingerloc.errors.InvalidParameterError` when nothing
sensible can come out; every message names what differs and how to fix it.

* :func:`check_observations` - the observations' modality (laser, image)
  against the map's, and their field of view (another lidar or set of
  topics); :func:`check_run` - the same for a whole run (its scans or
  records) and its poses against the map's places (:func:`check_frame`);
* :func:`check_frame` - a run's poses against the map's place positions
  (another frame: no overlap of the extents, or few poses near any place);
* :func:`check_run_for_map` - a run that cannot make a map (no usable scan,
  every view empty) or makes a poor one (a stationary run);
* :func:`check_map` - a map just made (one place, beta at its bound, few
  training views, empty fingerprints);
* :func:`check_queries` - too few queries for the summary's figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..observation import Observation

__all__ = [
    "MIN_QUERIES",
    "check_frame",
    "check_map",
    "check_observations",
    "check_queries",
    "check_run",
    "check_run_for_map",
    "map_sensor",
]

#: Fewer labelled queries than this: the top-1 and mean rank get a warning.
MIN_QUERIES = 10
#: Fields of view differing by more than this (degrees) get a warning.
FOV_TOLERANCE_DEG = 30.0
#: Below this part of a run's poses near a place (within the map's radius), the frame is in doubt.
NEAR_FRACTION = 0.1
#: A run whose positions span less than this part of the place spacing does not move.
STATIONARY_FRACTION = 0.25
#: beta's search interval (:func:`fingerloc.map.filter.fit_likelihood_scale`).
BETA_BOUNDS = (1e-3, 1e3)

_NAMES = {"laser": "laser", "image": "image"}


def _model(m: Any) -> Any:
    return getattr(m, "model", m)


def _views(m: Any) -> list[Observation]:
    return [o for p in _model(m).places_.values() for o in p.observations]


def map_sensor(m: Any, stored: dict[str, Any] | None = None) -> dict[str, Any]:
    """The map's sensor summary (``modality``, ``fov_deg``...): ``stored`` (or the map's own), else from its views."""
    from ..map.database import sensor_summary

    if stored is None:
        stored = getattr(m, "sensor", None)
    if isinstance(stored, dict) and isinstance(stored.get("modality"), list):
        return stored
    return sensor_summary(_views(m))


def _modality(observations: Sequence[Observation]) -> tuple[set[str], int]:
    from ..map.database import view_modality

    kinds: set[str] = set()
    empty = 0
    for o in observations:
        k = view_modality(o)
        kinds |= k
        empty += not k
    return kinds, empty


def _words(kinds: set[str] | Sequence[str]) -> str:
    k = sorted(kinds)
    return " and ".join(k) if k else "no"


def _preset_name(m: Any) -> str:
    p = getattr(m, "preset", None)
    name = getattr(p, "name", None)
    return f" (preset {name})" if name else ""


def check_observations(
    m: Any, observations: Sequence[Observation], *, what: str = "the observations", sensor: dict[str, Any] | None = None
) -> list[str]:
    """Observations against a map: modality and field of view.

    Parameters
    ----------
    m : LoadedMap or PlaceModel
        The map (a loaded map's stored ``sensor`` is used when it has one).
    observations : sequence of Observation
        What is about to be answered (or learned).
    what : str
        How the messages name them (``"data.jsonl"``).
    sensor : dict, optional
        The map's stored sensor summary (``MapInfo.sensor``), when known.

    Returns
    -------
    list of str
        Warnings: the observations have a modality the map lacks (ignored),
        their field of view differs from the map's.

    Raises
    ------
    InvalidParameterError
        The observations share no modality with the map (laser views against
        an image map, or the reverse), or every observation is empty.
    """
    obs = list(observations)
    if not obs:
        return []
    kinds, empty = _modality(obs)
    if empty == len(obs):
        raise InvalidParameterError(
            f"{what}: none of the {len(obs)} observation(s) has a feature (no laser return, no image feature): "
            "nothing to compare with the map's places"
        )
    fov = [math.degrees(sum(w for _, w in o.fov)) for o in obs]
    return _check_kinds(m, kinds, float(np.median(fov)), what=what, sensor=sensor)


def _check_kinds(m: Any, kinds: set[str], fov_deg: float | None, *, what: str, sensor: dict[str, Any] | None) -> list[str]:
    """The modality and field of view of what is answered against the map's."""
    sensor = map_sensor(m, sensor)
    have = set(sensor.get("modality") or [])
    out: list[str] = []
    if have and not (kinds & have):
        raise InvalidParameterError(
            f"{what} have {_words(kinds)} features, the map holds {_words(have)} views{_preset_name(m)}: they cannot "
            f"be compared; give {_words(have)} observations, or make a map of their own (another --db)"
        )
    if have and kinds - have:
        out.append(
            f"{what} also have {_words(kinds - have)} features, which the map{_preset_name(m)} has not learned: "
            "they are ignored"
        )
    f_map = sensor.get("fov_deg")
    if isinstance(f_map, (int, float)) and fov_deg is not None and "laser" in (kinds & have):
        f_obs = fov_deg
        if abs(f_obs - float(f_map)) > FOV_TOLERANCE_DEG:
            topics = sensor.get("topics")
            hint = f" (the map's topics: {', '.join(topics)})" if isinstance(topics, list) and topics else ""
            out.append(
                f"{what} cover {f_obs:.0f} deg, the map's views {float(f_map):.0f} deg: another lidar or another set "
                f"of topics? read them as the map's run was read (--topic ...){hint}"
            )
    return out


def check_run(m: Any, run: Any, *, what: str | None = None, sensor: dict[str, Any] | None = None) -> list[str]:
    """A run about to be answered (``localize``, ``track``) against a map: sensor and frame.

    JSON Lines records go through :func:`check_observations`; a laser run's
    scans are laser views (refused when none has a return, or when the map
    holds image views only), their field of view compared with the map's;
    with poses and the map's place positions, :func:`check_frame`.

    Returns
    -------
    list of str
        Warnings (see the functions above).

    Raises
    ------
    InvalidParameterError
        Nothing sensible can come out (another modality, no usable scan, no overlap with the map).
    """
    name = what or (str(run.paths[0]) if getattr(run, "paths", None) else "the run")
    if run.records is not None:
        out = check_observations(m, run.records, what=name, sensor=sensor)
    else:
        scans = run.scans or []
        if scans and not any(bool(np.any(s.valid)) for s in scans):
            raise InvalidParameterError(
                f"{name}: none of its {len(scans)} scans has a laser return (every range is missing, zero or beyond "
                "the sensor's maximum): nothing to compare with the map's places"
            )
        out = _check_kinds(m, {"laser"}, math.degrees(run.field_of_view()), what=f"{name}'s scans", sensor=sensor)
    positions, cal = getattr(m, "positions", None), getattr(m, "calibration", None)
    poses = run.poses
    if poses is not None and positions is not None and cal is not None:
        out += check_frame(positions, cal.radius, cal.spacing, poses, what=name)
    return out


def _extent(xy: np.ndarray) -> str:
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    return f"x {lo[0]:.1f}..{hi[0]:.1f} m, y {lo[1]:.1f}..{hi[1]:.1f} m"


def check_frame(
    positions: Any, radius: float, spacing: float, poses: Any, *, what: str = "the run"
) -> list[str]:
    """A run's poses against the map's place positions (the same frame?).

    Parameters
    ----------
    positions : array_like, shape (P, 2)
        Place centres, metres (the map's frame).
    radius, spacing : float
        The map's place radius and spacing, metres.
    poses : array_like, shape (n, 2) or (n, 3)
        The run's poses, metres (the run's frame).

    Returns
    -------
    list of str
        A warning when fewer than :data:`NEAR_FRACTION` of the poses lie
        within ``radius`` of a place (few queries can be scored).

    Raises
    ------
    InvalidParameterError
        When the run's extent and the places' (each widened by ``spacing``)
        do not overlap at all: another frame, or another building.
    """
    c = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    p = np.asarray(poses, dtype=np.float64)
    if c.shape[0] == 0 or p.size == 0:
        return []
    xy = p.reshape(p.shape[0], -1)[:, :2]
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if xy.shape[0] == 0:
        return []
    pad = max(float(spacing), float(radius))
    lo = np.maximum(xy.min(axis=0), c.min(axis=0) - pad)
    hi = np.minimum(xy.max(axis=0), c.max(axis=0) + pad)
    if np.any(lo > hi):
        raise InvalidParameterError(
            f"{what}'s poses ({_extent(xy)}) do not overlap the map's places ({_extent(c)}): another frame or "
            "another building? give a run recorded in the map's frame (or make a map of this run)"
        )
    d = np.sqrt(((xy[:, None, :] - c[None, :, :]) ** 2).sum(axis=2)).min(axis=1) if xy.shape[0] * c.shape[0] <= 4e7 else None
    if d is None:
        return []
    near = int(np.sum(d <= radius))
    if near < NEAR_FRACTION * xy.shape[0]:
        return [
            f"only {near} of {xy.shape[0]} poses of {what} lie within {radius:g} m of a place (median distance "
            f"{float(np.median(d)):.1f} m): is the run in the map's frame?"
        ]
    return []


def check_run_for_map(run: Any, *, mapping_part: float | None = None) -> list[str]:
    """A run about to make a map: refuse what cannot make one, warn about a poor one.

    Raises
    ------
    InvalidParameterError
        No scan of a laser run has a single return (all ranges NaN, zero or
        beyond the sensor's maximum), or no observation of a JSON Lines run
        has a feature.

    Returns
    -------
    list of str
        Warnings: scans without a return (how many), a run that does not
        move (its positions span less than a quarter of a place spacing: one
        place).
    """
    out: list[str] = []
    name = run.paths[0] if getattr(run, "paths", None) else "the run"
    if run.scans is not None:
        usable = sum(bool(np.any(s.valid)) for s in run.scans)
        if usable == 0:
            raise InvalidParameterError(
                f"{name}: none of its {len(run.scans)} scans has a laser return (every range is missing, zero or "
                "beyond the sensor's maximum): nothing to map"
            )
        if usable < len(run.scans):
            out.append(f"{name}: {len(run.scans) - usable} of {len(run.scans)} scans have no laser return")
    elif run.records is not None:
        _, empty = _modality(run.records)
        if empty == len(run.records):
            raise InvalidParameterError(f"{name}: none of its {len(run.records)} observations has a feature: nothing to map")
        if empty:
            out.append(f"{name}: {empty} of {len(run.records)} observations have no feature")
    poses = run.poses
    if poses is not None and poses.shape[0] > 1:
        from .places import PLACE_SPACING_M

        span = float(np.max(np.ptp(poses[:, :2], axis=0)))
        if span < STATIONARY_FRACTION * PLACE_SPACING_M:
            out.append(
                f"{name}: the robot moves {span:.2f} m in all ({poses.shape[0]} poses): a stationary run makes one "
                "place, and every answer is that place"
            )
    return out


def check_map(place_map: Any) -> list[str]:
    """A map just made (:class:`~fingerloc.pipeline.mapping.PlaceMap`): warnings about what it can tell.

    One place, a likelihood scale ``beta`` at a bound of its search, fewer
    calibration rows than the calibration wants, training views without
    features.
    """
    out: list[str] = []
    pm = place_map
    n_places = len(pm.labels)
    if n_places == 1:
        out.append("the map has 1 place: every answer will be that place (a short or stationary run?)")
    cal = getattr(pm, "calibration", None)
    if cal is not None and int(getattr(cal, "calibration_rows", 0) or 0):
        beta = float(cal.beta)
        lo, hi = BETA_BOUNDS
        if beta <= lo * 1.01 or beta >= hi / 1.01:
            out.append(
                f"the likelihood scale beta is {beta:.3g}, at the bound of its search ({lo:g} to {hi:g}): the "
                f"{cal.calibration_rows} held-out views are too few or too alike to calibrate it"
            )
    training = list(getattr(pm, "training", None) or [])
    if training:
        _, empty = _modality(training)
        if empty:
            out.append(f"{empty} of {len(training)} training views have no feature (empty fingerprints)")
    return out


def check_queries(n_labelled: int) -> list[str]:
    """A warning when fewer than :data:`MIN_QUERIES` labelled queries make the summary's figures."""
    if 0 < n_labelled < MIN_QUERIES:
        return [f"only {n_labelled} labelled quer{'y' if n_labelled == 1 else 'ies'}: top-1 and mean rank are rough"]
    return []
