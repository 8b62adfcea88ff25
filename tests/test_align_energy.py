"""Tests of the minimum-energy matcher (Lamon et al. 2001) in fingerloc.align."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.align import minimum_energy, minimum_energy_costs
from fingerloc.angles import dist_as
from fingerloc.errors import InvalidParameterError, UnknownLetterError
from fingerloc.fingerprint import Fingerprint, parse_fingerprint


def textbook_energy(a: Fingerprint, b: Fingerprint, occ=1.0, mismatch=math.inf, scale=20.0, wrap=True) -> float:
    """Slow oracle: plain DP over every rotation of b's letter order."""

    def linear(r: int) -> float:
        m = len(b)
        idx = [(r + j) % m for j in range(m)] if m else []
        d = [[0.0] * (m + 1) for _ in range(len(a) + 1)]
        for i in range(len(a) + 1):
            d[i][0] = i * occ
        for j in range(m + 1):
            d[0][j] = j * occ
        for i in range(1, len(a) + 1):
            for j in range(1, m + 1):
                k = idx[j - 1]
                typ = 0.0 if a.letters[i - 1] == b.letters[k] else mismatch
                dd = math.degrees(float(dist_as(a.bearings[i - 1], b.bearings[k])))
                d[i][j] = min(d[i - 1][j - 1] + typ + (dd / scale) ** 2, d[i - 1][j] + occ, d[i][j - 1] + occ)
        return d[len(a)][m]

    rots = range(len(b)) if (wrap and len(b)) else [0]
    return min(linear(r) for r in rots)


@st.composite
def fingerprints(draw, max_size=8):
    letters = draw(st.text(alphabet="vcbnA", max_size=max_size))
    bearings = draw(
        st.lists(st.floats(0, 359.9, allow_nan=False), min_size=len(letters), max_size=len(letters)).map(sorted)
    )
    return parse_fingerprint(letters, bearings)


@settings(max_examples=100, deadline=None)
@given(fingerprints(), fingerprints(), st.booleans())
def test_matches_oracle_and_is_symmetric(a, b, wrap):
    e = minimum_energy(a, b, wrap=wrap)
    assert e == pytest.approx(textbook_energy(a, b, wrap=wrap), abs=1e-9)
    assert minimum_energy(a, a, wrap=wrap) == 0.0
    if wrap:
        assert minimum_energy(b, a) == pytest.approx(e, abs=1e-9)
    e2 = minimum_energy(a, b, mismatch=0.7, occlusion=0.5, bearing_scale_deg=10.0, wrap=wrap)
    assert e2 == pytest.approx(textbook_energy(a, b, 0.5, 0.7, 10.0, wrap), abs=1e-9)


def test_worked_examples():
    a = parse_fingerprint("cvb", [10, 100, 200])
    # one bearing moved by 10 deg: (10/20)^2
    assert minimum_energy(a, parse_fingerprint("cvb", [10, 110, 200])) == pytest.approx(0.25)
    # a missing feature: one occlusion
    assert minimum_energy(a, parse_fingerprint("cb", [10, 200])) == pytest.approx(1.0)
    # different letters never pair by default: two occlusions
    assert minimum_energy(a, parse_fingerprint("cfb", [10, 100, 200])) == pytest.approx(2.0)
    assert minimum_energy(a, parse_fingerprint("cfb", [10, 100, 200]), mismatch=0.5) == pytest.approx(0.5)
    # across the 0 deg cut: 359 and 1 deg are 2 deg apart
    x = parse_fingerprint("cv", [1, 180])
    y = parse_fingerprint("vc", [180, 359])
    assert minimum_energy(x, y) == pytest.approx((2 / 20) ** 2)
    assert minimum_energy(x, y, wrap=False) == pytest.approx(2.0)  # v-v matched, both c occluded
    assert minimum_energy("", "cv") == 2.0 and minimum_energy("", "") == 0.0


