"""Tests of the int8 weighted cyclic kernel (fingerloc.align._cyclic_int) against brute-force oracles."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.align import CostModel, alignment_costs
from fingerloc.align._costs import N_LETTERS
from fingerloc.align._cyclic import cyclic_batch_brute
from fingerloc.align._cyclic_int import LANES8, integer_costs, nw_batch_cyclic_i8
from fingerloc.align._encode import encode_many
from fingerloc.align._kernels import nw_batch_cyclic, pack_lanes
from fingerloc.fingerprint import ALPHABET

FEATURE = CostModel.feature_aware()


def python_cyclic(a: str, b: str, costs: CostModel) -> float:
    """Textbook DP for every rotation of ``b``, in pure Python (float64): the oracle."""
    sub, ind = costs.substitution, costs.indel
    idx = {ch: i for i, ch in enumerate(ALPHABET)}

    def nw(x: str, y: str) -> float:
        d = [[0.0] * (len(y) + 1) for _ in range(len(x) + 1)]
        for i in range(1, len(x) + 1):
            d[i][0] = d[i - 1][0] + ind[idx[x[i - 1]]]
        for j in range(1, len(y) + 1):
            d[0][j] = d[0][j - 1] + ind[idx[y[j - 1]]]
        for i in range(1, len(x) + 1):
            for j in range(1, len(y) + 1):
                d[i][j] = min(
                    d[i - 1][j - 1] + sub[idx[x[i - 1]], idx[y[j - 1]]],
                    d[i - 1][j] + ind[idx[x[i - 1]]],
                    d[i][j - 1] + ind[idx[y[j - 1]]],
                )
        return d[len(x)][len(y)]

    return min(nw(a, b[r:] + b[:r]) for r in range(max(len(b), 1)))


def brute(qs: list[str], rs: list[str], costs: CostModel) -> np.ndarray:
    """Compiled brute force (plain float64 DP for every rotation of each reference)."""
    qc, qo = encode_many(qs)
    rc, ro = encode_many(rs)
    return cyclic_batch_brute(qc, qo, rc, ro, costs.substitution, costs.indel)


@st.composite
def dyadic_models(draw: st.DrawFn) -> CostModel:
    """Cost models whose costs are multiples of 1/scale and fit the int8 kernel's bound."""
    scale = draw(st.sampled_from([1, 2, 4, 8]))
    top = 127 // (3 * scale)  # 2 max indel + max substitution <= 3 top <= 127 / scale
    ints = st.integers(0, max(top, 1))
    sub = np.array(draw(st.lists(ints, min_size=N_LETTERS * N_LETTERS, max_size=N_LETTERS * N_LETTERS)), float)
    sub = sub.reshape(N_LETTERS, N_LETTERS)
    sub = np.triu(sub, 1) + np.triu(sub, 1).T
    indel = np.array(draw(st.lists(ints, min_size=N_LETTERS, max_size=N_LETTERS)), float)
    return CostModel(sub / scale, indel / scale)


def test_integer_costs_decides():
    sub8, ind8, scale = integer_costs(FEATURE.substitution, FEATURE.indel)
    assert scale == 4 and sub8.dtype == np.int8
    np.testing.assert_array_equal(sub8 / scale, FEATURE.substitution)
    np.testing.assert_array_equal(ind8 / scale, FEATURE.indel)
    assert integer_costs(CostModel(0.1).substitution, CostModel(0.1).indel) is None  # not dyadic
    big = CostModel(substitution=1.0, indel=100.0)  # 2 * 100 + 1 > 127
    assert integer_costs(big.substitution, big.indel) is None
    edge = CostModel(substitution=43.0, indel=42.0)  # exactly 127
    assert integer_costs(edge.substitution, edge.indel) is not None


