"""A place map from a recorded run: places, model, graph and calibration in one call (``fingerloc map``).

:func:`make_map` applies :func:`~fingerloc.pipeline.places.places_from_trajectory`
to a run's poses, labels the training scans with their nearest place
(:func:`~fingerloc.pipeline.places.place_label`), learns them with a preset and
calibrates the filters on the mapping part
(:func:`~fingerloc.pipeline.calibrate.calibrate_map`: the place graph of the
visiting order, the likelihood scale, the heading model, the pose filter's
tuning). The result is a :class:`~fingerloc.pipeline.placemap.PlaceMap`.

When the run's items carry laser ranges (a CARMEN log, a bag, JSON Lines
with ``scan``), the map also keeps the mapping part's laser end points as a
:class:`~fingerloc.map.scan_map.ScanMap` (:attr:`PlaceMap.scan_map`): the
pose filter weighs its particles by how well each observation's end points
(:func:`run_end_points`) fit it, with the power ``Calibration.scan_gamma``
chosen on the mapping part (0: off).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ..config import Config
from ..errors import InvalidParameterError
from .calibrate import MappingPart, calibrate_map
from .calibration import model_fit_headings, model_fit_score_of
from .placemap import PlaceMap
from .places import place_label, places_from_trajectory
from .presets import model_from_options, resolve_preset
from .readers import Run

__all__ = ["make_map", "run_end_points"]


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


def make_map(
    run: Run,
    config: Config | None = None,
    *,
    preset: str = "auto",
    overrides: Mapping[str, Any] | None = None,
    places: str = "poses",
    on_step: Callable[[str], None] | None = None,
) -> PlaceMap:
    """Places from a run's poses (or its fingerprints), learned with a preset, with the filters' calibration.

    Parameters
    ----------
    run : Run
        Every item needs a pose.
    config : Config, optional
        ``config.places``: the mapping part and the places' spacing and radius
        (:func:`~fingerloc.pipeline.places.places_from_trajectory`);
        ``config.calibration``: what is fitted on the mapping part
        (:func:`~fingerloc.pipeline.calibrate.calibrate_map`: ``beta``, the heading
        model, the pose filter's tuning, the scan evidence); ``config.pose_filter``:
        how the map tracks. Default :class:`~fingerloc.config.Config()`.
    preset : str, default "auto"
        A name of :data:`~fingerloc.pipeline.presets.PRESET_NAMES`.
    overrides : mapping, optional
        Explicit model options (JSON form) over the preset's.
    places : {"poses", "fingerprints"}, default "poses"
        ``"fingerprints"``: the places come from the views alone, no pose
        (:func:`~fingerloc.pipeline.topology.places_from_fingerprints`, with
        ``config.places``' mapping part); the map has no place positions
        (localize and the place filter use it).
    on_step : callable, optional
        Called with a short text before each stage.

    Returns
    -------
    PlaceMap
        With ``split``, ``training`` and ``tuning`` (what a map read back lacks).
    """
    cfg = Config() if config is None else config
    if places not in ("poses", "fingerprints"):
        raise InvalidParameterError(f"places must be 'poses' or 'fingerprints', got {places!r}")
    if places == "fingerprints":
        from .topology import places_from_fingerprints

        fm = places_from_fingerprints(
            run, preset=preset, overrides=overrides, mapping_part=cfg.places.mapping_part, until=cfg.places.until_s,
            on_step=on_step,
        )  # fmt: skip
        return fm.place_map(cfg.with_(calibration={"enabled": False}))
    pc, cc = cfg.places, cfg.calibration
    poses = run.poses
    if poses is None:
        raise InvalidParameterError(f"{run.paths[0]}: map needs a pose on every scan / observation")
    note = on_step or (lambda s: None)
    split = places_from_trajectory(
        poses[:, :2], mapping_part=pc.mapping_part, until=pc.until_s, timestamps=run.timestamps,
        spacing=pc.spacing_m, radius=pc.radius_m,
    )  # fmt: skip
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
    opts = resolved.options
    folds: dict[bytes, Any] = {}  # the held-out folds' models: fit once for their scores and their headings

    def fit_model(tr: Any, y: Any) -> Any:
        key = np.asarray(tr, dtype=np.int64).tobytes() + b"|" + np.asarray(y, dtype=np.int64).tobytes()
        if key not in folds:
            folds[key] = model_from_options(opts).fit([raw[i] for i in tr.tolist()], [str(v) for v in y.tolist()])
        return folds[key]

    fit_score = model_fit_score_of(fit_model, raw)
    fit_headings = model_fit_headings(fit_model, raw) if all(o.pose is not None for o in raw) else None
    mapping = MappingPart(
        split.train_idx, split.train_labels, split.centres, poses[: split.n_mapping], run.field_of_view(np.arange(split.n_mapping)),
        labels, run_end_points(run, np.arange(split.n_mapping)) if cc.scan else None,
    )  # fmt: skip
    factor = cc.odometry_error
    if factor is None:  # CARMEN logs hold corrected poses: their increments are an odometry without error
        factor = 1.0 if run.kind == "carmen" else 0.0
    mc = calibrate_map(fit_score, mapping, cfg, fit_headings=fit_headings, odometry_error=factor, on_step=note)
    folds.clear()
    from ..map.database import observation_hash

    name = " ".join(str(p) for p in run.paths)
    record = {"name": name, "key": run.key, "n_scans": split.n_scans, "n_mapping": split.n_mapping}
    return PlaceMap(
        model, labels, np.asarray(split.centres, dtype=np.float64).reshape(-1, 2), resolved, mc.calibration, cfg,
        mc.graph, [record], {observation_hash(o) for o in training}, mc.scan_map, split, training, mc.tuning,
    )  # fmt: skip
