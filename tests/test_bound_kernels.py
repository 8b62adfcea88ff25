"""The compiled passes of exact retrieval (fingerloc.terms._bound_kernels) against plain computations."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.distance import cdist

from fingerloc.align import CostModel, alignment_costs
from fingerloc.align._bounds import GROUP_LANES, pack_groups, semiglobal_bounds
from fingerloc.align._costs import N_LETTERS
from fingerloc.align._cyclic_int import integer_costs
from fingerloc.fingerprint import ALPHABET
from fingerloc.retrieval import place_layout
from fingerloc.terms._bound_kernels import (
    NO_VIEW,
    count_place_min,
    count_place_min_narrow,
    cyclic_place_min,
    exact_l1_place_min,
    l1_place_min,
    letter_counts,
    place_letter_counts,
    query_rows,
    scaled,
    semiglobal_place_min,
    unscored_mass,
)

COSTS = {"unit": CostModel(), "feature": CostModel.feature_aware()}


def random_views(seed, n_places, max_views, max_len, n_letters):
    """Places with 0..max_views views of random letters (layout order = place order), and their letter codes."""
    rng = np.random.default_rng(seed)
    per_place = rng.integers(0, max_views + 1, n_places).astype(np.int64)
    n_views = int(per_place.sum())
    lens = rng.integers(0, max_len + 1, n_views)
    off = np.zeros(n_views + 1, dtype=np.int64)
    np.cumsum(lens, out=off[1:])
    letters = rng.choice(N_LETTERS, n_letters, replace=False)
    codes = letters[rng.integers(0, n_letters, int(off[-1]))].astype(np.uint8)
    place_start = (np.cumsum(per_place) - per_place).astype(np.int64)
    return rng, per_place, place_start, codes, off, letters


def strings(codes, off):
    return ["".join(ALPHABET[c] for c in codes[off[i] : off[i + 1]]) for i in range(off.size - 1)]


def least_per_place(per_view, place_start, per_place, empty):
    return np.array([min(per_view[a : a + n], default=empty) for a, n in zip(place_start, per_place, strict=True)])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_places=st.integers(1, 30), costs=st.sampled_from(sorted(COSTS)))
def test_exact_cyclic_costs_a_place_are_those_of_the_batch_alignment(seed, n_places, costs):
    cm = COSTS[costs]
    sub8, indel8, scale = integer_costs(cm.substitution, cm.indel)
    rng, per_place, place_start, codes, off, letters = random_views(seed, n_places, 3, 12, 6)
    qlen = int(rng.integers(0, 12))
    query = letters[rng.integers(0, letters.size, qlen)].astype(np.uint8)
    places = rng.permutation(n_places)[: int(rng.integers(1, n_places + 1))].astype(np.int64)
    got = cyclic_place_min(query_rows(query, sub8, indel8), codes, off, place_start, per_place, places)
    views = strings(codes, off)
    qs = "".join(ALPHABET[c] for c in query)
    full = alignment_costs([qs], views, cyclic=True, costs=cm)[0] * scale if views else np.zeros(0)
    want = least_per_place(full, place_start, per_place, np.inf)[places]
    assert np.array_equal(np.where(got == NO_VIEW, np.inf, got.astype(np.float64)), want)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_places=st.integers(1, 40), costs=st.sampled_from(sorted(COSTS)))
def test_semiglobal_bounds_a_place_are_the_block_kernels_and_below_the_cyclic_cost(seed, n_places, costs):
    cm = COSTS[costs]
    sub8, indel8, scale = integer_costs(cm.substitution, cm.indel)
    rng, per_place, _, codes0, off0, letters = random_views(seed, n_places, 4, 10, 5)
    layout = place_layout(rng.random((n_places, 2)), np.maximum(per_place, 1), group_views=int(rng.choice([3, 8, 64])))
    # views in layout order, blocks of at most GROUP_LANES a group (as FingerprintBound packs them)
    first = np.cumsum(per_place) - per_place
    view_order = np.concatenate([np.arange(first[p], first[p] + per_place[p]) for p in layout.order]).astype(np.int64)
    lens = np.diff(off0)[view_order]
    off = np.zeros(view_order.size + 1, dtype=np.int64)
    np.cumsum(lens, out=off[1:])
    codes = np.concatenate([codes0[off0[v] : off0[v + 1]] for v in view_order] + [np.zeros(0, np.uint8)]).astype(np.uint8)
    n = per_place[layout.order]
    place_start = np.empty(n_places, dtype=np.int64)
    place_start[layout.order] = np.cumsum(n) - n
    group_start = np.append(np.cumsum(n) - n, n.sum())[layout.starts]
    cuts, owner = [], []
    for g in range(layout.n_groups):
        for c in range(int(group_start[g]), int(group_start[g + 1]), GROUP_LANES):
            cuts.append(c)
            owner.append(g)
    block_start = np.array([*cuts, view_order.size], dtype=np.int64)
    group_blocks = np.searchsorted(np.array(owner, dtype=np.int64), np.arange(layout.n_groups + 1))
    gp = pack_groups(codes, off, block_start, sub8, indel8)
    qlen = int(rng.integers(0, 10))
    query = letters[rng.integers(0, letters.size, qlen)].astype(np.uint8)
    groups = np.flatnonzero(rng.random(layout.n_groups) < 0.6).astype(np.int64)
    aa = np.concatenate([query, query[: max(qlen - 1, 0)]]).astype(np.int64)
    places, got = semiglobal_place_min(
        gp.row_of[aa], gp.indel[aa].astype(np.int32), groups, group_blocks, block_start, gp.prof, gp.pstart,
        gp.block_len, gp.gsum, gp.n_rows, layout.order, layout.starts, place_start, per_place,
    )
    assert np.array_equal(places, layout.places_of(groups))
    # the same lanes as the block kernel
    blocks = np.concatenate([np.arange(group_blocks[g], group_blocks[g + 1]) for g in groups] + [np.zeros(0, np.int64)])
    lanes = semiglobal_bounds(query, gp, blocks.astype(np.int64), workers=1)
    per_view = np.full(view_order.size, NO_VIEW, dtype=np.int64)
    for row, b in enumerate(blocks):
        m = block_start[b + 1] - block_start[b]
        per_view[block_start[b] : block_start[b] + m] = lanes[row, :m]
    assert np.array_equal(got, least_per_place(per_view, place_start, per_place, NO_VIEW)[places])
    # a lower bound of the cyclic cost
    views = strings(codes, off)
    if views:
        qs = "".join(ALPHABET[c] for c in query)
        exact = least_per_place(alignment_costs([qs], views, cyclic=True, costs=cm)[0] * scale, place_start, per_place, np.inf)
        assert np.all(np.where(got == NO_VIEW, np.inf, got) <= exact[places])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_places=st.integers(1, 50), costs=st.sampled_from(sorted(COSTS)))
def test_letter_count_bounds_a_place_are_the_least_over_its_views_and_below_the_cyclic_cost(seed, n_places, costs):
    cm = COSTS[costs]
    _sub8, _indel8, scale = integer_costs(cm.substitution, cm.indel)
    rng, per_place, place_start, codes, off, letters = random_views(seed, n_places, 3, 12, 7)
    nv = off.size - 1
    counts = np.zeros((nv, N_LETTERS), dtype=np.int64)
    np.add.at(counts, (np.repeat(np.arange(nv), np.diff(off)), codes.astype(np.int64)), 1)
    query = letters[rng.integers(0, letters.size, int(rng.integers(0, 12)))].astype(np.uint8)
    q = np.bincount(query, minlength=N_LETTERS).astype(np.int32)
    other = np.where(np.eye(N_LETTERS, dtype=bool), np.inf, cm.substitution).min(axis=1)
    h2 = (2 * scale * np.minimum(cm.indel, other / 2.0)).astype(np.int32)
    c2 = (2 * scale * np.minimum(cm.indel, other)).astype(np.int32)
    got = count_place_min(q, np.ascontiguousarray(counts.T.astype(np.int16)), np.arange(N_LETTERS, dtype=np.int64), h2, c2, place_start, per_place)
    d = q[None, :] - counts
    per_view = np.maximum.reduce([(np.abs(d) * h2).sum(1), (np.maximum(d, 0) * c2).sum(1), (np.maximum(-d, 0) * c2).sum(1)])
    assert np.array_equal(got, least_per_place(per_view, place_start, per_place, NO_VIEW))
    # the same in 16-bit lanes from 8-bit counts (its sums fit: short views)
    counts8 = np.ascontiguousarray(counts.T.astype(np.uint8))
    narrow = count_place_min_narrow(q.astype(np.int16), counts8, np.arange(N_LETTERS, dtype=np.int64), h2.astype(np.int16), c2.astype(np.int16), place_start, per_place)
    assert np.array_equal(narrow, got)
    assert np.array_equal(count_place_min(q, counts8, np.arange(N_LETTERS, dtype=np.int64), h2, c2, place_start, per_place), got)
    if nv:
        qs = "".join(ALPHABET[c] for c in query)
        exact = alignment_costs([qs], strings(codes, off), cyclic=True, costs=cm)[0] * scale
        assert np.all(np.where(got == NO_VIEW, np.inf, got / 2.0) <= least_per_place(exact, place_start, per_place, np.inf))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_places=st.integers(1, 40), width=st.integers(1, 60))
def test_range_distances_a_place_are_cdists_bit_for_bit(seed, n_places, width):
    rng = np.random.default_rng(seed)
    per_place = rng.integers(0, 4, n_places).astype(np.int64)
    refs = np.cumsum(rng.random((int(per_place.sum()), width)), axis=1)
    refs /= np.maximum(refs[:, -1:], 1e-12)
    q = np.cumsum(rng.random(width))
    q /= q[-1]
    first = (np.cumsum(per_place) - per_place).astype(np.int64)
    places = rng.permutation(n_places).astype(np.int64)
    got = exact_l1_place_min(q, np.ascontiguousarray(refs), first, per_place, places)
    full = cdist(q[None, :], refs, metric="cityblock")[0] if refs.shape[0] else np.zeros(0)
    assert np.array_equal(got, least_per_place(full, first, per_place, np.inf)[places])
    # the rounded descriptors' L1 in steps (as many as a 16-bit sum holds)
    steps = 65535 // width
    d16 = np.round(refs * steps).astype(np.uint16)
    q16 = np.round(q * steps).astype(np.uint16)
    got16 = l1_place_min(np.ascontiguousarray(d16.T), q16, first, per_place)
    want16 = np.abs(d16.astype(np.int64) - q16.astype(np.int64)).sum(axis=1)
    assert np.array_equal(got16, least_per_place(want16, first, per_place, NO_VIEW))


def test_a_query_without_letters_costs_each_view_its_indels():
    cm = CostModel.feature_aware()
    sub8, indel8, _scale = integer_costs(cm.substitution, cm.indel)
    codes = np.array([3, 4, 4, 9], dtype=np.uint8)
    off = np.array([0, 1, 4], dtype=np.int64)
    got = cyclic_place_min(query_rows(np.zeros(0, dtype=np.uint8), sub8, indel8), codes, off, np.array([0, 1, 2]), np.array([1, 1, 0]), np.array([0, 1, 2]))
    assert got[0] == indel8[3] and got[1] == indel8[4] * 2 + indel8[9] and got[2] == NO_VIEW


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_places=st.integers(1, 30))
def test_letter_counts_of_views_and_places_are_those_of_the_strings(seed, n_places):
    _, per_place, _, codes, off, _ = random_views(seed, n_places, 3, 12, 9)
    views = off.size - 1
    by_view = letter_counts(codes, off, N_LETTERS)
    assert by_view.shape == (N_LETTERS, views)
    for v in range(views):
        assert np.array_equal(by_view[:, v], np.bincount(codes[off[v] : off[v + 1]], minlength=N_LETTERS))
    by_place = place_letter_counts(codes, off, per_place, N_LETTERS)
    first = np.cumsum(per_place) - per_place
    for p in range(n_places):
        want = by_view[:, first[p] : first[p] + per_place[p]].sum(axis=1)
        assert np.array_equal(by_place[p], want.astype(np.float64))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(0, 200))
def test_scaled_values_and_the_unscored_mass_are_numpys(seed, n):
    rng = np.random.default_rng(seed)
    least = rng.integers(0, 5000, n).astype(np.int64)
    least[rng.random(n) < 0.2] = NO_VIEW
    got = scaled(least, 8.0)
    assert np.array_equal(got, np.where(least == NO_VIEW, np.inf, least / 8.0))
    ub = rng.normal(-30.0, 10.0, n)
    level = rng.integers(1, 4, n).astype(np.int8)
    want = np.exp(ub[level < 3] - 5.0).sum()
    assert unscored_mass(ub, level, 5.0) == pytest.approx(want, rel=1e-12, abs=0.0)
