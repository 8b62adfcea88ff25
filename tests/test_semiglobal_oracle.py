"""The semi-global bound's block kernel against a plain dynamic programme, lane by lane."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.align import CostModel
from fingerloc.align._bounds import GROUP_LANES, pack_groups, semiglobal_bounds
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


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    n_refs=st.integers(1, 2 * GROUP_LANES + 5),
    qlen=st.integers(0, 21),
    costs=st.sampled_from(["unit", "feature"]),
)
def test_block_kernel_is_the_plain_semiglobal_programme(seed, n_refs, qlen, costs):
    cm = CostModel() if costs == "unit" else CostModel.feature_aware()
    sub8, indel8, _scale = integer_costs(cm.substitution, cm.indel)
    rng = np.random.default_rng(seed)
    letters = rng.choice(N_LETTERS, 7, replace=False)
    lens = rng.integers(0, 16, n_refs)
    off = np.zeros(n_refs + 1, dtype=np.int64)
    np.cumsum(lens, out=off[1:])
    codes = letters[rng.integers(0, letters.size, int(off[-1]))].astype(np.uint8)
    cuts = [0]
    while cuts[-1] < n_refs:  # blocks of 1 to GROUP_LANES references
        cuts.append(min(n_refs, cuts[-1] + int(rng.integers(1, GROUP_LANES + 1))))
    starts = np.array(cuts, dtype=np.int64)
    gp = pack_groups(codes, off, starts, sub8, indel8)
    query = letters[rng.integers(0, letters.size, qlen)].astype(np.uint8)
    blocks = rng.permutation(starts.size - 1).astype(np.int64)
    got = semiglobal_bounds(query, gp, blocks, workers=1)
    for row, blk in enumerate(blocks):
        for lane, r in enumerate(range(starts[blk], starts[blk + 1])):
            b = codes[off[r] : off[r + 1]].tolist()
            assert got[row, lane] == semiglobal(query.tolist(), b, sub8, indel8)
