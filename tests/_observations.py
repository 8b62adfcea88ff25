"""A hypothesis strategy of observations of every kind a database record holds (shared by the database tests)."""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import strategies as st

from fingerloc import Observation

ANGLES = st.floats(-10.0, 10.0, allow_nan=False)
POSITIVE = st.floats(0.01, 50.0, allow_nan=False)


@st.composite
def observations(draw: Any, *, cp_ties: bool = False, fovs: Any = None, max_appearance: int = 400) -> Observation:
    """Observations with an optional scan, field of view, pose, timestamp and appearance.

    ``cp_ties``: colour patches often share a bearing (then sorted by hue); ``fovs``: a strategy of
    fields of view (default: 1-3 random intervals, radians); ``max_appearance``: the longest
    appearance descriptor drawn.
    """
    n = st.integers(0, 6)
    kw: dict[str, Any] = {k: draw(st.lists(ANGLES, max_size=draw(n))) for k in ("ve", "ex", "c", "b")}
    ncp, nw = draw(n), draw(n)
    cp = st.sampled_from([0.5, -2.0]) | ANGLES if cp_ties else ANGLES
    kw["cp"] = draw(st.lists(cp, min_size=ncp, max_size=ncp))
    kw["cp_hue"] = draw(st.lists(st.floats(0.0, 359.9), min_size=ncp, max_size=ncp))
    kw["w"] = draw(st.lists(ANGLES, min_size=nw, max_size=nw))
    kw["w_length"] = draw(st.lists(POSITIVE, min_size=nw, max_size=nw))
    kw["w_range"] = draw(st.lists(POSITIVE, min_size=nw, max_size=nw))
    if draw(st.booleans()):
        nb = draw(st.sampled_from([2, 5, 300]))
        kw["ranges"] = draw(st.lists(st.one_of(POSITIVE, st.just(float("inf"))), min_size=nb, max_size=nb))
        kw["range_bearings"] = np.linspace(-1.5, 1.5, nb)
    if draw(st.booleans()):
        if fovs is None:
            kw["fov"] = tuple(draw(st.lists(st.tuples(ANGLES, st.floats(0.1, 6.28)), min_size=1, max_size=3)))
        else:
            kw["fov"] = draw(fovs)
    if draw(st.booleans()):
        kw["pose"] = (draw(POSITIVE), draw(ANGLES), draw(ANGLES))
    if draw(st.booleans()):
        kw["timestamp"] = draw(st.floats(-1e9, 1e9))
    if draw(st.booleans()):
        kw["appearance"] = draw(st.lists(POSITIVE, min_size=1, max_size=max_appearance))
    return Observation(**kw, label="p", source=draw(st.none() | st.just("a.png")))