@settings(max_examples=40, deadline=None)
@given(
    dyadic_models(),
    st.lists(st.text(alphabet=ALPHABET, max_size=14), min_size=1, max_size=3),
    st.lists(st.text(alphabet=ALPHABET, max_size=14), min_size=1, max_size=6),
)
def test_int8_kernel_equals_python_oracle(cm, qs, rs):
    assert integer_costs(cm.substitution, cm.indel) is not None
    out = alignment_costs(qs, rs, cyclic=True, costs=cm)
    expect = np.array([[python_cyclic(q, r, cm) for r in rs] for q in qs])
    np.testing.assert_array_equal(out, expect)  # bit for bit: dyadic sums are exact


@settings(max_examples=25, deadline=None)
@given(st.lists(st.text(alphabet="vcfnABCPhit", max_size=12), min_size=1, max_size=4))
def test_int8_kernel_feature_aware_small_alphabet(qs):
    rs = [*qs, "", "n", "nnnn", "fcv", "ABAB"]
    out = alignment_costs(qs, rs, cyclic=True, costs=FEATURE)
    np.testing.assert_array_equal(out, brute(qs, rs, FEATURE))


def test_int8_kernel_at_its_bound_on_long_strings():
    # Costs at the int8 limit and 150-letter strings: differences stay bounded, values do not overflow.
    rng = np.random.default_rng(7)
    cm = CostModel(substitution=43.0, indel=42.0)
    letters = np.array(list(ALPHABET))
    qs = ["".join(rng.choice(letters, n)) for n in (150, 3, 0)]
    rs = ["".join(rng.choice(letters[:4], n)) for n in (150, 149, 1, 0, 40)]
    np.testing.assert_array_equal(alignment_costs(qs, rs, cyclic=True, costs=cm), brute(qs, rs, cm))


def test_int8_kernel_several_blocks_mixed_lengths():
    rng = np.random.default_rng(8)
    letters = np.array(list("vcbfnABhi"))
    n_refs = 2 * LANES8 + 17  # three blocks, the last one mostly padding
    rs = ["".join(rng.choice(letters, int(n))) for n in rng.integers(0, 30, n_refs)]
    qs = ["".join(rng.choice(letters, int(n))) for n in (25, 0, 9)]
    out = alignment_costs(qs, rs, cyclic=True, costs=FEATURE, workers=2)
    np.testing.assert_array_equal(out, brute(qs, rs, FEATURE))
    # and the float64 block kernel that non-dyadic models still use agrees
    qc, qo = encode_many(qs)
    rc, ro = encode_many(rs)
    blocks, blens, block_len, slot = pack_lanes(rc, ro)
    f64 = nw_batch_cyclic(qc, qo, blocks, blens, block_len, FEATURE.substitution, FEATURE.indel)[:, slot]
    np.testing.assert_array_equal(out, f64)


def test_int8_kernel_direct_call_matches_scaled_costs():
    sub8, ind8, scale = integer_costs(FEATURE.substitution, FEATURE.indel)
    qs, rs = ["fcvA", "nnB"], ["vcfB", "Cnn", ""]
    qc, qo = encode_many(qs)
    rc, ro = encode_many(rs)
    blocks, blens, block_len, slot = pack_lanes(rc, ro, LANES8)
    raw = nw_batch_cyclic_i8(qc, qo, blocks, blens, block_len, sub8, ind8)[:, slot]
    assert raw.dtype == np.int32
    np.testing.assert_array_equal(raw / scale, brute(qs, rs, FEATURE))


def test_non_dyadic_model_keeps_the_float_kernel():
    cm = CostModel(substitution=0.3, indel=0.7)
    qs, rs = ["fcvAn", "b"], ["vcfB", "cnnf", ""]
    out = alignment_costs(qs, rs, cyclic=True, costs=cm)
    expect = np.array([[python_cyclic(q, r, cm) for r in rs] for q in qs])
    np.testing.assert_allclose(out, expect, rtol=0, atol=1e-12)


@pytest.mark.parametrize("workers", [1, 2])
def test_int8_kernel_workers_do_not_change_results(workers):
    rng = np.random.default_rng(9)
    letters = np.array(list(ALPHABET))
    rs = ["".join(rng.choice(letters, 20)) for _ in range(300)]
    qs = rs[:3]
    np.testing.assert_array_equal(
        alignment_costs(qs, rs, cyclic=True, costs=FEATURE, workers=workers), brute(qs, rs, FEATURE)
    )


