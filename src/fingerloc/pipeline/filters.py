"""The filters of a map, built from what it learned (:class:`Calibration`) and its settings (:class:`Config`).

One place builds them for every caller: the streaming tracker
(:mod:`fingerloc.pipeline.tracker`), the tuning on the mapping part
(:mod:`fingerloc.pipeline.calibrate`) and the real-log benchmark.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..config import Config
from ..map.driver import Augmented, Challenger, PoseTracking, SensorReset, Strategy
from ..map.filter import MarkovFilter, SharedPlaceSteps, TransitionModel
from ..map.graph import PlaceGraph
from ..map.pose_filter import PoseFilter
from ..map.scan_map import ScanMap
from .calibration import Calibration

__all__ = ["place_filter_of", "place_transition_of", "pose_filter_of", "pose_tracking", "strategy_of", "transition_of"]


def transition_of(graph: PlaceGraph, calibration: Calibration, config: Config, *, uniform_mix: float | None = None) -> TransitionModel:
    """The place filter's transition model over ``graph``'s places (uniform when it has no edge).

    ``uniform_mix``: the uniform mixing per step (default ``1 / (counted steps + 2)``,
    :meth:`~fingerloc.map.filter.TransitionModel.from_graph`).
    """
    if graph.graph.number_of_edges() == 0:
        return TransitionModel.uniform(graph.n_places)
    return TransitionModel.from_graph(
        graph, alpha=config.pose_filter.alpha, uniform_mix=uniform_mix, metres_per_move=calibration.metres_per_move
    )


def place_transition_of(
    graph: PlaceGraph, calibration: Calibration, config: Config, centres: Any = None, *, uniform_mix: float | None = None
) -> TransitionModel:
    """The transitions of the filter over places (``filter="places"``): with the places' positions the metric
    kernel (:meth:`~fingerloc.map.filter.TransitionModel.from_positions`, spread = the map's place spacing), else
    the graph's chain (:func:`transition_of`).

    The uniform mixing per step is the graph's (``1 / (counted steps + 2)``) unless given. The graph's chain
    moves on at the mapping part's mean rate whatever the robot sees and lags a place behind at place changes;
    the kernel lets the views decide between neighbours (docs/RESULTS.md).
    """
    if centres is None:
        return transition_of(graph, calibration, config, uniform_mix=uniform_mix)
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    eps = 1.0 / (float(graph.count_matrix().sum()) + 2.0) if uniform_mix is None else float(uniform_mix)
    return TransitionModel.from_positions(c, float(calibration.spacing), uniform_mix=eps)


def place_filter_of(transition: TransitionModel, place_steps: SharedPlaceSteps | None = None) -> MarkovFilter:
    """A discrete filter over ``transition`` (replaying ``place_steps``' beliefs while its calls match)."""
    return MarkovFilter(transition) if place_steps is None else place_steps.filter(transition)


def pose_filter_of(
    centres: Any,
    calibration: Calibration,
    config: Config,
    *,
    seed: int = 0,
    rng: np.random.Generator | None = None,
    scan_map: ScanMap | None = None,
    kidnap: float | None = None,
) -> PoseFilter:
    """A fresh pose filter over the places (seeded; ``rng``: this generator instead).

    ``scan_map``: the map's laser end points, weighed with the calibration's
    ``scan_gamma`` (``None``: no scan evidence). ``kidnap`` overrides the
    calibration's kidnapping probability.
    """
    c, pf = calibration, config.pose_filter
    return PoseFilter(
        centres,
        c.radius,
        n_particles=pf.n_particles,
        kidnap=c.kidnap if kidnap is None else kidnap,
        outlier=c.outlier,
        off_place=c.off_place,
        heading=c.heading,
        scan_map=scan_map,
        scan_gamma=c.scan_gamma if scan_map is not None else 0.0,
        fresh_factor=pf.scan_fresh,
        lost_fit=c.lost_fit,
        lost_kidnap=c.lost_kidnap,
        lost_after=pf.lost_after,
        lost_statistic=pf.lost_statistic,
        lost_uniform=pf.lost_uniform,
        lost_uniform_share=pf.lost_uniform_share,
        random_state=seed if rng is None else rng,
    )


def strategy_of(config: Config) -> Strategy:
    """The driver's strategy of ``config.pose_filter.strategy`` (``None``: the plain update)."""
    pf = config.pose_filter
    if pf.strategy == "challenger":
        return Challenger(switch_nats=pf.challenger_switch_nats)
    if pf.strategy == "reset":
        return SensorReset(pf.reset_nats)
    if pf.strategy == "augmented":
        return Augmented()
    return None


def pose_tracking(
    pose_filter: PoseFilter,
    transition: TransitionModel,
    calibration: Calibration,
    config: Config,
    *,
    place_steps: SharedPlaceSteps | None = None,
    strategy: Strategy | str = "config",
) -> PoseTracking:
    """The driver of ``pose_filter`` with the map's place filter, tempering and answer rules.

    ``place_steps``: the place filter's beliefs shared with other runs on the
    same steps (the tuning on the mapping part; the same results).
    ``strategy``: ``"config"`` (default) for :func:`strategy_of`, or a strategy itself.
    """
    c, pf = calibration, config.pose_filter
    relocalize = pf.relocalize
    needs_places = relocalize or pf.tie_break is not None
    return PoseTracking(
        pose_filter,
        place_filter=place_filter_of(transition, place_steps) if needs_places else None,
        relocalize=relocalize,
        temper=(c.temper_metres, c.temper_radians) if pf.temper else None,
        heading_temper=(c.heading_temper_metres, c.temper_radians) if pf.temper and c.heading_temper_metres > 0 else None,
        start_at_first_observation=pf.start_at_first_observation,
        gap_metres=pf.gap_m,
        strategy=strategy_of(config) if isinstance(strategy, str) else strategy,
        hold_margin=pf.hold_margin,
        tie_break=pf.tie_break,
    )
