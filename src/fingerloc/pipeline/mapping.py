"""A place map from a recorded run: places, model, graph and calibration in one call (``fingerloc map``).

:func:`make_map` applies :func:`~fingerloc.pipeline.places.places_from_trajectory`
to a run's poses, labels the training scans with their nearest place
(:func:`~fingerloc.pipeline.places.place_label`), learns them with a preset,
builds the place graph from the mapping part's visiting order and calibrates
the filters on the mapping part (:mod:`fingerloc.pipeline.tracker`).
:func:`save_map` writes it all to a place database (schema version 4);
:func:`load_map` reads it back.

When the run's items carry laser ranges (a CARMEN log, a bag, JSON Lines
with ``scan``), the map also keeps the mapping part's laser end points as a
:class:`~fingerloc.map.scan_map.ScanMap` (:attr:`PlaceMap.scan_map`): the
pose filter of ``track --filter pose`` weighs its particles by how well each
observation's end points (:func:`run_end_points`) fit it, with the power
``Calibration.scan_gamma`` chosen on the mapping part (0: off).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..map.graph import PlaceGraph
from ..observation import Observation
from .places import PLACE_RADIUS_M, PLACE_SPACING_M, PlaceSplit, place_label, places_from_trajectory
from .presets import ResolvedPreset, model_from_options, resolve_preset
from .readers import Run
from .tracker import (
    TUNE_WITH_HEADING,
    Calibration,
    Tracker,
    held_out_calibration,
    held_out_headings,
    mapping_graph,
    model_fit_score,
    scan_tuning_inputs,
    tune_pose_filter,
    with_heading_model,
)

__all__ = ["LoadedMap", "PlaceMap", "load_map", "make_map", "run_end_points", "save_map"]


def run_end_points(run: Run, idx: Any = None, *, stride: int | None = None) -> list[Any] | None:
    """The laser end points of a run's items ``idx`` (default all): robot frame, shape (m, 2) each, metres.

    A laser log's scans give theirs with the sensor's offset
    (:func:`~fingerloc.map.scan_map.end_points`); a JSON Lines observation its
    ``ranges`` at ``range_bearings`` (robot frame). An item without ranges
    gives an empty (0, 2) array; ``None`` when no item has ranges.
    ``stride``: every ``stride``-th beam with a return
    (:func:`~fingerloc.map.scan_map.scan_points`; default
    :data:`~fingerloc.map.scan_map.SCAN_STRIDE`, the pose filter's).
    """
    from ..map.scan_map import SCAN_STRIDE, end_points, scan_points

    st = SCAN_STRIDE if stride is None else stride
    sel = range(len(run)) if idx is None else [int(i) for i in np.asarray(idx, dtype=np.int64).reshape(-1)]
    empty = np.zeros((0, 2))
    out: list[Any] = []
    if run.scans is not None:
        for i in sel:
            s = run.scans[i]
            out.append(end_points(s, stride=st))
        return out
    any_ranges = False
    for i in sel:
        o = (run.records or [])[i]
        if o.ranges is None or o.range_bearings is None:
            out.append(empty)
        else:
            any_ranges = True
            out.append(scan_points(o.ranges, o.range_bearings, stride=st))
    return out if any_ranges else None


def _scan_map(run: Run, n_mapping: int, poses: Any) -> tuple[Any, list[Any] | None]:
    """The :class:`~fingerloc.map.scan_map.ScanMap` of the mapping part's end points (the pose filter's
    stride, as the benchmark's) and those end points; (None, None) without ranges or any return."""
    from ..map.scan_map import ScanMap

    pts = run_end_points(run, np.arange(n_mapping))
    if pts is None or not any(q.shape[0] for q in pts):
        return None, None
    return ScanMap.from_scans(pts, poses[:n_mapping]), pts


@dataclass(slots=True)
class PlaceMap:
    """The result of :func:`make_map`.

    Attributes
    ----------
    model : PlaceModel
        Fitted on the training observations.
    split : PlaceSplit
        Places, training scans and queries (indices into the run).
    labels : list of str
        Place labels, in creation order (place ``j`` is ``labels[j]``).
    training : list of Observation
        The training observations, labelled, in run order.
    preset : ResolvedPreset
    calibration : Calibration
    graph : PlaceGraph
        Places in creation order.
    run_name, run_key : str
        The run's files and content hash (:attr:`Run.key`).
    scan_map : ScanMap or None
        The mapping part's laser end points
        (:class:`~fingerloc.map.scan_map.ScanMap`); ``None``: the run has no
        ranges, or ``make_map(scan=False)``.
    """

    model: Any
    split: PlaceSplit
    labels: list[str]
    training: list[Observation]
    preset: ResolvedPreset
    calibration: Calibration
    graph: PlaceGraph
    run_name: str
    run_key: str
    scan_map: Any = None

    @property
    def positions(self) -> dict[str, tuple[float, float]]:
        """Place centres by label, creation order."""
        return {lab: (float(x), float(y)) for lab, (x, y) in zip(self.labels, self.split.centres, strict=True)}

    def run_record(self) -> dict[str, Any]:
        """What a database stores of the mapped run (to recognise it later)."""
        return {"name": self.run_name, "key": self.run_key, "n_scans": self.split.n_scans, "n_mapping": self.split.n_mapping}

    def loaded(self) -> LoadedMap:
        """The map as :func:`load_map` would read it back from :func:`save_map`'s database, without writing it."""
        from ..map.database import observation_hash

        return LoadedMap(
            self.model,
            list(self.labels),
            np.asarray(self.split.centres, dtype=np.float64).reshape(-1, 2),
            self.preset,
            self.calibration,
            self.graph,
            [self.run_record()],
            {observation_hash(o) for o in self.training},
            self.scan_map,
        )


def make_map(
    run: Run,
    *,
    preset: str = "auto",
    overrides: Mapping[str, Any] | None = None,
    mapping_part: float | None = 0.5,
    until: float | None = None,
    spacing: float = PLACE_SPACING_M,
    radius: float = PLACE_RADIUS_M,
    calibrate: bool = True,
    odometry_error: float | None = None,
    heading: bool = True,
    scan: bool = True,
    on_step: Callable[[str], None] | None = None,
) -> PlaceMap:
    """Places from a run's poses, learned with a preset, with the filters' calibration.

    Parameters
    ----------
    run : Run
        Every item needs a pose.
    preset : str, default "auto"
        A name of :data:`~fingerloc.pipeline.presets.PRESET_NAMES`.
    overrides : mapping, optional
        Explicit model options (JSON form) over the preset's.
    mapping_part, until, spacing, radius
        :func:`~fingerloc.pipeline.places.places_from_trajectory`.
    calibrate : bool, default True
        Fit ``beta`` on the mapping part (two more model fits), then choose the
        pose filter's reliability and tempering along it
        (:func:`~fingerloc.pipeline.tracker.tune_pose_filter`); False keeps the defaults.
    odometry_error : float, optional
        Factor of the simulated wheel-odometry errors used while choosing them:
        by default 1 for CARMEN logs (their poses are corrected ones, as
        ``fingerloc track`` and the benchmark assume), else 0.
    heading : bool, default True
        With ``calibrate``: fit the pose filter's heading model on the
        mapping part (:func:`~fingerloc.pipeline.tracker.with_heading_model`:
        each held-out training view's heading implied at its own place by
        the model fit on the other views, against its recorded heading; two
        more fits) so that ``track --filter pose`` weighs the particles by
        the heading each view implies (the tuning of ``rho`` and the
        tempering then runs with it). Skipped when the views have no poses.
    scan : bool, default True
        When the run's items carry laser ranges: keep the mapping part's
        end points as a :class:`~fingerloc.map.scan_map.ScanMap`
        (:attr:`PlaceMap.scan_map`) and, with ``calibrate``, choose the pose
        filter's ``scan_gamma`` with it on the mapping part. False, or a run
        without ranges (panoramas): no scan map, no scan evidence.
    on_step : callable, optional
        Called with a short text before each stage.

    Returns
    -------
    PlaceMap
    """
    poses = run.poses
    if poses is None:
        raise InvalidParameterError(f"{run.paths[0]}: map needs a pose on every scan / observation")
    note = on_step or (lambda s: None)
    split = places_from_trajectory(
        poses[:, :2], mapping_part=mapping_part, until=until, timestamps=run.timestamps, spacing=spacing, radius=radius
    )
    if split.n_places == 0 or split.n_train == 0:
        raise InvalidParameterError(f"{run.paths[0]}: the mapping part holds no scan (mapping part {split.n_mapping} of {split.n_scans})")
    labels = [place_label(j) for j in range(split.n_places)]
    note(f"extracting features of {split.n_train} training scans")
    raw = run.observations(split.train_idx)
    resolved = resolve_preset(preset, raw, overrides)
    if resolved.features:
        raw = run.observations(split.train_idx, features=resolved.features)
    training = [o.with_label(labels[j]) for o, j in zip(raw, split.train_labels.tolist(), strict=True)]
    note(f"learning {split.n_places} places ({resolved.name})")
    model = resolved.model().fit(training)
    graph, metres = mapping_graph(poses[: split.n_mapping, :2], split.centres, labels)
    scan_map = mapping_points = None
    if scan:
        note(f"mapping the laser end points of {split.n_mapping} scans")
        scan_map, mapping_points = _scan_map(run, split.n_mapping, poses)
    held = None
    if calibrate:
        note("calibrating the filters on the mapping part")
        held = held_out_calibration(
            model_fit_score(resolved.options, raw), split.train_idx, split.train_labels, split.n_places
        )
    beta, rows = (1.0, 0) if held is None else (held.beta, held.rows)
    cal = Calibration(
        beta=float(beta),
        metres_per_move=float(metres),
        temper_metres=float(spacing),
        temper_radians=run.field_of_view(np.arange(split.n_mapping)),
        kidnap=1.0 / (split.n_train + 2),
        radius=float(radius),
        spacing=float(spacing),
        n_train=split.n_train,
        calibration_rows=rows,
    )
    headings = None
    if held is not None and heading and all(o.pose is not None for o in raw):
        note("fitting the heading model on the mapping part")
        opts = resolved.options

        def fit_model(tr: Any, y: Any) -> Any:
            return model_from_options(opts).fit([raw[i] for i in tr.tolist()], [str(v) for v in y.tolist()])

        headings = held_out_headings(fit_model, raw, split.train_labels, held, split.n_places)
        if headings is not None:
            cal = with_heading_model(cal, held, headings, poses[split.train_idx[held.index], 2])
    if held is not None:
        note("choosing the pose filter's reliability and tempering on the mapping part")
        factor = (1.0 if run.kind == "carmen" else 0.0) if odometry_error is None else odometry_error
        scan_args = {}
        if mapping_points is not None:
            scan_args = scan_tuning_inputs(mapping_points, poses[: split.n_mapping], split.train_idx,
                                           split.train_labels, held)  # fmt: skip
        cal, _ = tune_pose_filter(
            Tracker(split.centres, graph, cal), held, split.train_idx, poses[: split.n_mapping], odometry_error=factor,
            headings=headings if TUNE_WITH_HEADING else None, **scan_args,
        )  # fmt: skip
    name = " ".join(str(p) for p in run.paths)
    return PlaceMap(model, split, labels, training, resolved, cal, graph, name, run.key, scan_map)


def save_map(place_map: PlaceMap, path: str | Path) -> int:
    """Write a :class:`PlaceMap` to a place database (replacing the file); returns its size in bytes."""
    from ..map.database import MapInfo, observation_hash, save_model

    pm = place_map
    info = MapInfo(
        preset=pm.preset.to_json(),
        positions=pm.positions,
        calibration=pm.calibration.to_json(),
        content_hashes={observation_hash(o) for o in pm.training},
        runs=[pm.run_record()],
        scan_map=pm.scan_map,
    )
    return save_model(pm.model, path, graph_edges=pm.graph.edges(), info=info)


@dataclass(slots=True)
class LoadedMap:
    """A place database read back: the model and, when it was made by ``map``, the map information.

    Attributes
    ----------
    model : PlaceModel
    labels : list of str
        Places in creation order when positions are stored, else the model's order.
    positions : ndarray, shape (P, 2) or None
        ``None`` when the database stores none, or not for every place (places
        added by ``learn`` after ``map``).
    preset : ResolvedPreset or None
    calibration : Calibration or None
    graph : PlaceGraph
        Places in ``labels`` order.
    runs : list of dict
    content_hashes : set of str
    scan_map : ScanMap or None
        The mapping run's laser end points (schema version 4); ``None``: none
        stored, or read with ``load_map(scan=False)``.
    """

    model: Any
    labels: list[str]
    positions: Any
    preset: ResolvedPreset | None
    calibration: Calibration | None
    graph: PlaceGraph
    runs: list[dict[str, Any]]
    content_hashes: set[str]
    scan_map: Any = None

    def tracker(self, *, scan: bool = True, **options: Any) -> Tracker:
        """A :class:`Tracker` with the stored positions, calibration and (``scan``) scan map.

        ``options``: :class:`Tracker`'s (``n_particles``, ``uniform_mix``, ``scan_map``).
        """
        if self.positions is None or self.calibration is None:
            raise InvalidParameterError("the database holds no place positions or calibration (make it with 'fingerloc map')")
        options.setdefault("scan_map", self.scan_map if scan else None)
        return Tracker(self.positions, self.graph, self.calibration, **options)

    def mapped_run(self, key: str) -> dict[str, Any] | None:
        """The stored mapped run with this content key, if any."""
        return next((r for r in self.runs if r.get("key") == key), None)


def load_map(path: str | Path, *, scan: bool = True) -> LoadedMap:
    """Read a place database with its map information (any readable schema version).

    ``scan``: read the stored scan map too (False: ``scan_map`` is None).
    """
    from ..map.database import load_model, read_map_info
    from ..map.graph import load_graph

    model = load_model(path)
    info = read_map_info(path, scan_map=scan)
    classes = [str(c) for c in model.classes_]
    positions = None
    labels = classes
    if info.positions and set(info.positions) == set(classes):  # places learned later have no position
        labels = list(info.positions)
        positions = np.array([info.positions[lab] for lab in labels], dtype=np.float64).reshape(-1, 2)
    preset = None if info.preset is None else ResolvedPreset.from_json(info.preset)
    cal = None if info.calibration is None else Calibration.from_json(info.calibration)
    graph = load_graph(path, labels)
    hashes = info.content_hashes
    if not hashes:  # version 1: hash the stored observations
        from ..map.database import observation_hash

        hashes = {observation_hash(o) for p in model.places_.values() for o in p.observations}
    return LoadedMap(model, labels, positions, preset, cal, graph, info.runs, hashes, info.scan_map)
