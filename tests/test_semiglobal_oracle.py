"""The semi-global bound's kernel (sub-blocks gathered, the profile computed) against a plain dynamic programme, lane by lane."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.align import CostModel
from fingerloc.align._bounds import (
    GROUP_LANES,
    SUB_LANES,
    pack_subblocks,
    query_profile_rows,
    reversed_bound,
    semiglobal_bounds,
    sweep,
)
from fingerloc.align._costs import N_LETTERS
from fingerloc.align._cyclic_int import integer_costs


def semiglobal(a, b, sub, indel):
    """min over substrings s of a + a[:-1] of the global alignment cost of s against b (b whole), integer costs."""
    aa = list(a) + list(a[: max(len(a) - 1, 0)])
    m = len(b)
    prev = [0] * (m + 1)
    for j in range(1, m + 1):
        prev[j] = prev[j - 1] + int(indel[b[j - 1]])
    best = prev[m]
    for x in aa:
        cur = [0] * (m + 1)  # free start: any row may begin with nothing of b used
        for j in range(1, m + 1):
            y = b[j - 1]
            cur[j] = min(prev[j - 1] + int(sub[x, y]), prev[j] + int(indel[x]), cur[j - 1] + int(indel[y]))
        best = min(best, cur[m])  # free end
        prev = cur
    return best


def random_costs(rng):
    """A random symmetric cost model of quarter units (substitutions 0.25-1.5, indels 0.25-1): any table must work."""
    sub = rng.integers(1, 7, (N_LETTERS, N_LETTERS)) / 4.0
    sub = np.triu(sub, 1)
    sub = sub + sub.T
    return CostModel(substitution=sub, indel=rng.integers(1, 5, N_LETTERS) / 4.0)


def cost_model(name, rng):
    return {"unit": CostModel(), "feature": CostModel.feature_aware()}.get(name) or random_costs(rng)


#: The draws of :func:`random_references`: up to two sweeps of references and a query of 0-21 letters, three kinds of costs.
REFERENCES = {
    "seed": st.integers(0, 2**31),
    "n_refs": st.integers(1, 2 * GROUP_LANES + 5),
    "qlen": st.integers(0, 21),
    "costs": st.sampled_from(["unit", "feature", "random"]),
}


def random_references(seed, n_refs, qlen, costs):
    """References of 0-15 letters out of 7, packed in sub-blocks, and a query of those letters, integer costs."""
    rng = np.random.default_rng(seed)
    cm = cost_model(costs, rng)
    sub8, indel8, _scale = integer_costs(cm.substitution, cm.indel)
    letters = rng.choice(N_LETTERS, 7, replace=False)
    lens = rng.integers(0, 16, n_refs)
    off = np.zeros(n_refs + 1, dtype=np.int64)
    np.cumsum(lens, out=off[1:])
    codes = letters[rng.integers(0, letters.size, int(off[-1]))].astype(np.uint8)
    query = letters[rng.integers(0, letters.size, qlen)].astype(np.uint8)
    return rng, sub8, indel8, codes, off, pack_subblocks(codes, off, sub8, indel8), query


@settings(max_examples=30, deadline=None)
@given(**REFERENCES)
def test_sweeps_of_gathered_subblocks_are_the_plain_semiglobal_programme(seed, n_refs, qlen, costs):
    """Sub-blocks gathered in any order, SUBS a sweep: every lane is the plain programme's value."""
    rng, sub8, indel8, codes, off, sb, query = random_references(seed, n_refs, qlen, costs)
    subs = rng.permutation(sb.length.size)[: int(rng.integers(1, sb.length.size + 1))].astype(np.int64)
    got = sweep(query_profile_rows(query, sb), sb, subs).reshape(-1)
    for t, s in enumerate(subs):
        for lane in range(SUB_LANES):
            r = s * SUB_LANES + lane
            if r < n_refs:
                b = codes[off[r] : off[r + 1]].tolist()
                assert got[t * SUB_LANES + lane] == semiglobal(query.tolist(), b, sub8, indel8)
    whole = semiglobal_bounds(query, sb)
    assert [int(whole[r]) for r in range(n_refs)] == [semiglobal(query.tolist(), codes[off[r] : off[r + 1]].tolist(), sub8, indel8) for r in range(n_refs)]


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), costs=st.sampled_from(["unit", "feature", "random"]))
def test_the_computed_profile_is_the_substitution_table(seed, costs):
    """alpha + exceptions = s(c, b) - g(c) - g(b) for every row and every letter used; -g(c) for the wildcard."""
    rng = np.random.default_rng(seed)
    cm = cost_model(costs, rng)
    sub8, indel8, _scale = integer_costs(cm.substitution, cm.indel)
    used = rng.choice(N_LETTERS, int(rng.integers(1, N_LETTERS + 1)), replace=False)
    codes = used.astype(np.uint8)
    sb = pack_subblocks(codes, np.arange(codes.size + 1, dtype=np.int64), sub8, indel8)
    for c in range(N_LETTERS):
        r = sb.row_of[c]
        exc = dict(zip(sb.exc_code[r, : sb.n_exc[r]].tolist(), sb.exc_delta[r, : sb.n_exc[r]].tolist(), strict=True))
        for b in [*used.tolist(), sb.wild_code]:
            want = -int(indel8[c]) if b == sb.wild_code else int(sub8[c, b]) - int(indel8[c]) - int(indel8[b])
            assert int(sb.alpha[r]) + exc.get(b, 0) == want


@settings(max_examples=30, deadline=None)
@given(**REFERENCES)
def test_reversed_bounds_are_the_plain_programme_with_the_roles_swapped(seed, n_refs, qlen, costs):
    """The query whole against any substring of each view written twice: the plain programme with query and view swapped."""
    rng, sub8, indel8, codes, off, sb, query = random_references(seed, n_refs, qlen, costs)
    views = rng.permutation(n_refs)[: int(rng.integers(1, n_refs + 1))].astype(np.int64)
    got = reversed_bound(query_profile_rows(query, sb), sb, codes, off, views)
    for t, r in enumerate(views):
        b = codes[off[r] : off[r + 1]].tolist()
        assert got[t] == semiglobal(b, query.tolist(), sub8, indel8)
