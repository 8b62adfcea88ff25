"""Labelled observations into a place database (``fingerloc learn``): a new database, or one extended.

:func:`learn_into` holds the database's writer lock
(:func:`fingerloc.map.database.locked`) from its first read to its last
write, so a concurrent writer waits and nothing is lost. A new database is
learned with a preset; an existing one is extended:

* observations already stored (same content hash) are skipped; places named
  again are extended, new labels become new places; the other places are
  not refit;
* the options must be the database's own (an option that differs is an
  error naming it), and so must the sensor: observations with none of the
  map's modality are refused (:func:`fingerloc.pipeline.compat.check_observations`);
* a database made by ``fingerloc map`` keeps what ``track`` needs: place
  positions (a new place gets the mean of its views' poses, so each needs a
  pose in the map's frame, else the learn is refused with a line saying
  why), the place graph (the file order adds transitions), the calibration
  (``n_train`` and the kidnapping probability count the new views; beta and
  the pose filter's tuning stay as the mapping part chose them) and the scan
  map (the new views' laser end points are added at their poses).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..observation import Observation

__all__ = ["LearnResult", "learn_into"]

Notify = Callable[[str], None]


@dataclass(slots=True)
class LearnResult:
    """What :func:`learn_into` did.

    Attributes
    ----------
    created : bool
        A new database was written (else an existing one extended).
    preset : str
        The preset's name (the database's own when extended).
    reason : str
        Why this preset (new database only; ``""`` otherwise).
    added, extended : list of str
        Labels of the new places, and of the places that got new views.
    skipped : int
        Observations already stored (same content hash).
    places : int
        Places in the database after the learn.
    size : int
        Size of the written file, bytes.
    beta : float or None
        The calibration's likelihood scale (``None``: no calibration).
    calibration_rows : int
        Held-out views beta was fit on (a new database).
    positions : int
        Places with a stored position after the learn.
    warnings : list of str
        Doubts about the data, one line each (the command line prints them as ``warning: ...``).
    """

    created: bool
    preset: str
    reason: str = ""
    added: list[str] = field(default_factory=list)
    extended: list[str] = field(default_factory=list)
    skipped: int = 0
    places: int = 0
    size: int = 0
    beta: float | None = None
    calibration_rows: int = 0
    positions: int = 0
    warnings: list[str] = field(default_factory=list)


def learn_into(
    db: str | Path,
    observations: Sequence[Observation],
    *,
    preset: str | None = None,
    overrides: Mapping[str, Any] | None = None,
    calibrate: bool = True,
    lock_timeout: float | None = None,
    notify: Notify | None = None,
) -> LearnResult:
    """Learn labelled observations into the place database ``db`` (module docstring).

    Parameters
    ----------
    db : str or Path
        The database: created, or extended when it exists.
    observations : sequence of Observation
        Every one labelled; their order is the visiting order (the place
        graph's transitions, the calibration's folds).
    preset : str, optional
        A preset name (:data:`~fingerloc.pipeline.presets.PRESET_NAMES`);
        default ``auto`` for a new database, the database's own otherwise.
    overrides : mapping, optional
        Explicit model options (JSON form); an existing database must have the same.
    calibrate : bool, default True
        A new database: fit the filters' likelihood scale on held-out views.
    lock_timeout : float, optional
        Seconds to wait for another writer (default: the database module's).
    notify : callable, optional
        Gets a line when the writer lock is waited for.

    Returns
    -------
    LearnResult

    Raises
    ------
    InvalidParameterError
        An observation without a label, an option or preset that differs
        from the database's, observations of another modality, new places
        without poses in a map with positions.
    DatabaseError
        The database cannot be read or written, or its lock was held too long.
    """
    from ..map.database import locked
    from .presets import PRESET_NAMES

    obs = list(observations)
    if not obs:
        raise InvalidParameterError("no observation to learn")
    missing = next((i for i, o in enumerate(obs) if not o.label), None)
    if missing is not None:
        raise InvalidParameterError(f"observation {missing + 1} has no place label; learning needs labels")
    if preset is not None and preset not in PRESET_NAMES:
        raise InvalidParameterError(f"preset must be one of {', '.join(PRESET_NAMES)}, got {preset!r}")
    given = dict(overrides or {})
    path = Path(db)
    with locked(path, timeout=lock_timeout, notify=notify):  # first read to last write
        if path.exists():
            return _extend(path, obs, preset, given)
        return _create(path, obs, preset, given, calibrate)


def _create(path: Path, obs: list[Observation], preset: str | None, given: dict[str, Any], calibrate: bool) -> LearnResult:
    from ..map.database import MapInfo, observation_hash, save_model, sensor_summary
    from ..map.graph import PlaceGraph
    from .calibration import calibrate_labelled
    from .presets import empty_terms, resolve_preset

    resolved = resolve_preset("auto" if preset is None else preset, obs, given)
    model = resolved.model().fit(obs)
    warnings = []
    empty = empty_terms(resolved.options, obs)
    if empty:
        warnings.append(
            f"no observation has {', '.join(empty)} bearings: those terms cannot tell places apart (see --preset / --terms)"
        )
    cal = None
    if calibrate and len(model.places_) > 1:
        cal = calibrate_labelled(resolved.options, obs).to_json()
    info = MapInfo(preset=resolved.to_json(), content_hashes={observation_hash(o) for o in obs}, calibration=cal,
                   sensor=sensor_summary(obs))  # fmt: skip
    graph = PlaceGraph([str(c) for c in model.classes_])
    for a, b in itertools.pairwise(obs):
        graph.add_transition(str(a.label), str(b.label))
    size = save_model(model, path, graph_edges=graph.edges(), info=info)
    labels = [str(c) for c in model.classes_]
    return LearnResult(
        created=True, preset=resolved.name, reason=resolved.reason, added=labels, places=len(labels), size=size,
        beta=None if cal is None else float(cal["beta"]), calibration_rows=0 if cal is None else int(cal["calibration_rows"]),
        warnings=warnings,
    )  # fmt: skip


def _check_options(path: Path, lm: Any, obs: list[Observation], preset: str | None, given: dict[str, Any]) -> None:
    """The options and preset must be the database's own."""
    from .presets import resolve_preset

    stored = _stored_options(lm.model)
    stored_preset = lm.preset
    if preset is not None and stored_preset is not None and preset not in ("auto", stored_preset.name):
        raise InvalidParameterError(f"{path} was learned with preset {stored_preset.name!r}, not {preset!r} (use a new database)")
    if preset is not None and stored_preset is None and preset != "auto":
        resolved = resolve_preset(preset, obs)
        for k, v in resolved.options.items():
            if k in stored and k not in given and stored[k] != v:
                raise InvalidParameterError(f"{path} was learned with {k}={stored[k]!r}, not preset {preset} (use a new database)")
    for k, v in given.items():
        if stored.get(k) != v:
            raise InvalidParameterError(f"{path} was learned with {k} {stored.get(k)!r}; got {v!r} (use a new database)")


def _stored_options(model: Any) -> dict[str, Any]:
    """A loaded model's options in JSON form (costs by name when they are one of the named ones)."""
    from ..align import CostModel

    params = model.get_params()
    c = params["costs"]
    if c is None:
        params["costs"] = "unit"
    else:
        f = CostModel.feature_aware()
        same = np.array_equal(c.substitution, f.substitution) and np.array_equal(c.indel, f.indel)
        params["costs"] = "feature" if same else "custom"
    params["terms"] = list(params["terms"])
    return params


def _extend(path: Path, obs: list[Observation], preset: str | None, given: dict[str, Any]) -> LearnResult:
    from ..map.database import MapInfo, observation_hash, read_graph_edges, read_map_info, save_model
    from ..map.graph import PlaceGraph
    from .compat import check_observations
    from .placemap import load_map

    lm = load_map(path)
    info = read_map_info(path)
    _check_options(path, lm, obs, preset, given)
    warnings = check_observations(lm, obs, what="the observations", sensor=info.sensor)
    model = lm.model
    hashes = [observation_hash(o) for o in obs]
    known = set(lm.content_hashes)
    fresh: list[int] = []
    for i, h in enumerate(hashes):
        if h not in known:
            fresh.append(i)
            known.add(h)
    new_obs = [obs[i] for i in fresh]
    before = [str(c) for c in model.classes_]
    new_labels = list(dict.fromkeys(str(o.label) for o in new_obs if str(o.label) not in set(before)))
    positions = dict(info.positions)
    if positions and new_labels:
        positions.update(_new_positions(path, new_obs, new_labels, info, warnings))
    if positions:
        warnings += _frame_of_known(path, new_obs, positions, info)
    if new_obs:
        model.add_places(new_obs)
    labels = [str(c) for c in model.classes_]
    calibration = _recount(info.calibration, len(new_obs))
    scan_map = info.scan_map
    if scan_map is not None and new_obs:
        scan_map, note = _extend_scan_map(scan_map, new_obs)
        if note:
            warnings.append(note)
    out_info = MapInfo(
        preset=info.preset,
        positions=positions,
        calibration=calibration,
        content_hashes=set(lm.content_hashes) | {hashes[i] for i in fresh},
        runs=info.runs,
        scan_map=scan_map,
        sensor=info.sensor,
    )
    graph = PlaceGraph(labels, read_graph_edges(path))
    for a, b in itertools.pairwise(obs):
        graph.add_transition(str(a.label), str(b.label))
    size = save_model(model, path, graph_edges=graph.edges(), info=out_info)
    return LearnResult(
        created=False,
        preset="" if lm.preset is None else lm.preset.name,
        added=new_labels,
        extended=sorted({str(o.label) for o in new_obs} & set(before)),
        skipped=len(obs) - len(fresh),
        places=len(labels),
        size=size,
        beta=None if calibration is None else float(calibration.get("beta", 1.0)),
        positions=len(positions),
        warnings=warnings,
    )


def _new_positions(
    path: Path, new_obs: list[Observation], new_labels: list[str], info: Any, warnings: list[str]
) -> dict[str, tuple[float, float]]:
    """Positions of new places in a map: the mean of their views' poses (every view needs one)."""
    out: dict[str, tuple[float, float]] = {}
    lacking = [lab for lab in new_labels if any(o.pose is None for o in new_obs if str(o.label) == lab)]
    if lacking:
        names = ", ".join(repr(x) for x in lacking[:5]) + (" ..." if len(lacking) > 5 else "")
        raise InvalidParameterError(
            f"{path} is a map with place positions ('fingerloc map'); the new place(s) {names} have views without a "
            "pose, so they would get no position and 'fingerloc track' could not use the map: give every view a "
            "pose in the map's frame, or learn them into a new database"
        )
    centres = np.array(list(info.positions.values()), dtype=np.float64).reshape(-1, 2)
    radius = float((info.calibration or {}).get("radius", 1.0))
    for lab in new_labels:
        xy = np.array([o.pose[:2] for o in new_obs if str(o.label) == lab and o.pose is not None], dtype=np.float64)
        c = xy.mean(axis=0)
        out[lab] = (float(c[0]), float(c[1]))
        if centres.size:
            d = np.hypot(*(centres - c).T)
            j = int(np.argmin(d))
            if d[j] <= radius:
                warnings.append(
                    f"new place {lab!r} at ({c[0]:.2f}, {c[1]:.2f}) lies {d[j]:.2f} m from place "
                    f"{list(info.positions)[j]!r}, within the map's radius {radius:g} m: two places in one spot"
                )
    return out


def _frame_of_known(path: Path, new_obs: list[Observation], positions: dict[str, tuple[float, float]], info: Any) -> list[str]:
    """Views of places with a position, with poses far from it: refuse (another frame) or warn."""
    spacing = float((info.calibration or {}).get("spacing", 2.0))
    far = []
    for o in new_obs:
        if o.pose is None or str(o.label) not in positions:
            continue
        px, py = positions[str(o.label)]
        far.append(math.hypot(o.pose[0] - px, o.pose[1] - py))
    if not far:
        return []
    d = float(np.median(far))
    if d > 5 * spacing:
        raise InvalidParameterError(
            f"the views' poses lie {d:.1f} m (median) from their places' stored positions in {path} (place spacing "
            f"{spacing:g} m): are they in another frame? give poses in the map's frame"
        )
    return []


def _recount(calibration: dict[str, Any] | None, n_new: int) -> dict[str, Any] | None:
    """The stored calibration with the new views counted (``n_train``; ``kidnap`` when it followed n_train)."""
    if calibration is None or not n_new:
        return calibration
    cal = dict(calibration)
    n_old = int(cal.get("n_train", 0) or 0)
    n = n_old + n_new
    cal["n_train"] = n
    k = cal.get("kidnap")
    if isinstance(k, (int, float)) and n_old and math.isclose(float(k), 1.0 / (n_old + 2), rel_tol=1e-9):
        cal["kidnap"] = 1.0 / (n + 2)
    return cal


def _extend_scan_map(sm: Any, new_obs: list[Observation]) -> tuple[Any, str]:
    """The scan map with the laser end points of the new views (at their poses) added, on the same cell lattice."""
    from ..map.scan_map import SCAN_MAX_CELLS, ScanMap, scan_points

    world = []
    for o in new_obs:
        if o.pose is None or o.ranges is None or o.range_bearings is None:
            continue
        q = scan_points(o.ranges, o.range_bearings)
        if q.shape[0] == 0:
            continue
        x, y, th = o.pose
        c, s = math.cos(th), math.sin(th)
        world.append(np.column_stack([x + c * q[:, 0] - s * q[:, 1], y + s * q[:, 0] + c * q[:, 1]]))
    if not world:
        return sm, ""
    pts = np.vstack(world)
    res = float(sm.resolution)
    pad = float(sm.clip) + 1.0
    old_lo = np.asarray(sm.origin, dtype=np.float64)
    old_hi = old_lo + res * np.asarray(sm.shape, dtype=np.float64)
    lo = np.minimum(old_lo, pts.min(axis=0) - pad)
    hi = np.maximum(old_hi, pts.max(axis=0) + pad)
    shift = np.ceil((old_lo - lo) / res - 1e-9).astype(np.int64)  # whole cells: the old cells keep their place
    lo = old_lo - shift * res
    shape = np.ceil((hi - lo) / res - 1e-9).astype(np.int64)
    if int(shape[0]) * int(shape[1]) > SCAN_MAX_CELLS:
        return sm, (
            f"the new views' laser end points would grow the scan map beyond {SCAN_MAX_CELLS} cells: it is kept as it "
            "was (the pose filter has no scan evidence at the new places)"
        )
    cells = np.clip(np.floor((pts - lo) / res).astype(np.int64), 0, shape - 1)
    merged = np.vstack([np.asarray(sm.cells, dtype=np.int64) + shift, cells])
    return ScanMap(lo, res, (int(shape[0]), int(shape[1])), merged, sigma=sm.sigma, floor=sm.floor, clip=sm.clip), ""
