"""Many references packed a chunk at a time for the int8 cyclic kernel give the costs of packing them at once."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import fingerloc.align as align
from fingerloc.align import CostModel, alignment_costs, cyclic_alignment
from fingerloc.fingerprint import ALPHABET


def _strings(rng, n, max_len, letters):
    return ["".join(rng.choice(letters, int(rng.integers(0, max_len + 1)))) for _ in range(n)]


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31), n_refs=st.integers(600, 900), chunk_bytes=st.sampled_from([1, 300_000, 500_000]))
def test_chunked_references_give_the_same_costs(seed, n_refs, chunk_bytes):
    rng = np.random.default_rng(seed)
    letters = list(ALPHABET[:12])
    refs = _strings(rng, n_refs, 30, letters)
    queries = _strings(rng, 3, 30, letters)
    cm = CostModel.feature_aware()
    whole = alignment_costs(queries, refs, cyclic=True, costs=cm)
    with pytest.MonkeyPatch.context() as m:
        m.setattr(align, "_PACKED_MAX_BYTES", 0)
        m.setattr(align, "_PACK_CHUNK_BYTES", chunk_bytes)
        assert align._reference_chunk(refs, 34) < n_refs  # more than one chunk
        chunked = alignment_costs(queries, refs, cyclic=True, costs=cm)
    assert np.array_equal(chunked, whole)
    for j in rng.choice(n_refs, 5, replace=False):  # and those of aligning one pair
        assert chunked[0, j] == pytest.approx(cyclic_alignment(queries[0], refs[j], costs=cm).cost, abs=1e-9)


def test_references_packed_at_once_while_their_profile_may_be_kept():
    refs = ["abc" * 5] * 1000
    assert align._reference_chunk(refs, 34) == 1000  # 1,000 x 34 x 16 bytes: kept whole
    many = ["abc" * 10] * 300_000  # 300,000 x 34 x 32 bytes, over the bound: chunks of the longest
    assert align._reference_chunk(many, 34) == align._PACK_CHUNK_BYTES // (34 * 32 + 60)


def test_a_batch_keeps_its_packed_form_or_its_chunk_size(monkeypatch):
    rng = np.random.default_rng(3)
    letters = list(ALPHABET[:12])
    refs = _strings(rng, 700, 30, letters)
    queries = _strings(rng, 2, 30, letters)
    cm = CostModel.feature_aware()
    whole = alignment_costs(queries, refs, cyclic=True, costs=cm)
    kept = align.FingerprintBatch(refs)
    assert np.array_equal(alignment_costs(queries, kept, cyclic=True, costs=cm), whole)
    assert [type(v).__name__ for v in kept._packed.values()] == ["ProfileBlocks"]
    monkeypatch.setattr(align, "_PACKED_MAX_BYTES", 0)
    monkeypatch.setattr(align, "_PACK_CHUNK_BYTES", 1)  # chunks of 256 references
    chunked = align.FingerprintBatch(refs)
    for _ in range(2):  # measured once, then the kept chunk size
        assert np.array_equal(alignment_costs(queries, chunked, cyclic=True, costs=cm), whole)
        assert list(chunked._packed.values()) == [256]
    monkeypatch.setattr(align, "_reference_chunk", lambda *a: pytest.fail("measured again"))
    assert np.array_equal(alignment_costs(queries, chunked, cyclic=True, costs=cm), whole)