def test_plain_strings_get_even_bearings():
    assert minimum_energy("cvbn", "cvbn") == 0.0
    assert minimum_energy("cvbn", parse_fingerprint("cvbn")) == 0.0


def test_batch_equals_pairwise():
    rng = np.random.default_rng(2)
    fps = [
        parse_fingerprint("".join(rng.choice(list("vcbnAB"), k)), np.sort(rng.uniform(0, 360, k)))
        for k in (0, 3, 5, 8, 12)
    ]
    out = minimum_energy_costs(fps[:3], [*fps, "cvb"], bearing_scale_deg=15.0)
    assert out.shape == (3, 6)
    expect = [[minimum_energy(q, r, bearing_scale_deg=15.0) for r in [*fps, "cvb"]] for q in fps[:3]]
    np.testing.assert_allclose(out, expect, atol=1e-12)
    assert minimum_energy_costs([], fps).shape == (0, 5)
    assert minimum_energy_costs(fps[1], fps, workers=1).shape == (1, 5)


def test_bad_parameters():
    with pytest.raises(InvalidParameterError, match="occlusion"):
        minimum_energy("c", "v", occlusion=-1.0)
    with pytest.raises(InvalidParameterError, match="bearing_scale_deg"):
        minimum_energy("c", "v", bearing_scale_deg=0.0)
    with pytest.raises(InvalidParameterError, match="mismatch"):
        minimum_energy("c", "v", mismatch=float("nan"))
    with pytest.raises(UnknownLetterError):
        minimum_energy_costs(["c"], ["x"])


@settings(max_examples=30, deadline=None)
@given(fingerprints(max_size=20), st.integers(0, 5), st.floats(-30, 30), st.data())
def test_oracle_on_similar_fingerprints(a, n_edits, turn_deg, data):
    # b: a turned a little, with a few letters dropped (the realistic case)
    b = a.turned(np.deg2rad(turn_deg))
    for _ in range(min(n_edits, len(b))):
        k = data.draw(st.integers(0, len(b) - 1))
        b = Fingerprint(b.letters[:k] + b.letters[k + 1 :], np.delete(b.bearings, k))
    for mismatch in (math.inf, 0.6):
        e = minimum_energy(a, b, mismatch=mismatch)
        assert e == pytest.approx(textbook_energy(a, b, mismatch=mismatch), rel=1e-9, abs=1e-9)


@settings(max_examples=15, deadline=None)
@given(
    st.lists(fingerprints(max_size=10), min_size=1, max_size=3),
    st.lists(fingerprints(max_size=10), min_size=1, max_size=40),
    st.booleans(),
    st.sampled_from([math.inf, 0.3]),
)
def test_batch_kernel_equals_pair_kernel(qs, rs, wrap, mismatch):
    out = minimum_energy_costs(qs, rs, wrap=wrap, mismatch=mismatch)
    expect = [[minimum_energy(q, r, wrap=wrap, mismatch=mismatch) for r in rs] for q in qs]
    np.testing.assert_allclose(out, expect, rtol=1e-12, atol=1e-12)


def test_batch_rotating_the_query_equals_pair_kernel_over_several_blocks():
    # the batch kernel minimises over rotations of the query, the pair kernel over rotations of the reference
    rng = np.random.default_rng(21)
    fps = [
        parse_fingerprint("".join(rng.choice(list("vcbnfA"), k)), np.sort(rng.uniform(0, 360, k)))
        for k in rng.integers(0, 14, 75)
    ]
    qs = [fps[0], fps[1], parse_fingerprint("vcbnnfAc", np.sort(rng.uniform(0, 360, 8))), ""]
    for mismatch in (math.inf, 0.4):
        out = minimum_energy_costs(qs, fps, mismatch=mismatch, workers=2)
        expect = [[minimum_energy(q, r, mismatch=mismatch) for r in fps] for q in qs]
        np.testing.assert_allclose(out, expect, rtol=1e-12, atol=1e-12)
