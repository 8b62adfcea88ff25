"""Places from fingerprints alone: a topological map of a run without any pose.

:func:`places_from_trajectory <fingerloc.pipeline.places.places_from_trajectory>`
makes a place every two metres of the robot's poses. Here the views
themselves decide, with the place model's own evidence
(:mod:`fingerloc.pipeline.view_distances`, :mod:`fingerloc.pipeline.revisits`):

1. **Keyframes.** The views that differ from the previous keyframe by at
   least :data:`~fingerloc.pipeline.view_distances.KEYFRAME_CHANGE` of the
   distance between unrelated views (a robot standing still or a fast
   scanner adds no keyframe). A view that is no keyframe belongs to the place
   of the keyframe before it.
2. **The unit of change**: ``c``, the median distance ``D[k, k - 1]`` between
   consecutive keyframes (the run's own typical change from one view to the
   next; ``D`` in nats of the model's likelihood).
3. **Walk the keyframes in order.** Keyframe ``k`` is a *revisit* when the
   revisit filter gives its best earlier keyframe ``j`` (at least
   :data:`~fingerloc.pipeline.revisits.RECENT_VIEWS` keyframes back) a
   posterior probability of at least ``join`` (:data:`JOIN_PROBABILITY`,
   0.95) and ``j`` lies in another place than the current one: ``k`` joins
   ``j``'s place (a loop closure) and the change count restarts. Otherwise the
   change ``D[k, k - 1]`` is added to the current place's count; when the count
   exceeds ``change * c`` (:data:`PLACE_CHANGE`, 4.5) the view is no longer the
   current place and no earlier place is recognised: ``k`` starts a new place.
4. **The place graph** counts the passages between the places of consecutive
   keyframes (:meth:`~fingerloc.map.graph.PlaceGraph.from_sequence`); a loop
   closure is an edge to an older place.
5. **The model** (the preset's) learns every place from its keyframes; each
   place also gets a consensus fingerprint
   (:func:`~fingerloc.terms.fingerprint.consensus_fingerprint`). The filters
   use the model's posterior as it is (``beta = 1``; a fit on held-out
   keyframes is an option, ``calibrate=True``).

No threshold comes from poses: ``c`` and the scales are the run's own,
``change``, ``join`` and the filter's constants were chosen once on four
CARMEN logs (docs/LOOPS.md). Poses, when the run has them, only score the
result (:func:`place_purity`). The result saves to a place database without
place positions (:meth:`FingerprintMap.save`) that ``fingerloc localize`` and
the discrete place filter use like any other.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._types import IArray
from ..config import Config
from ..errors import InvalidParameterError
from ..map.graph import PlaceGraph
from ..observation import Observation
from ..validation import check_int
from .calibration import Calibration
from .placemap import PlaceMap
from .places import mapping_count, place_label
from .presets import ResolvedPreset, resolve_preset
from .readers import Run
from .revisits import LEAVE_PROBABILITY, RECENT_VIEWS, background_log_likelihood, revisit_filter, square_distances

__all__ = [
    "JOIN_PROBABILITY",
    "PLACE_CHANGE",
    "PURITY_RADIUS_M",
    "FingerprintMap",
    "fingerprint_places",
    "place_purity",
    "places_from_fingerprints",
]

#: A place ends when the change since it began exceeds this many typical view-to-view changes.
PLACE_CHANGE = 4.5
#: A keyframe joins an earlier place when the revisit filter names it with at least this probability.
JOIN_PROBABILITY = 0.95
#: Place purity: a view counts as pure within this distance of its place's median position, metres.
PURITY_RADIUS_M = 3.0


def _positive(name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
        raise InvalidParameterError(f"{name} must be a positive number, got {v!r}")
    return float(v)


def fingerprint_places(
    distances: Any,
    *,
    change: float = PLACE_CHANGE,
    join: float = JOIN_PROBABILITY,
    recent: int = RECENT_VIEWS,
    leave: float = LEAVE_PROBABILITY,
) -> tuple[IArray, IArray]:
    """Places of a sequence of keyframes from their distances (module docstring, steps 2-3).

    Parameters
    ----------
    distances : array_like, shape (k, k)
        ``D`` between the keyframes, in order
        (:func:`~fingerloc.pipeline.view_distances.view_distance_matrix`).
    change : float, default PLACE_CHANGE
        Typical view-to-view changes a place may hold (> 0).
    join : float, default JOIN_PROBABILITY
        Revisit probability that joins an earlier place, in (0, 1]; above 1: never.
    recent, leave
        The revisit filter's (:func:`~fingerloc.pipeline.revisits.revisit_filter`).

    Returns
    -------
    place : ndarray of int, shape (k,)
        Each keyframe's place, numbered in creation order from 0.
    closures : ndarray of int, shape (m, 2)
        The loop closures: rows ``(keyframe, earlier keyframe it revisits)``.
    """
    d = square_distances(distances)
    n = d.shape[0]
    a = _positive("change", change)
    if isinstance(join, bool) or not isinstance(join, (int, float)) or not join > 0:
        raise InvalidParameterError(f"join must be a probability > 0, got {join!r}")
    if n == 0:
        return np.zeros(0, np.int64), np.zeros((0, 2), np.int64)
    steps = d[np.arange(1, n), np.arange(n - 1)]
    unit = float(np.median(steps)) if steps.size else 1.0
    unit = unit if unit > 0 else 1.0
    r = check_int("recent", recent, minimum=0)
    post = revisit_filter(d, background_log_likelihood(d, r), np.maximum(0, np.arange(n) - r), leave=leave)
    place = np.zeros(n, dtype=np.int64)
    closures: list[tuple[int, int]] = []
    cur, count, n_places = 0, 0.0, 1
    log_join = math.log(join) if join <= 1 else math.inf
    for k in range(1, n):
        j = int(post.best[k])
        if j >= 0 and post.log_probability[k] >= log_join and place[j] != cur:
            cur = int(place[j])
            count = 0.0
            closures.append((k, j))
        else:
            count += float(d[k, k - 1])
            if count > a * unit:
                cur, n_places, count = n_places, n_places + 1, 0.0
        place[k] = cur
    return place, np.asarray(closures, dtype=np.int64).reshape(-1, 2)


def place_purity(assignment: Any, positions: Any, radius: float = PURITY_RADIUS_M) -> float:
    """Share of the views lying within ``radius`` metres of their place's median position (scoring only).

    Parameters
    ----------
    assignment : array_like of int, shape (n,)
        Each view's place (negative: no place, not counted).
    positions : array_like, shape (n, 2)
        The views' true positions, metres.
    radius : float, default PURITY_RADIUS_M

    Returns
    -------
    float
        Over every placed view (each view weighs the same); NaN when none is placed.
    """
    lab = np.asarray(assignment, dtype=np.int64).reshape(-1)
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    if pos.shape[0] != lab.size:
        raise InvalidParameterError(f"one position per view is needed, got {pos.shape[0]} for {lab.size}")
    rad = _positive("radius", radius)
    placed = lab >= 0
    if not placed.any():
        return float("nan")
    good = 0
    for p in np.unique(lab[placed]):
        q = pos[lab == p]
        med = np.median(q, axis=0)
        good += int(np.count_nonzero(np.hypot(q[:, 0] - med[0], q[:, 1] - med[1]) <= rad))
    return good / int(placed.sum())


@dataclass(slots=True)
class FingerprintMap:
    """The result of :func:`places_from_fingerprints`.

    Attributes
    ----------
    model : PlaceModel
        Fitted on the keyframes, one place per label.
    labels : list of str
        Place labels in creation order (place ``j`` is ``labels[j]``).
    training : list of Observation
        The keyframes' observations, labelled, in run order.
    preset : ResolvedPreset
    calibration : Calibration
        ``beta`` (held-out keyframes), ``kidnap``, ``n_train``; no metric field is meaningful.
    graph : PlaceGraph
        Passages between the places of consecutive keyframes.
    assignment : ndarray of int, shape (n_mapping,)
        Each view's place (index into ``labels``) over the mapping part.
    keyframes : ndarray of int, shape (k,)
        The keyframes' indices in the run.
    closures : ndarray of int, shape (m, 2)
        Loop closures as run indices: ``(view, earlier view it revisits)``.
    consensus : list of Fingerprint or None
        Per place, its consensus fingerprint (None when not computed: no string term, or ``consensus=False``).
    scales : dict of str -> float
        Each distance term's ``lambda``.
    unit : float
        The typical change between consecutive keyframes (nats).
    run_name, run_key : str
    n_scans, n_mapping : int
    """

    model: Any
    labels: list[str]
    training: list[Observation]
    preset: ResolvedPreset
    calibration: Calibration
    graph: PlaceGraph
    assignment: IArray
    keyframes: IArray
    closures: IArray
    consensus: list[Any]
    scales: dict[str, float]
    unit: float
    run_name: str
    run_key: str
    n_scans: int
    n_mapping: int

    @property
    def n_places(self) -> int:
        """Number of places."""
        return len(self.labels)

    def run_record(self) -> dict[str, Any]:
        """What a database stores of the mapped run (to recognise it later)."""
        return {"name": self.run_name, "key": self.run_key, "n_scans": self.n_scans, "n_mapping": self.n_mapping,
                "places": "fingerprints"}  # fmt: skip

    def place_map(self, config: Config | None = None) -> PlaceMap:
        """The map as a :class:`~fingerloc.pipeline.placemap.PlaceMap` without place positions.

        ``localize``, the discrete place filter (``track --filter places``) and
        :meth:`PlaceMap.save` use it like any other; the pose filter needs
        positions and refuses it. ``config``: stored with the map (default
        :class:`~fingerloc.config.Config` with this map's mapping part).
        """
        from ..map.database import observation_hash

        cfg = config if config is not None else Config()
        return PlaceMap(
            self.model, list(self.labels), None, self.preset, self.calibration, cfg, self.graph,
            [self.run_record()], {observation_hash(o) for o in self.training}, None, None, list(self.training),
        )  # fmt: skip

    def save(self, path: str | Path) -> int:
        """Write the map to a place database (replacing the file), without place positions; returns its size in bytes."""
        return self.place_map().save(path)


def places_from_fingerprints(
    run: Run,
    *,
    preset: str = "auto",
    overrides: Mapping[str, Any] | None = None,
    mapping_part: float | None = 0.5,
    until: float | None = None,
    change: float = PLACE_CHANGE,
    join: float = JOIN_PROBABILITY,
    keyframe_change: float | None = None,
    calibrate: bool = False,
    consensus: bool = True,
    on_step: Callable[[str], None] | None = None,
) -> FingerprintMap:
    """A place map of a run's mapping part from its views alone (module docstring).

    Parameters
    ----------
    run : Run
        Any run: a laser log or bag (with or without poses), JSON Lines
        observations (e.g. panoramas in order).
    preset : str, default "auto"
        A name of :data:`~fingerloc.pipeline.presets.PRESET_NAMES`.
    overrides : mapping, optional
        Explicit model options (JSON form) over the preset's.
    mapping_part, until
        The mapping part (:func:`~fingerloc.pipeline.places.mapping_count`):
        by default the first half, as ``fingerloc map``.
    change : float, default PLACE_CHANGE
    join : float, default JOIN_PROBABILITY
        Above 1: no loop closure (a chain of places).
    keyframe_change : float, optional
        :func:`~fingerloc.pipeline.view_distances.keyframes`' ``change``
        (default :data:`~fingerloc.pipeline.view_distances.KEYFRAME_CHANGE`; 0: every view).
    calibrate : bool, default False
        Fit the filters' likelihood scale ``beta`` on held-out keyframes (two
        more model fits). Off by default: a held-out keyframe is scored
        against its place's neighbours in time, which the rule made alike, so
        the fit distrusts the model (on four laser logs it gave beta 0.02 to
        0.83 and a place filter worse than single-shot; with ``beta = 1`` the
        place filter matches or beats it, docs/LOOPS.md).
    consensus : bool, default True
        Give each place its consensus fingerprint (when the model weighs the
        fingerprint string; a greedy median-string search, the slowest step
        for long strings).
    on_step : callable, optional
        Called with a short text before each stage.

    Returns
    -------
    FingerprintMap
    """
    from ..terms import FingerprintTerm, consensus_fingerprint
    from .calibration import held_out_calibration, model_fit_score
    from .view_distances import KEYFRAME_CHANGE, distance_term_weights, keyframes, view_distance_matrix

    note = on_step or (lambda s: None)
    n = len(run)
    n_map = mapping_count(n, mapping_part=mapping_part, until=until, timestamps=run.timestamps)
    if n_map < 1:
        raise InvalidParameterError(f"{run.paths[0]}: the mapping part holds no view (mapping part {n_map} of {n})")
    note(f"reading the features of {n_map} views")
    raw = run.observations(np.arange(n_map))
    resolved = resolve_preset(preset, raw, overrides)
    if resolved.features:
        raw = run.observations(np.arange(n_map), features=resolved.features)
    note("choosing keyframes")
    keys = keyframes(raw, resolved.options, change=KEYFRAME_CHANGE if keyframe_change is None else keyframe_change)
    kobs = [raw[i] for i in keys.tolist()]
    note(f"comparing {keys.size} keyframes")
    d, scales = view_distance_matrix(kobs, resolved.options)
    place, closures = fingerprint_places(d, change=change, join=join)
    steps = d[np.arange(1, keys.size), np.arange(keys.size - 1)]
    unit = float(np.median(steps)) if steps.size else 1.0
    n_places = int(place.max()) + 1 if place.size else 0
    labels = [place_label(j) for j in range(n_places)]
    training = [o.with_label(labels[j]) for o, j in zip(kobs, place.tolist(), strict=True)]
    note(f"learning {n_places} places ({resolved.name})")
    model = resolved.model().fit(training)
    graph = PlaceGraph.from_sequence(labels, [labels[j] for j in place.tolist()])
    owner = np.searchsorted(keys, np.arange(n_map), side="right") - 1
    assignment = place[owner]
    cons: list[Any] = [None] * n_places
    fp = model.terms_.get("Fp")
    if consensus and isinstance(fp, FingerprintTerm) and distance_term_weights(resolved.options).get("Fp", 0.0) > 0:
        note("consensus fingerprints")
        cons = [consensus_fingerprint(fps, costs=fp.costs, cyclic=fp.cyclic) if fps else None
                for fps in fp.fingerprints_]  # fmt: skip
    beta, rows = 1.0, 0
    if calibrate and n_places > 1:
        note("fitting the likelihood scale on held-out keyframes")
        held = held_out_calibration(model_fit_score(resolved.options, kobs), keys, place, n_places)
        beta, rows = held.beta, held.rows
    cal = Calibration(
        beta=float(beta),
        metres_per_move=None,
        kidnap=1.0 / (keys.size + 2),
        n_train=int(keys.size),
        calibration_rows=int(rows),
    )
    return FingerprintMap(
        model=model,
        labels=labels,
        training=training,
        preset=resolved,
        calibration=cal,
        graph=graph,
        assignment=np.asarray(assignment, dtype=np.int64),
        keyframes=keys,
        closures=keys[closures] if closures.size else np.zeros((0, 2), np.int64),
        consensus=cons,
        scales=scales,
        unit=unit,
        run_name=" ".join(str(p) for p in run.paths),
        run_key=run.key,
        n_scans=n,
        n_mapping=n_map,
    )
