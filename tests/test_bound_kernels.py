"""The compiled passes of exact retrieval (fingerloc.terms._bound_kernels) against plain computations."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.distance import cdist

from fingerloc.align import CostModel, alignment_costs
from fingerloc.align._bounds import SUB_LANES, pack_subblocks, query_profile_rows, semiglobal_bounds
from fingerloc.align._costs import N_LETTERS
from fingerloc.align._cyclic_int import integer_costs
from fingerloc.fingerprint import ALPHABET
from fingerloc.terms._bound_kernels import (
    COUNT_GROUPS,
    NO_VIEW,
    SweepState,
    count_place_min,
    count_place_min_narrow,
    cyclic_place_min,
    exact_l1_place_min,
    group_count_place_min,
    l1_place_min,
    letter_counts,
    open_places,
    place_letter_counts,
    query_rows,
    scaled,
    semiglobal_cover,
    semiglobal_views_min,
    top_places,
    unscored_mass,
    view_spans,
)
from fingerloc.terms.bounds import count_potentials

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
def test_semiglobal_bounds_a_place_are_the_sweeps_of_every_view_and_below_the_cyclic_cost(seed, n_places, costs):
    """The views of chosen places, their sub-blocks gathered, get the bounds of a sweep over every view, and bound the cyclic cost."""
    cm = COSTS[costs]
    sub8, indel8, scale = integer_costs(cm.substitution, cm.indel)
    rng, per_place, place_start, codes, off, letters = random_views(seed, n_places, 4, 10, 5)
    sb = pack_subblocks(codes, off, sub8, indel8)
    qlen = int(rng.integers(0, 10))
    query = letters[rng.integers(0, letters.size, qlen)].astype(np.uint8)
    places = rng.permutation(n_places)[: int(rng.integers(1, n_places + 1))].astype(np.int64)
    pov = np.repeat(np.arange(n_places), per_place).astype(np.int32)
    q = query_profile_rows(query, sb)
    got = semiglobal_views_min(q, sb, SweepState(sb.length.size), places, place_start, per_place, pov, view_spans(place_start, per_place, pov.size))
    per_view = semiglobal_bounds(query, sb)[: off.size - 1]
    assert np.array_equal(got, least_per_place(per_view, place_start, per_place, NO_VIEW)[places])
    # a lower bound of the cyclic cost
    views = strings(codes, off)
    if views:
        qs = "".join(ALPHABET[c] for c in query)
        exact = least_per_place(alignment_costs([qs], views, cyclic=True, costs=cm)[0] * scale, place_start, per_place, np.inf)
        assert np.all(np.where(got == NO_VIEW, np.inf, got) <= exact[places])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_places=st.integers(1, 60), calls=st.integers(1, 5))
def test_each_sweep_covers_the_places_it_completes_once_and_their_bounds_stay(seed, n_places, calls):
    """Calls of semiglobal_cover on chosen places: each returns the places whose views are all swept now and were not before."""
    cm = COSTS["feature"]
    sub8, indel8, _ = integer_costs(cm.substitution, cm.indel)
    rng, per_place, place_start, codes, off, letters = random_views(seed, n_places, 12, 8, 5)
    sb = pack_subblocks(codes, off, sub8, indel8)
    pov = np.repeat(np.arange(n_places), per_place).astype(np.int32)
    span = view_spans(place_start, per_place, pov.size)
    query = letters[rng.integers(0, letters.size, int(rng.integers(0, 9)))].astype(np.uint8)
    q = query_profile_rows(query, sb)
    state = SweepState(sb.length.size)
    swept = np.zeros(sb.length.size, dtype=bool)
    done = per_place == 0  # a place without views is never covered
    for _ in range(calls):
        chosen = rng.permutation(n_places)[: int(rng.integers(0, n_places + 1))].astype(np.int64)
        for p in chosen:
            swept[place_start[p] // SUB_LANES : (place_start[p] + per_place[p] - 1) // SUB_LANES + 1] |= per_place[p] > 0
        got = semiglobal_cover(q, sb, state, chosen, place_start, per_place, pov, span)
        now = np.array([per_place[p] > 0 and swept[place_start[p] // SUB_LANES : (place_start[p] + per_place[p] - 1) // SUB_LANES + 1].all() for p in range(n_places)])
        assert sorted(got.tolist()) == sorted(np.flatnonzero(now & ~done).tolist())
        done |= now
    covered = np.flatnonzero(done & (per_place > 0)).astype(np.int64)
    want = least_per_place(semiglobal_bounds(query, sb), place_start, per_place, NO_VIEW)[covered]
    assert np.array_equal(semiglobal_views_min(q, sb, state, covered, place_start, per_place, pov, span), want)


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


def random_cost_model(rng):
    """Symmetric costs of quarter units, not metric in general (the bounds must hold for any table)."""
    sub = np.triu(rng.integers(1, 9, (N_LETTERS, N_LETTERS)) / 4.0, 1)
    return CostModel(substitution=sub + sub.T, indel=rng.integers(1, 5, N_LETTERS) / 4.0)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), n_places=st.integers(1, 30), costs=st.sampled_from(["unit", "feature", "random"]))
def test_letter_counts_with_every_potential_bound_the_cyclic_cost_and_tighten_the_three_potential_bound(seed, n_places, costs):
    """The grouped pass (every potential of count_potentials) gives the direct sums, between the three-potential bound and the cyclic cost."""
    # up to COUNT_GROUPS groups of letters: with unit costs every letter is alike, else at most 4 letters
    rng, per_place, place_start, codes, off, letters = random_views(seed, n_places, 3, 12, 7 if costs == "unit" else COUNT_GROUPS)
    cm = COSTS.get(costs) or random_cost_model(rng)
    _sub8, _indel8, scale = integer_costs(cm.substitution, cm.indel)
    pots = count_potentials(cm.substitution, cm.indel)
    u = np.array([a for a, _ in pots]) * 2 * scale
    w = np.array([b for _, b in pots]) * 2 * scale
    assert np.array_equal(u, np.round(u)) and np.array_equal(w, np.round(w))
    nv = off.size - 1
    counts = np.zeros((nv, N_LETTERS), dtype=np.int64)
    np.add.at(counts, (np.repeat(np.arange(nv), np.diff(off)), codes.astype(np.int64)), 1)
    query = letters[rng.integers(0, letters.size, int(rng.integers(0, 12)))].astype(np.uint8)
    extra = rng.choice(np.setdiff1d(np.arange(N_LETTERS), letters), 2, replace=False)  # letters only the query has
    query = np.concatenate([query, extra[rng.integers(0, 2, int(rng.integers(0, 3)))]]).astype(np.uint8)
    q = np.bincount(query, minlength=N_LETTERS).astype(np.int32)
    used = np.flatnonzero(counts.sum(0) > 0)
    rest = np.setdiff1d(np.arange(N_LETTERS), used)
    const = u[:, rest] @ q[rest]
    # the letters the views use, in groups of equal potentials (the kernel takes up to COUNT_GROUPS)
    keys = {}
    group = np.array([keys.setdefault(u[:, x].tobytes() + w[:, x].tobytes(), len(keys)) for x in used], dtype=np.int64)
    assert len(keys) <= COUNT_GROUPS
    ca = np.zeros((len(pots), COUNT_GROUPS), dtype=np.int16)
    cb = np.zeros((len(pots), COUNT_GROUPS), dtype=np.int16)
    vsum = np.zeros((COUNT_GROUPS, nv), dtype=np.int16)
    qsum = np.zeros(COUNT_GROUPS, dtype=np.int16)
    for x, g in zip(used, group, strict=True):
        ca[:, g], cb[:, g] = u[:, x] + w[:, x], u[:, x] - w[:, x]
        vsum[g] += counts[:, x].astype(np.int16)
        qsum[g] += q[x]
    got = group_count_place_min(
        q.astype(np.int16), np.ascontiguousarray(counts.T.astype(np.uint8)), used.astype(np.int64), group, vsum, qsum, ca, cb,
        (2 * const).astype(np.int16), place_start, per_place,
    )
    d = q[None, :] - counts
    per_view = np.maximum(0, (np.maximum(d, 0) @ u.T + np.maximum(-d, 0) @ w.T).max(axis=1)) if nv else np.zeros(0)
    assert np.array_equal(got, least_per_place(2 * per_view, place_start, per_place, NO_VIEW))
    has = per_place > 0
    got = np.where(has, got // 2, NO_VIEW)
    other = np.where(np.eye(N_LETTERS, dtype=bool), np.inf, cm.substitution).min(axis=1)
    h2 = (2 * scale * np.minimum(cm.indel, other / 2.0)).astype(np.int32)
    c2 = (2 * scale * np.minimum(cm.indel, other)).astype(np.int32)
    coarse = count_place_min(q, np.ascontiguousarray(counts.T.astype(np.int16)), np.arange(N_LETTERS, dtype=np.int64), h2, c2, place_start, per_place)
    assert np.all(got >= coarse)
    if nv:
        qs = "".join(ALPHABET[c] for c in query)
        exact = alignment_costs([qs], strings(codes, off), cyclic=True, costs=cm)[0] * scale
        assert np.all(np.where(has, got / 2.0, np.inf) <= least_per_place(exact, place_start, per_place, np.inf))


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
    got = unscored_mass(ub, level, 5.0, 3)  # a bound: each term at most 1.6 % above, places 60 nats below count exp(-60) each
    assert want * (1 - 1e-12) <= got <= want * np.exp(1 / 64) + n * np.exp(-60.0)
    assert unscored_mass(ub, level, float(ub.max(initial=0.0)) + 61.0, 3) >= np.count_nonzero(level < 3) * np.exp(-60.0) * (1 - 1e-12)
    # the m best places, best first (ties of value in any order), and the open ones
    m = int(rng.integers(0, n + 1))
    top = top_places(ub, m)
    assert np.array_equal(np.sort(ub[top])[::-1], np.sort(ub)[::-1][:m])
    assert np.all(np.diff(ub[top]) <= 0)
    cut = float(rng.normal(-30.0, 10.0))
    assert np.array_equal(open_places(ub, level, cut, 3), np.flatnonzero((level < 3) & (ub >= cut)))