def test_int8_kernel_empty_strings_only():
    # every reference empty (blocks of length 0), then every query empty: the cost is the other side's indels
    np.testing.assert_array_equal(
        alignment_costs(["cvn", "", "A"], ["", ""], cyclic=True, costs=FEATURE), [[2.5, 2.5], [0.0, 0.0], [1.0, 1.0]]
    )
    np.testing.assert_array_equal(
        alignment_costs(["", ""], ["cvn", "", "A"], cyclic=True, costs=FEATURE), [[2.5, 0, 1]] * 2
    )


# -- the shifted two-row kernel: its separate paths ---------------------------------------


@pytest.mark.parametrize("n_query", [0, 1, 2, 3, 4, 5])
def test_int8_kernel_odd_and_even_queries(n_query):
    # rows go two a sweep; an odd query ends with one row alone
    rng = np.random.default_rng(n_query)
    letters = np.array(list("vcfnABh"))
    q = "".join(rng.choice(letters, n_query))
    rs = ["".join(rng.choice(letters, int(m))) for m in rng.integers(0, 9, 40)]
    out = alignment_costs([q], rs, cyclic=True, costs=FEATURE)
    np.testing.assert_array_equal(out, [[python_cyclic(q, r, FEATURE) for r in rs]])


@pytest.mark.parametrize(
    "cm",
    [
        CostModel(substitution=0.0, indel=0.0),  # every cost 0: every alignment ties
        CostModel(substitution=2.0, indel=2.0),  # all-equal costs
        CostModel(substitution=0.0, indel=0.5),  # substitutions free
        CostModel(substitution=4.0, indel=0.25),  # a substitution dearer than two indels
    ],
)
def test_int8_kernel_degenerate_models(cm):
    assert integer_costs(cm.substitution, cm.indel) is not None
    rng = np.random.default_rng(11)
    letters = np.array(list(ALPHABET))
    qs = ["".join(rng.choice(letters, n)) for n in (0, 1, 7, 12)]
    rs = ["".join(rng.choice(letters, n)) for n in (0, 1, 2, 6, 12, 30)] + qs
    np.testing.assert_array_equal(alignment_costs(qs, rs, cyclic=True, costs=cm), brute(qs, rs, cm))


@settings(max_examples=15, deadline=None)
@given(dyadic_models(), st.integers(0, 2**32 - 1), st.sampled_from([ALPHABET, "vcfn", "nv"]))
def test_int8_kernel_mixed_blocks_equal_brute(cm, seed, alphabet):
    # several blocks whose lanes end at different columns (the masked part of the last row's sum), very
    # different lengths side by side, queries of both parities
    rng = np.random.default_rng(seed)
    letters = np.array(list(alphabet))
    n_refs = int(rng.integers(1, 2 * LANES8 + 40))
    lens = rng.integers(0, 25, n_refs)
    lens[rng.integers(0, n_refs, 3)] = 0
    rs = ["".join(rng.choice(letters, int(m))) for m in lens]
    qs = ["".join(rng.choice(letters, int(n))) for n in rng.integers(0, 25, 3)]
    out = alignment_costs(qs, rs, cyclic=True, costs=cm, workers=2)
    np.testing.assert_array_equal(out, brute(qs, rs, cm))


@pytest.mark.parametrize("m", [390, 391])
def test_int8_kernel_last_row_sum_at_the_int16_limit(m):
    # costs at the int8 limit (indel 42): each H of the last row can be -84, and 84 * 390 = 32760 fits
    # int16 while 84 * 391 does not: the sum must switch to int32 there, not wrap
    cm = CostModel(substitution=43.0, indel=42.0)
    q = "v" * m
    rs = ["v" * m, "v" * (m - 1) + "c", "c" + "v" * (m - 1), "v" * (m - 3), "", "v"]
    out = alignment_costs([q], rs, cyclic=True, costs=cm)
    np.testing.assert_array_equal(out, [[0.0, 43.0, 43.0, 126.0, 42.0 * m, 42.0 * (m - 1)]])
