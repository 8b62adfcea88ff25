import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from fingerloc.angles import dist_as, rad_to_deg360, wrap, wrap_deg360

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


@given(finite)
def test_wrap_range(x):
    y = float(wrap(x))
    assert -np.pi <= y < np.pi
    # same angle: the difference is a whole number of turns
    k = (x - y) / (2 * np.pi)
    assert abs(k - round(k)) < 1e-6


def test_wrap_float_edge():
    # np.mod(-1e-17 + pi, 2 pi) - pi rounds to pi: wrap must fold it back
    assert wrap(-1e-17) < np.pi
    assert wrap(np.pi) == -np.pi
    assert float(wrap(-np.pi)) == -np.pi
    assert float(wrap_deg360(-1e-14)) == 0.0
    assert float(wrap_deg360(360.0)) == 0.0


@given(finite, finite)
def test_dist_as_is_shortest_signed(a, b):
    d = float(dist_as(a, b))
    assert -np.pi < d <= np.pi
    assert abs(float(wrap(a + d - b))) < 1e-6 or abs(abs(float(wrap(a + d - b))) - 2 * np.pi) < 1e-6


def test_dist_as_values():
    assert np.isclose(dist_as(np.deg2rad(170), np.deg2rad(-170)), np.deg2rad(20))
    assert np.isclose(dist_as(np.deg2rad(-170), np.deg2rad(170)), np.deg2rad(-20))
    assert np.isclose(dist_as(0.0, np.pi), np.pi)
    assert np.isclose(rad_to_deg360(-np.pi / 2), 270.0)
