"""The int8 cyclic kernel's packed references: kept by a FingerprintBatch, one thread or several, refreshed on new places."""

from __future__ import annotations

import numpy as np
import pytest

import fingerloc.align as align
from fingerloc.align import CostModel, FingerprintBatch, alignment_costs
from fingerloc.align._cyclic import cyclic_batch_brute
from fingerloc.align._cyclic_int import LANES8, cyclic_i8_costs, integer_costs, pack_profiles
from fingerloc.align._encode import encode_many
from fingerloc.fingerprint import ALPHABET, Fingerprint
from fingerloc.observation import Observation
from fingerloc.terms.fingerprint import FingerprintTerm

FEATURE = CostModel.feature_aware()


def _strings(rng: np.random.Generator, n: int, hi: int = 30) -> list[str]:
    letters = list(ALPHABET)
    return ["".join(rng.choice(letters, int(rng.integers(0, hi)))) for _ in range(n)]


def _brute(qs: list[str], rs: list[str], cm: CostModel) -> np.ndarray:
    qc, qo = encode_many(qs)
    rc, ro = encode_many(rs)
    return cyclic_batch_brute(qc, qo, rc, ro, cm.substitution, cm.indel)


def test_batch_keeps_one_packed_form_and_reuses_it():
    rng = np.random.default_rng(5)
    rs = _strings(rng, LANES8 + 40)
    qs = _strings(rng, 3)
    batch = FingerprintBatch(rs)
    first = alignment_costs(qs, batch, cyclic=True, costs=FEATURE)
    assert len(batch._packed) == 1
    (kept,) = batch._packed.values()
    again = alignment_costs(qs[:1], batch, cyclic=True, costs=FEATURE)
    (kept2,) = batch._packed.values()
    assert kept2 is kept  # not packed again
    np.testing.assert_array_equal(again, first[:1])
    np.testing.assert_array_equal(first, _brute(qs, rs, FEATURE))
    other = CostModel.feature_aware(n_indel=1.0)
    d = alignment_costs(qs, batch, cyclic=True, costs=other)
    assert len(batch._packed) == 1 and next(iter(batch._packed.values())) is not kept  # replaced, not added
    np.testing.assert_array_equal(d, _brute(qs, rs, other))


def test_batch_over_the_memory_bound_is_not_kept(monkeypatch):
    monkeypatch.setattr(align, "_PACKED_MAX_BYTES", 1000)
    rng = np.random.default_rng(6)
    rs = _strings(rng, 50)
    batch = FingerprintBatch(rs)
    d = alignment_costs(rs[:2], batch, cyclic=True, costs=FEATURE)
    assert batch._packed == {}
    np.testing.assert_array_equal(d, _brute(rs[:2], rs, FEATURE))


@pytest.mark.parametrize("n_queries", [1, 2, 5])
def test_one_thread_and_all_threads_agree(n_queries):
    rng = np.random.default_rng(n_queries)
    rs = _strings(rng, 2 * LANES8 + 7, hi=40)
    qs = _strings(rng, n_queries, hi=40)
    small = integer_costs(FEATURE.substitution, FEATURE.indel)
    assert small is not None
    sub8, ind8, scale = small
    qc, qo = encode_many(qs)
    pk = pack_profiles(*encode_many(rs), sub8, ind8)
    serial = cyclic_i8_costs(qc, qo, pk, workers=1)[:, pk.slot]
    par = cyclic_i8_costs(qc, qo, pk, workers=2)[:, pk.slot]
    np.testing.assert_array_equal(serial, par)
    np.testing.assert_array_equal(serial / scale, _brute(qs, rs, FEATURE))
    assert pk.prof.ctypes.data % 4096 == 0 and pk.nbytes >= pk.prof.nbytes


def _obs(rng: np.random.Generator, label: str) -> Observation:
    return Observation(
        ve=rng.uniform(0, 2 * np.pi, int(rng.integers(1, 6))),
        c=rng.uniform(0, 2 * np.pi, int(rng.integers(0, 4))),
        b=rng.uniform(0, 2 * np.pi, int(rng.integers(0, 3))),
        label=label,
    )


def test_fingerprint_term_repacks_when_places_are_added():
    rng = np.random.default_rng(11)
    groups = [[_obs(rng, f"p{j}") for _ in range(2)] for j in range(5)]
    queries = [_obs(rng, "q") for _ in range(3)]
    term = FingerprintTerm(cyclic=True, costs=FEATURE).fit(groups)
    before = term.distances(queries)
    more = [*groups, [_obs(rng, "p5")], [_obs(rng, "p6"), _obs(rng, "p6")]]
    term.update(more, [5, 6])
    after = term.distances(queries)
    fresh = FingerprintTerm(cyclic=True, costs=FEATURE).fit(more).distances(queries)
    assert after.shape == (3, 7)
    np.testing.assert_array_equal(after, fresh)
    np.testing.assert_array_equal(after[:, :5], before)
    fps = [term.fingerprint(o) for o in queries]
    refs = [fp for g in more for fp in (term.fingerprint(o) for o in g)]
    assert all(isinstance(f, Fingerprint) for f in refs)
    d = _brute([f.letters for f in fps], [f.letters for f in refs], FEATURE)
    np.testing.assert_array_equal(after[:, 5], d[:, 5 * 2 : 5 * 2 + 1].min(axis=1))


def test_pickled_batch_leaves_its_packed_form_behind():
    import pickle

    rng = np.random.default_rng(8)
    rs = _strings(rng, 40)
    batch = FingerprintBatch(rs)
    d = alignment_costs(rs[:2], batch, cyclic=True, costs=FEATURE)
    assert batch._packed
    copy = pickle.loads(pickle.dumps(batch))
    assert copy._packed == {} and copy.letters == batch.letters
    np.testing.assert_array_equal(alignment_costs(rs[:2], copy, cyclic=True, costs=FEATURE), d)
    assert copy._packed
    old = FingerprintBatch.__new__(FingerprintBatch)
    old.__setstate__((None, {"letters": batch.letters, "bearings": batch.bearings}))  # a pickle of the slots alone
    np.testing.assert_array_equal(alignment_costs(rs[:2], old, cyclic=True, costs=FEATURE), d)
