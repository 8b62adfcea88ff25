"""Observation rows decoded in bulk: the very observations of the one-by-one decoder, crafted rows refused alike."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc import Observation
from fingerloc.errors import DatabaseError
from fingerloc.map._records import decode_observation, encode_observation
from fingerloc.map.database import _observation_blob, _observation_blobs
from fingerloc.map.database_rows import decode_rows

from ._observations import observations as _observations

_FOV = ((-1.0, 4.0),)


def observations():
    return _observations(cp_ties=True, fovs=st.sampled_from([_FOV, ((0.5, 1.0), (2.0, 1.5))]), max_appearance=40)


def _identical(a: Observation, b: Observation) -> bool:
    for k in ("ve", "cp", "cp_hue", "ex", "c", "b", "w", "w_length", "w_range", "ranges", "range_bearings", "appearance", "profile"):
        x, y = getattr(a, k), getattr(b, k)
        if (x is None) != (y is None) or (x is not None and (x.dtype != y.dtype or x.tobytes() != y.tobytes() or x.flags.writeable)):
            return False
    return (a.fov, a.pose, a.timestamp, a.label, a.source, a.keypoints) == (b.fov, b.pose, b.timestamp, b.label, b.source, b.keypoints)


def _one_by_one(records, labels, sources, default_fov):
    out = []
    for r, lab, src in zip(records, labels, sources, strict=True):
        try:
            out.append(decode_observation(r, label=lab, source=src, default_fov=default_fov))
        except DatabaseError as err:
            return out, str(err)
    return out, None


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(observations(), st.booleans(), st.booleans()), min_size=1, max_size=8), st.booleans())
def test_bulk_decoding_gives_the_observations_of_the_one_by_one_decoder(items, use_default):
    default_fov = _FOV if use_default else None
    records = [encode_observation(o, scan=scan, default_fov=default_fov, walls32=w32) for o, scan, w32 in items]
    labels = [f"p{i}" for i in range(len(items))]
    sources = [o.source for o, _, _ in items]
    want, err = _one_by_one(records, labels, sources, default_fov)
    assert err is None
    got = decode_rows(records, labels, sources, default_fov=default_fov)
    assert len(got) == len(want)
    assert all(_identical(a, b) for a, b in zip(got, want, strict=True))


def _laser_like(rng: np.random.Generator, n: int) -> list[Observation]:
    out = []
    for i in range(n):
        k = int(rng.integers(0, 6))
        out.append(
            Observation(
                ve=rng.uniform(-4, 4, int(rng.integers(0, 5))),
                w=rng.uniform(-4, 4, k),
                w_length=rng.uniform(0.1, 9.0, k),
                w_range=rng.uniform(0.2, 20.0, k),
                cp=rng.uniform(-4, 4, 2),
                cp_hue=rng.uniform(0, 360, 2),
                pose=(float(rng.normal()), float(rng.normal()), float(rng.normal())) if i % 2 else None,
                timestamp=float(i) if i % 3 else None,
                fov=_FOV if i % 4 else ((-np.pi, 2 * np.pi),),
                label="x",
            )
        )
    return out


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 5), st.lists(st.tuples(st.integers(0, 400), st.integers(0, 255)), min_size=1, max_size=4))
def test_crafted_records_are_decoded_or_refused_as_one_by_one(seed, row, edits):
    """Bytes of a valid record changed anywhere (counts, flags, values: NaN, -0.0, unsorted, out of range)."""
    rng = np.random.default_rng(seed)
    obs = _laser_like(rng, 6)
    records = [encode_observation(o, scan=False, default_fov=_FOV, walls32=bool(i % 2)) for i, o in enumerate(obs)]
    data = bytearray(records[row])
    for pos, value in edits:
        data[pos % len(data)] = value
    records[row] = bytes(data)
    labels = [f"p{i}" for i in range(6)]
    sources = [None] * 6
    want, err = _one_by_one(records, labels, sources, _FOV)
    if err is not None:
        with pytest.raises(DatabaseError) as info:
            decode_rows(records, labels, sources, default_fov=_FOV)
        assert str(info.value) == f"place 'p{row}': {err}"
    else:
        got = decode_rows(records, labels, sources, default_fov=_FOV)
        assert all(_identical(a, b) for a, b in zip(got, want, strict=True))


@pytest.mark.parametrize(
    "values",
    [[0.5, 0.25], [-0.0], [np.nan], [np.pi], [-np.pi - 1e-9], [np.inf]],
    ids=["unsorted", "negative-zero", "nan", "pi", "below-minus-pi", "inf"],
)
def test_bearings_an_observation_would_change_take_the_one_by_one_path(values):
    """Records written by hand with bearings the observation wraps, sorts or refuses."""
    import struct

    vals = np.asarray(values, dtype="<f8")
    record = struct.pack("<BB9B", 1, 0, vals.size, 0, 0, 0, 0, 0, 0, 0, 0) + vals.tobytes()
    want, err = _one_by_one([record], ["p"], [None], None)
    if err is not None:
        with pytest.raises(DatabaseError, match="place 'p'"):
            decode_rows([record], ["p"], [None])
    else:
        assert _identical(decode_rows([record], ["p"], [None])[0], want[0])


def test_batched_records_are_those_of_one_at_a_time():
    """The saving side's batch (float32 walls checked against the stored fingerprint) writes the same bytes."""
    from fingerloc.fingerprint import make_fingerprint

    params = {"empty_step_deg": 20.0, "merge_tol_deg": 2.0, "laser_letters": True}
    rng = np.random.default_rng(3)
    obs = _laser_like(rng, 40)

    def make_fp(o):
        return make_fingerprint(o, empty_step_deg=20.0, merge_tol_deg=2.0, laser_letters=True)

    stored = []
    for i, o in enumerate(obs):
        fp = make_fp(o)
        letters = fp.letters if i % 5 else fp.letters[::-1]  # some fingerprints no record gives back
        stored.append(None if i % 7 == 0 else (letters, fp.bearings))
    want = [_observation_blob(o, s, True, _FOV, make_fp) for o, s in zip(obs, stored, strict=True)]
    assert any(k for _, k in want) and not all(k for _, k in want)
    assert _observation_blobs(obs, stored, True, _FOV, params) == want
