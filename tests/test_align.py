"""Tests of fingerloc.align: plain, cyclic and batch alignment, cost models."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rapidfuzz.distance import Levenshtein

from fingerloc.align import (
    CostModel,
    FingerprintBatch,
    alignment_costs,
    cyclic_alignment,
    global_alignment,
    minimum_energy_costs,
)
from fingerloc.errors import InvalidParameterError, UnknownLetterError
from fingerloc.fingerprint import ALPHABET, parse_fingerprint

FP = st.text(alphabet=ALPHABET, max_size=30)
FP_SHORT = st.text(alphabet=ALPHABET, max_size=12)
# A small alphabet makes matches (and ties between rotations) frequent.
FP_SMALL = st.text(alphabet="vcfnAB", max_size=12)
FEATURE = CostModel.feature_aware()


def textbook(a: str, b: str, costs: CostModel) -> float:
    """Slow, obvious Needleman-Wunsch in pure Python: the oracle."""
    sub, ind = costs.substitution, costs.indel
    idx = {ch: i for i, ch in enumerate(ALPHABET)}
    d = [[0.0] * (len(b) + 1) for _ in range(len(a) + 1)]
    for i in range(1, len(a) + 1):
        d[i][0] = d[i - 1][0] + ind[idx[a[i - 1]]]
    for j in range(1, len(b) + 1):
        d[0][j] = d[0][j - 1] + ind[idx[b[j - 1]]]
    for i in range(1, len(a) + 1):
        for j in range(1, len(b) + 1):
            d[i][j] = min(
                d[i - 1][j - 1] + sub[idx[a[i - 1]], idx[b[j - 1]]],
                d[i - 1][j] + ind[idx[a[i - 1]]],
                d[i][j - 1] + ind[idx[b[j - 1]]],
            )
    return d[len(a)][len(b)]


def brute_cyclic(a: str, b: str, costs: CostModel | None = None) -> float:
    if not b:
        return global_alignment(a, b, costs=costs)
    return min(global_alignment(a, b[r:] + b[:r], costs=costs) for r in range(len(b)))


def alignment_cost(a: str, b: str, pairs, costs: CostModel) -> float:
    """Cost of an explicit alignment, checking that it is a valid one."""
    ia = [i for i, _ in pairs if i is not None]
    jb = [j for _, j in pairs if j is not None]
    assert ia == list(range(len(a))) and jb == list(range(len(b)))
    total = 0.0
    for i, j in pairs:
        if i is None:
            total += costs.indel_cost(b[j])
        elif j is None:
            total += costs.indel_cost(a[i])
        else:
            total += costs.cost(a[i], b[j])
    return total


# -- plain --------------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(FP, FP)
def test_unit_cost_is_levenshtein(a, b):
    expect = Levenshtein.distance(a, b)
    assert global_alignment(a, b) == expect
    cost, pairs = global_alignment(a, b, return_alignment=True)
    assert cost == expect
    assert alignment_cost(a, b, pairs, CostModel()) == expect


@settings(max_examples=150, deadline=None)
@given(FP_SHORT, FP_SHORT)
def test_weighted_matches_textbook_oracle(a, b):
    expect = textbook(a, b, FEATURE)
    assert global_alignment(a, b, costs=FEATURE) == pytest.approx(expect, abs=1e-12)
    cost, pairs = global_alignment(a, b, costs=FEATURE, return_alignment=True)
    assert cost == pytest.approx(expect, abs=1e-12)
    assert alignment_cost(a, b, pairs, FEATURE) == pytest.approx(expect, abs=1e-12)


@settings(max_examples=150, deadline=None)
@given(FP, FP)
def test_symmetry_and_identity(a, b):
    for cm in (None, FEATURE):
        assert global_alignment(a, b, costs=cm) == pytest.approx(global_alignment(b, a, costs=cm), abs=1e-12)
        assert global_alignment(a, a, costs=cm) == 0.0


@settings(max_examples=150, deadline=None)
@given(FP_SHORT, FP_SHORT, FP_SHORT)
def test_triangle_inequality_unit(a, b, c):
    assert global_alignment(a, c) <= global_alignment(a, b) + global_alignment(b, c)


def test_empty_strings():
    assert global_alignment("", "") == 0.0
    assert global_alignment("", "cvn") == 3.0
    assert global_alignment("cvn", "") == 3.0
    assert global_alignment("cnn", "", costs=FEATURE) == 2.0  # c: 1, n: 0.5 each
    assert global_alignment("", "ab".replace("a", "c"), return_alignment=True) == (2.0, [(None, 0), (None, 1)])


def test_fingerprint_inputs():
    fp = parse_fingerprint("cvnnb")
    assert global_alignment(fp, "cvnb") == 1.0


def test_unknown_letter_is_an_error():
    with pytest.raises(UnknownLetterError, match=r"'x' at position 2"):
        global_alignment("cvx", "c")
    with pytest.raises(UnknownLetterError, match=r"references\[1\]"):
        alignment_costs(["cv"], ["c", "cz"])


def test_feature_aware_preset():
    assert FEATURE.cost("A", "B") == 0.25
    assert FEATURE.cost("A", "P") == 0.25  # hue is circular
    assert FEATURE.cost("A", "C") == 0.5
    assert FEATURE.cost("A", "I") == 1.0
    assert FEATURE.cost("f", "c") == FEATURE.cost("v", "f") == 0.5
    assert FEATURE.cost("v", "c") == 1.0
    assert FEATURE.indel_cost("n") == 0.5
    assert FEATURE.indel_cost("v") == 1.0
    # wall letters (laser extension): h i j / k l m / o p q / r s t = range class x length class
    assert FEATURE.cost("h", "i") == FEATURE.cost("h", "k") == 0.5
    assert FEATURE.cost("h", "l") == FEATURE.cost("h", "j") == 1.0
    assert FEATURE.cost("e", "v") == 1.0
    assert global_alignment("cfG", "cvH", costs=FEATURE) == 0.75


def test_cost_model_validation():
    assert CostModel().is_unit and CostModel(substitution=1.0, indel=1.0) == CostModel()
    assert not FEATURE.is_unit
    assert CostModel(indel={"n": 0.5}).indel_cost("n") == 0.5
    assert CostModel(substitution={"fc": 0.5}).cost("c", "f") == 0.5
    with pytest.raises(InvalidParameterError, match="must be finite and >= 0"):
        CostModel(indel=-1.0)
    with pytest.raises(InvalidParameterError, match="must be finite and >= 0"):
        CostModel(substitution={"fc": -0.5})
    sub = 1.0 - np.eye(len(ALPHABET))
    sub[0, 1] = 0.3
    with pytest.raises(InvalidParameterError, match="symmetric"):
        CostModel(substitution=sub)
    sub = 1.0 - np.eye(len(ALPHABET))
    sub[2, 3] = sub[3, 2] = -1.0
    with pytest.raises(InvalidParameterError, match=">= 0"):
        CostModel(substitution=sub)
    with pytest.raises(InvalidParameterError, match="match must cost 0"):
        CostModel(substitution=np.ones((len(ALPHABET), len(ALPHABET))))
    with pytest.raises(InvalidParameterError, match="shape"):
        CostModel(substitution=np.zeros((3, 3)))
    with pytest.raises(UnknownLetterError):
        CostModel(indel={"x": 1.0})
    with pytest.raises(InvalidParameterError, match="hue_step"):
        CostModel.feature_aware(hue_step=-0.1)
    with pytest.raises(InvalidParameterError, match="costs"):
        global_alignment("c", "v", costs="unit")  # type: ignore[arg-type]
    with pytest.raises(InvalidParameterError, match="workers"):
        alignment_costs(["c"], ["v"], workers=0)


def test_cost_model_is_immutable_and_hashable():
    with pytest.raises(ValueError):
        FEATURE.substitution[0, 1] = 5.0
    assert hash(CostModel.feature_aware()) == hash(FEATURE)
    assert CostModel.feature_aware() == FEATURE


# -- batch ---------------------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(st.lists(FP, min_size=1, max_size=5), st.lists(FP, min_size=1, max_size=20))
def test_batch_equals_pairwise(qs, rs):
    for cm in (None, FEATURE):
        out = alignment_costs(qs, rs, costs=cm)
        assert out.shape == (len(qs), len(rs)) and out.dtype == np.float64
        expect = np.array([[global_alignment(q, r, costs=cm) for r in rs] for q in qs])
        np.testing.assert_allclose(out, expect, atol=1e-12)


def test_batch_shapes_and_single_inputs():
    assert alignment_costs([], ["c"]).shape == (0, 1)
    assert alignment_costs(["c"], []).shape == (1, 0)
    out = alignment_costs("cv", ["cv", "", parse_fingerprint("vvv")], costs=FEATURE, workers=1)
    np.testing.assert_array_equal(out, [[0.0, 2.0, 2.0]])


# -- cyclic --------------------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(FP_SMALL, FP_SMALL)
def test_cyclic_equals_brute_force(a, b):
    for cm in (None, FEATURE):
        res = cyclic_alignment(a, b, costs=cm)
        assert res.cost == pytest.approx(brute_cyclic(a, b, cm), abs=1e-12)
        if b:
            rot = b[res.rotation :] + b[: res.rotation]
            assert global_alignment(a, rot, costs=cm) == pytest.approx(res.cost, abs=1e-12)
            assert alignment_cost(a, rot, res.alignment, cm or CostModel()) == pytest.approx(res.cost, abs=1e-12)


@settings(max_examples=100, deadline=None)
@given(FP_SMALL, FP_SMALL, st.integers(0, 50), st.integers(0, 50))
def test_cyclic_invariant_under_rotation_of_either_string(a, b, ka, kb):
    base = cyclic_alignment(a, b).cost
    ra = a[ka % len(a) :] + a[: ka % len(a)] if a else a
    rb = b[kb % len(b) :] + b[: kb % len(b)] if b else b
    assert cyclic_alignment(ra, b).cost == base
    assert cyclic_alignment(a, rb).cost == base
    assert cyclic_alignment(b, a).cost == base  # symmetric too


@settings(max_examples=20, deadline=None)
@given(st.lists(FP_SMALL, min_size=1, max_size=4), st.lists(FP_SMALL, min_size=1, max_size=12))
def test_cyclic_batch_equals_brute_force(qs, rs):
    for cm in (None, FEATURE):
        out = alignment_costs(qs, rs, cyclic=True, costs=cm)
        expect = np.array([[brute_cyclic(q, r, cm) for r in rs] for q in qs])
        np.testing.assert_allclose(out, expect, atol=1e-12)


def test_heading_recovers_a_known_rotation():
    rng = np.random.default_rng(3)
    letters = "cbvnfGcnEnvccA"
    bearings = np.sort(rng.uniform(0, 360, len(letters)))
    b = parse_fingerprint(letters, bearings)
    for turn_deg in (0.0, 17.0, 95.0, 200.0, 333.0):
        a = b.turned(np.deg2rad(turn_deg))
        res = cyclic_alignment(a, b)
        assert res.cost == 0.0
        assert res.heading_deg is not None
        err = (res.heading_deg - turn_deg + 180.0) % 360.0 - 180.0
        assert abs(err) < 1e-6
        assert b.letters[res.rotation :] + b.letters[: res.rotation] == a.letters


def test_heading_with_noise_and_a_missing_feature():
    rng = np.random.default_rng(4)
    letters = "cvbcAvncfc"
    bearings = np.sort(rng.uniform(0, 360, len(letters)))
    b = parse_fingerprint(letters, bearings)
    turned = b.turned(np.deg2rad(120.0))
    noisy = parse_fingerprint(turned.letters[1:], (turned.bearings_deg + rng.normal(0, 2.0, len(letters)))[1:])
    res = cyclic_alignment(noisy, b)
    assert res.cost == 1.0
    assert abs((res.heading_deg - 120.0 + 180.0) % 360.0 - 180.0) < 3.0


def test_heading_none_without_bearings():
    assert cyclic_alignment("cvb", "vbc").heading_deg is None
    res = cyclic_alignment("cvb", "")
    assert res.cost == 3.0 and res.rotation == 0 and res.heading_deg is None


def test_cyclic_batch_long_strings_and_role_swap():
    rng = np.random.default_rng(5)
    letters = np.array(list("vcfnAB"))
    qs = ["".join(rng.choice(letters, n)) for n in (0, 1, 5, 64, 65, 70)]
    rs = ["".join(rng.choice(letters, n)) for n in (0, 1, 7, 63, 64, 66)]
    out = alignment_costs(qs, rs, cyclic=True)
    expect = np.array([[brute_cyclic(q, r) for r in rs] for q in qs])
    np.testing.assert_array_equal(out, expect)
    out_w = alignment_costs(qs, rs, cyclic=True, costs=FEATURE)
    expect_w = np.array([[brute_cyclic(q, r, FEATURE) for r in rs] for q in qs])
    np.testing.assert_allclose(out_w, expect_w, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.text(alphabet=ALPHABET, max_size=70), min_size=1, max_size=3), st.lists(FP, min_size=1, max_size=4))
def test_cyclic_unit_kernel_full_alphabet(qs, rs):
    out = alignment_costs(qs, rs, cyclic=True, workers=-1)
    expect = np.array([[brute_cyclic(q, r) for r in rs] for q in qs])
    np.testing.assert_array_equal(out, expect)
    np.testing.assert_array_equal(alignment_costs(rs, qs, cyclic=True, workers=1), expect.T)


def test_fingerprint_batch_is_validated_once_and_reusable():
    fps = [parse_fingerprint("cvb", [10, 100, 200]), "ncv", ""]
    batch = FingerprintBatch(fps)
    assert len(batch) == 3 and batch.letters == ["cvb", "ncv", ""]
    np.testing.assert_array_equal(alignment_costs(["cv"], batch), alignment_costs(["cv"], fps))
    np.testing.assert_array_equal(
        alignment_costs(batch, batch, cyclic=True, costs=FEATURE), alignment_costs(fps, fps, cyclic=True, costs=FEATURE)
    )
    np.testing.assert_array_equal(minimum_energy_costs(batch, batch), minimum_energy_costs(fps, fps))
    with pytest.raises(UnknownLetterError):
        FingerprintBatch(["cx"])


def test_heading_on_periodic_strings_picks_the_consistent_rotation():
    # "cncncn": rotations 0, 2 and 4 all cost 0; only one pairs letters at one offset
    bearings = [5.0, 40.0, 100.0, 160.0, 250.0, 300.0]
    b = parse_fingerprint("cncncn", bearings)
    for turn_deg in (30.0, 130.0, 250.0):
        a = b.turned(np.deg2rad(turn_deg))
        res = cyclic_alignment(a, b)
        assert res.cost == 0.0
        assert abs((res.heading_deg - turn_deg + 180.0) % 360.0 - 180.0) < 1e-6


def test_unit_costs_with_repeated_references_equal_each_pair():
    """Equal references are aligned once and copied: every column still equals its own alignment."""
    from fingerloc.align import alignment_costs, global_alignment
    from fingerloc.fingerprint import parse_fingerprint

    refs = [parse_fingerprint(s) for s in ["vnc", "fnnv", "vnc", "", "fnnv", "vnc", "cbn"]]
    queries = [parse_fingerprint(s) for s in ["vcn", "fnv", ""]]
    got = alignment_costs(queries, refs)
    want = [[global_alignment(q, r) for r in refs] for q in queries]
    assert got.shape == (3, 7) and got.tolist() == want
