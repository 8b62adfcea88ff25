"""The laser extractor's tuning (:class:`LaserParams`): one frozen dataclass, every field checked.

The fields are the keywords of
:func:`fingerloc.features.laser.extract_laser_features` (and of
``observation_from_scan``); presets store some of them with a map.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from ..errors import InvalidParameterError

__all__ = ["LaserParams"]


@dataclass(frozen=True, slots=True)
class LaserParams:
    """Tuning of the laser extractor; every field is a keyword of :func:`extract_laser_features`.

    Parameters
    ----------
    range_sigma : float, default 0.015
        Standard deviation of the range noise, metres.
    breakpoint_angle_deg : float, default 7
        Smallest incidence angle (between beam and surface) at which a
        surface stays one segment; grazing views break it. Degrees.
    max_bridge_beams : int, default 2
        Runs of at most this many beams without a return are bridged when the
        returns on both sides are close (isolated drop-outs).
    split_tol : float, default 0.04
        Split-and-merge tolerance at zero range, metres.
    split_tol_rel : float, default 0.01
        Part of the range added to ``split_tol`` (1 % of the range).
    min_line_points : int, default 5
        Fewest beams a fitted line may have.
    min_line_length : float, default 0.2
        Shortest fitted line, metres.
    merge_angle_deg : float, default 6
        Neighbouring lines closer than this in direction are merged when the
        joint fit stays within tolerance. Degrees.
    corner_min_angle_deg : float, default 35
        Two lines meeting at less than this (or more than 180 minus this)
        degrees do not make a corner.
    corner_max_dist : float, default 0.3
        Largest distance, metres, between the lines' intersection and the
        lines' facing end points for a corner.
    bridge_min_points : int, default 2
        Returns needed on a surface seen edge-on between two segments to join
        them by two corners instead of ending them at a jump...
    bridge_max_length : float, default 1.0
        ...when that surface is at most this long (metres)...
    bridge_max_gap : float, default 0.6
        ...and no stretch of it longer than this part of its length lacks a return.
    min_segment_points : int, default 3
        Segments with fewer beams are clutter: they give no feature (but
        still occlude their neighbours).
    min_extremity_extent : float, default 0.1
        Smallest extent (metres, end point to end point) of a segment whose
        ends count as extremities.
    extremity_max_tail : float, default 0.3
        A segment end is a line extremity only when a fitted line ends within
        this distance (metres) of it: a short unfitted tail (a door jamb seen
        edge-on) is allowed, a ragged clutter end is not.
    beacon_threshold : float or None, default None
        Absolute intensity above which a beam is bright, in the sensor's unit.
        ``None``: adapt to the scan (see ``beacon_ratio``, ``beacon_global_ratio``).
    beacon_ratio : float, default 2
        Adaptive threshold: a bright beam is at least this factor above the
        median intensity of the beams around it (``beacon_window_m``)...
    beacon_global_ratio : float, default 2.5
        ...and at least this factor above the scan's median intensity
        (retro-reflectors return 3 to 10 times a wall; a glossy surface at
        twice the median is not a beacon).
    beacon_window_m : float, default 0.4
        Half width of the local background window, metres at the beam's
        range (so wider in bearing for near beams): at least twice the
        widest reflector (15 cm), so that the window's median is background.
    beacon_window_deg : float, default 3
        ...and at least this many degrees, and at least three beams, on each
        side (far beams); at most 60 degrees.
    beacon_gap_deg : float, default 1
        Bright beams at most this far apart (degrees; at least two beam
        steps) join one beacon: dim or missing beams inside a reflector.
    beacon_min_width : float, default 0.04
        A beacon has at least as many bright beams as this width (metres)
        spans at its range, and at least one: on a dense scanner a lone
        bright beam, or a few on a glossy surface, is noise, not a reflector
        (retro-reflective targets are 4 to 15 cm wide).
    beacon_max_width : float, default 0.5
        A bright run wider than this (metres) is a reflective surface, not a
        beacon.
    beacon_max_fraction : float, default 0.2
        When more than this part of the returns is bright, the adaptive
        threshold is not trusted and no beacon is reported.
    """

    range_sigma: float = 0.015
    breakpoint_angle_deg: float = 7.0
    max_bridge_beams: int = 2
    split_tol: float = 0.04
    split_tol_rel: float = 0.01
    min_line_points: int = 5
    min_line_length: float = 0.2
    merge_angle_deg: float = 6.0
    corner_min_angle_deg: float = 35.0
    corner_max_dist: float = 0.3
    bridge_min_points: int = 2
    bridge_max_length: float = 1.0
    bridge_max_gap: float = 0.6
    min_segment_points: int = 3
    min_extremity_extent: float = 0.1
    extremity_max_tail: float = 0.3
    beacon_threshold: float | None = None
    beacon_ratio: float = 2.0
    beacon_global_ratio: float = 2.5
    beacon_window_m: float = 0.4
    beacon_window_deg: float = 3.0
    beacon_gap_deg: float = 1.0
    beacon_min_width: float = 0.04
    beacon_max_width: float = 0.5
    beacon_max_fraction: float = 0.2

    def __post_init__(self) -> None:
        positive = (
            "range_sigma",
            "split_tol",
            "min_line_length",
            "corner_max_dist",
            "beacon_ratio",
            "beacon_global_ratio",
            "bridge_max_length",
            "bridge_max_gap",
            "beacon_max_width",
            "beacon_max_fraction",
            "beacon_window_m",
            "beacon_window_deg",
            "beacon_gap_deg",
            "beacon_min_width",
        )
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InvalidParameterError(f"{name} must be a positive number, got {v!r}")
        for name in ("split_tol_rel", "min_extremity_extent", "extremity_max_tail"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise InvalidParameterError(f"{name} must be a number >= 0, got {v!r}")
        if not 0 < self.breakpoint_angle_deg < 90:
            raise InvalidParameterError(
                f"breakpoint_angle_deg must be in (0, 90) degrees, got {self.breakpoint_angle_deg!r}"
            )
        if not 0 <= self.merge_angle_deg < 45:
            raise InvalidParameterError(f"merge_angle_deg must be in [0, 45) degrees, got {self.merge_angle_deg!r}")
        if not 0 < self.corner_min_angle_deg < 90:
            raise InvalidParameterError(
                f"corner_min_angle_deg must be in (0, 90) degrees, got {self.corner_min_angle_deg!r}"
            )
        for name, lo in (
            ("max_bridge_beams", 0),
            ("min_line_points", 2),
            ("min_segment_points", 1),
            ("bridge_min_points", 1),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise InvalidParameterError(f"{name} must be an integer >= {lo}, got {v!r}")
        if self.beacon_threshold is not None and not np.isfinite(self.beacon_threshold):
            raise InvalidParameterError(f"beacon_threshold must be finite or None, got {self.beacon_threshold!r}")

    @classmethod
    def from_kwargs(cls, params: dict[str, Any]) -> LaserParams:
        """Build from keyword arguments, naming any unknown one."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(params) - known)
        if unknown:
            raise InvalidParameterError(
                f"unknown laser feature parameter {unknown[0]!r} (known: {', '.join(sorted(known))})"
            )
        return cls(**params)
