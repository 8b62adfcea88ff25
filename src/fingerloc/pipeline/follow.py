"""A run tracked as it arrives: stream items (:mod:`fingerloc.io.stream`) through the streaming tracker, step for
step as ``PlaceMap.track`` tracks the same run read from a file.

For each item, what offline ``track`` decides from the whole run is decided
from the item alone:

* **truth**: a labelled observation's label when it names a place; else the
  place whose centre is nearest to the item's pose, within the map's radius;
* **observe** (``observe="queries"``, the default): an item with a pose and no
  label observes only when it has a true place (the others only predict), as
  offline; ``"all"``, a labelled observation, or an item without a pose: always;
* **motion**: the differences of the items' poses (a log's poses, as offline),
  or of their odometry poses when they have no pose; with ``odometry_error``
  the tracker adds simulated wheel-odometry errors to them, one step at a time.

A stream is tracked from its first item: the mapping part of the run a map was
made from is skipped by ``PlaceMap.track`` (it knows the run's content), not
here.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from ..io.stream import StreamItem
from .placemap import PlaceMap, check_track_options
from .places import nearest_within
from .tracker import Answer, Tracker

__all__ = ["StreamStepper", "track_stream"]

class StreamStepper:
    """One :meth:`step` per stream item: the item's truth, observe flag and motion (module docstring).

    Parameters
    ----------
    place_map : PlaceMap
    tracker : Tracker
        Made by ``place_map.tracker(...)``.
    observe : {"queries", "all"}, default "queries"
    """

    def __init__(self, place_map: PlaceMap, tracker: Tracker, *, observe: str = "queries") -> None:
        check_track_options(observe=observe)
        self.tracker = tracker
        self.observe = observe
        self.labels = list(place_map.labels)
        self._known = set(self.labels)
        self._centres = None if place_map.positions is None else np.asarray(place_map.positions, dtype=np.float64)
        self._radius = None if place_map.calibration is None else float(place_map.calibration.radius)

    def _labelled(self, item: StreamItem) -> bool:
        return item.observation is not None and item.observation.label is not None

    def truth(self, item: StreamItem) -> str | None:
        """The item's true place: an observation's label, or the place within the radius of the item's pose."""
        if self._labelled(item):
            assert item.observation is not None
            label = str(item.observation.label)
            return label if label in self._known else None
        if item.pose is None or self._centres is None or self._radius is None:
            return None
        idx, near = nearest_within(
            np.asarray(item.pose[:2], dtype=np.float64).reshape(1, 2), self._centres, self._radius
        )
        return self.labels[int(near[0])] if idx.size else None

    def step(self, item: StreamItem) -> Answer:
        """Step the tracker with one item."""
        truth = self.truth(item)
        observe = True
        if (
            self.observe == "queries"
            and not self._labelled(item)
            and item.pose is not None
            and self._centres is not None
        ):
            observe = truth is not None
        motion = item.pose if item.pose is not None else item.odometry
        return self.tracker.step(item.item, odometry=motion, stamp=item.stamp, observe=observe, truth=truth,
                                 name=item.name)  # fmt: skip


def track_stream(
    place_map: PlaceMap,
    items: Iterable[StreamItem],
    *,
    observe: str = "queries",
    **tracker_options: Any,
) -> Iterator[Answer]:
    """The answers to stream items, each as soon as its item comes (``tracker_options``: ``PlaceMap.tracker``'s).

    An item with odometry alone (a reader's ``odometry_lines=True``) is a
    prediction step, with its answer.
    """
    stepper = StreamStepper(place_map, place_map.tracker(**tracker_options), observe=observe)
    for item in items:
        yield stepper.step(item)
