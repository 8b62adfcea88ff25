"""``Observation.with_label``: the copy the validating constructor would make, without validating again."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.errors import InvalidParameterError
from fingerloc.observation import Observation

_bearings = st.lists(st.floats(-179.0, 179.0), max_size=6)


@st.composite
def _observations(draw):
    features = {"VE": draw(_bearings), "c": draw(_bearings), "B": draw(_bearings)}
    features["CP"] = [(b, h) for b, h in zip(draw(_bearings), draw(st.lists(st.floats(0.0, 359.0), min_size=6, max_size=6)), strict=False)]
    features["W"] = [(b, 1.0 + i, 2.0 + i) for i, b in enumerate(draw(_bearings))]
    pose = draw(st.none() | st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-180, 180)))
    fov = draw(st.none() | st.just([[-90.0, 90.0]]))
    appearance = draw(st.none() | st.lists(st.floats(0, 1), min_size=4, max_size=4))
    return Observation.from_degrees(features, fov=fov, label=draw(st.none() | st.text(max_size=4)), pose=pose,
                                    timestamp=draw(st.none() | st.floats(0, 1e6)), appearance=appearance,
                                    source=draw(st.none() | st.just("log.gz")))  # fmt: skip


@given(_observations(), st.none() | st.text(max_size=5))
@settings(max_examples=150, deadline=None)
def test_with_label_equals_the_validated_copy(o, label):
    mine = o.with_label(label)
    ref = replace(o, label=label)  # through __post_init__
    assert mine == ref and mine.label == label
    for name in Observation.__slots__:
        a, b = getattr(mine, name), getattr(ref, name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape and not a.flags.writeable
        else:
            assert a == b or (a is None and b is None)
    assert o.label != label or o == mine  # the original is untouched


def test_with_label_refuses_what_the_constructor_refuses():
    o = Observation.from_degrees({"VE": [10.0]})
    with pytest.raises(InvalidParameterError, match="label"):
        o.with_label(3)  # type: ignore[arg-type]
