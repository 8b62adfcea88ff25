"""Observation rows of a place database in bulk: decoded and checked as whole arrays, not one view at a time.

A database of 100,000 places holds some 300,000 observation records. Decoding
them one by one through :func:`~fingerloc.map._records.decode_observation`
builds and validates each :class:`~fingerloc.observation.Observation` with a
few dozen small numpy calls: minutes at that size. :func:`decode_rows` reads
the common records (codec version 1: bearings, colour patches, walls, an
optional pose and timestamp, the full or the database's default field of
view; no appearance, scan, profile or keypoints) field by field over every
row at once, and checks in bulk that each value is one the observation would
keep unchanged: finite, already wrapped to ``[-pi, pi)`` (bit for bit, no
``-0.0``), sorted within its record as the observation sorts it, hues in
``[0, 360)``, wall lengths and ranges ``> 0``, a finite pose within
``+-1e9`` m. Such a record gives the very observation the one-by-one path
gives (the same values, bit for bit), built without validating it again.
Every other record (another codec version, a field the bulk path does not
read, a length that does not match its counts, a value that fails a check)
goes through :func:`~fingerloc.map._records.decode_observation`, which
decodes it or refuses it with its own message: a crafted database is
refused exactly as before.

:func:`record_fingerprints` is the saving side's check of float32 walls: the
fingerprints of many decoded records at once (one batch of
:func:`fingerloc._fingerprints.make_fingerprints`, the same strings and
bearings as one at a time).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..angles import wrap
from ..errors import DatabaseError, FingerlocError
from ..observation import FULL_FOV, Observation
from ._records import (
    _APPEARANCE,
    _DEFAULT_FOV,
    _FOV,
    _MAX_COORD_M,
    _N_COUNTS,
    _POSE,
    _SCAN,
    _TIME,
    _VERSION,
    _WALLS32,
    _WIDE,
    decode_observation,
)

__all__ = ["decode_rows", "record_fingerprints"]

Fov = tuple[tuple[float, float], ...]

#: Rows decoded together (bounds the temporary index arrays).
CHUNK_ROWS = 50_000

_HEAD = 2 + _N_COUNTS  # version, flags, 9 uint8 counts (codec version 1 without wide counts)


def _ranges(lo: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``concatenate([arange(a, a + k) for a, k in zip(lo, n)])``."""
    if n.size == 0:
        return np.zeros(0, dtype=np.int64)
    return np.repeat(lo - np.cumsum(n) + n, n) + np.arange(int(n.sum()))


def _seg_ok_sorted(x: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Per segment (``bounds`` its starts then the end), whether ``x`` does not decrease within it."""
    n_seg = bounds.size - 1
    bad = np.zeros(n_seg, dtype=bool)
    if x.size > 1:
        drop = np.flatnonzero(x[1:] < x[:-1]) + 1  # position i: x[i] < x[i-1]
        seg = np.searchsorted(bounds, drop, side="right") - 1  # the segment of position i
        inside = drop > bounds[seg]  # i and i-1 in the same segment
        bad[seg[inside]] = True
    return ~bad


def _canonical_angles(x: np.ndarray) -> np.ndarray:
    """Elementwise: finite, not ``-0.0``, and wrapping changes no bit."""
    fin = np.isfinite(x)
    y = np.where(fin, x, 0.0)
    same = wrap(y).view(np.int64) == y.view(np.int64)
    return fin & same & ~((y == 0.0) & np.signbit(y))


def _bad_rows(ok_values: np.ndarray, owner: np.ndarray, n_rows: int) -> np.ndarray:
    bad = np.zeros(n_rows, dtype=bool)
    bad[owner[~ok_values]] = True
    return bad


def decode_rows(
    records: Sequence[Any], labels: Sequence[str], sources: Sequence[Any], *, default_fov: Fov | None = None
) -> list[Observation]:
    """The observations of ``records`` (one place label and source each), as :func:`decode_observation` gives them.

    Parameters
    ----------
    records : sequence of bytes
        Observation records (:func:`~fingerloc.map._records.encode_observation`); anything else is left to
        :func:`decode_observation`, which refuses it.
    labels, sources : sequences
        The place label (text) and the source (text or None) of each record.
    default_fov : tuple of (start, width), optional
        The database's default field of view.

    Raises
    ------
    DatabaseError
        As :func:`decode_observation` does for the first record it refuses, its message prefixed
        with ``place LABEL:``.
    """
    out: list[Observation] = []
    fov_fast = _fast_default_fov(default_fov)
    for s in range(0, len(records), CHUNK_ROWS):
        out.extend(_decode_chunk(records[s : s + CHUNK_ROWS], labels[s : s + CHUNK_ROWS], sources[s : s + CHUNK_ROWS], default_fov, fov_fast))
    return out


def _fast_default_fov(default_fov: Fov | None) -> bool:
    """True when an observation keeps ``default_fov`` unchanged (so the bulk path may give it as is)."""
    if default_fov is None:
        return False
    try:
        return Observation(fov=default_fov).fov == default_fov
    except (FingerlocError, TypeError, ValueError):  # refused: the one-by-one path gives the message
        return False


def _decode_chunk(records: Sequence[Any], labels: Sequence[str], sources: Sequence[Any], default_fov: Fov | None, fov_fast: bool) -> list[Observation]:
    n = len(records)
    is_bytes = np.array([isinstance(r, bytes) and len(r) >= _HEAD for r in records], dtype=bool)
    head = np.zeros((n, _HEAD), dtype=np.int64)
    lens = np.zeros(n, dtype=np.int64)
    if is_bytes.any():
        idx = np.flatnonzero(is_bytes).tolist()
        head[idx] = np.frombuffer(b"".join(records[i][:_HEAD] for i in idx), dtype=np.uint8).reshape(-1, _HEAD)
        lens[idx] = [len(records[i]) for i in idx]
    version, flags = head[:, 0], head[:, 1]
    c = head[:, 2:]
    n_ve, n_cp, n_ex, n_c, n_b, n_w = (c[:, i] for i in range(6))
    w32 = (flags & _WALLS32) != 0
    pose = (flags & _POSE) != 0
    time = (flags & _TIME) != 0
    dfov = (flags & _DEFAULT_FOV) != 0
    n64 = n_ve + 2 * n_cp + n_ex + n_c + n_b + n_w + np.where(w32, 0, 2 * n_w) + 3 * pose + time
    fast = (
        is_bytes
        & (version == _VERSION)
        & ((flags & (_APPEARANCE | _SCAN | _WIDE | _FOV)) == 0)
        & ((c[:, 6:9] == 0).all(axis=1))
        & (~dfov | fov_fast)
        & (lens == _HEAD + 8 * n64 + np.where(w32, 8 * n_w, 0))
    )
    rows = np.flatnonzero(fast)
    obs: list[Observation | None] = [None] * n
    if rows.size:
        _fill_fast(records, labels, sources, rows, n_ve, n_cp, n_ex, n_c, n_b, n_w, w32, pose, time, dfov, n64, default_fov, obs)
    for i in range(n):
        if obs[i] is None:
            try:
                obs[i] = decode_observation(records[i], label=labels[i], source=sources[i], default_fov=default_fov)
            except DatabaseError as err:
                raise DatabaseError(f"place {labels[i]!r}: {err}") from err
    return obs  # type: ignore[return-value]


def _fill_fast(
    records: Sequence[Any], labels: Sequence[str], sources: Sequence[Any], rows: np.ndarray,
    n_ve: np.ndarray, n_cp: np.ndarray, n_ex: np.ndarray, n_c: np.ndarray, n_b: np.ndarray, n_w: np.ndarray,
    w32: np.ndarray, pose: np.ndarray, time: np.ndarray, dfov: np.ndarray, n64: np.ndarray, default_fov: Fov | None,
    obs: list[Observation | None],
) -> None:  # fmt: skip
    """Decode and check the rows ``rows`` (headers already checked), putting each one that passes in ``obs``."""
    k = rows.size
    vals = np.frombuffer(b"".join(records[i][_HEAD : _HEAD + 8 * int(n64[i])] for i in rows), dtype="<f8").astype(np.float64)
    shorts = np.frombuffer(
        b"".join(records[i][_HEAD + 8 * int(n64[i]) :] for i in rows if w32[i]), dtype="<f4"
    ).astype(np.float64)
    r64 = n64[rows]
    base = np.cumsum(r64) - r64  # each row's first value in vals
    # the fields in record order: ve, cp, hue, ex, c, b, w, [w_length, w_range], [pose], [timestamp]
    sizes = {"ve": n_ve[rows], "cp": n_cp[rows], "cp_hue": n_cp[rows], "ex": n_ex[rows], "c": n_c[rows], "b": n_b[rows], "w": n_w[rows]}
    rw32 = w32[rows]
    sizes["w_length"] = np.where(rw32, 0, n_w[rows])
    sizes["w_range"] = sizes["w_length"]
    sizes["pose"] = 3 * pose[rows]
    sizes["time"] = time[rows].astype(np.int64)
    fields: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # name -> (values, starts of each row's segment, (k + 1,))
    at = base.copy()
    for name, sz in sizes.items():
        v = vals[_ranges(at, sz)]
        fields[name] = (v, np.append(np.cumsum(sz) - sz, int(sz.sum())))
        at = at + sz
    # float32 wall lengths and ranges: both of a row after its float64 values
    nw = n_w[rows]
    s_n = np.where(rw32, 2 * nw, 0)
    s_base = np.cumsum(s_n) - s_n
    wl = np.where(rw32, nw, 0)
    len32 = shorts[_ranges(s_base, wl)]
    rng32 = shorts[_ranges(s_base + wl, wl)]
    seg_w = fields["w"][1]
    # per row, the wall lengths and ranges: from float64 values or from float32 ones
    wl_all = np.empty(int(nw.sum()))
    wr_all = np.empty(int(nw.sum()))
    pos32 = _ranges(seg_w[:-1][rw32], nw[rw32])
    pos64 = _ranges(seg_w[:-1][~rw32], nw[~rw32])
    wl_all[pos32], wr_all[pos32] = len32, rng32
    wl_all[pos64], wr_all[pos64] = fields["w_length"][0], fields["w_range"][0]
    fields["w_length"] = (wl_all, seg_w)
    fields["w_range"] = (wr_all, seg_w)
    bad = np.zeros(k, dtype=bool)
    for name in ("ve", "ex", "c", "b", "w", "cp"):
        v, seg = fields[name]
        owner = np.repeat(np.arange(k), np.diff(seg))
        bad |= _bad_rows(_canonical_angles(v), owner, k)
        if name != "cp":
            bad |= ~_seg_ok_sorted(np.where(np.isfinite(v), v, 0.0), seg)
    hue, seg_h = fields["cp_hue"]
    owner = np.repeat(np.arange(k), np.diff(seg_h))
    bad |= _bad_rows(np.isfinite(hue) & (hue >= 0.0) & (hue < 360.0), owner, k)
    cp = fields["cp"][0]
    if cp.size > 1:  # sorted by bearing, then hue (the observation's lexsort)
        same = owner[1:] == owner[:-1]
        wrong = (cp[1:] < cp[:-1]) | ((cp[1:] == cp[:-1]) & (hue[1:] < hue[:-1]))
        bad[owner[1:][same & wrong]] = True
    owner_w = np.repeat(np.arange(k), nw)
    bad |= _bad_rows(np.isfinite(wl_all) & (wl_all > 0) & np.isfinite(wr_all) & (wr_all > 0), owner_w, k)
    pv, _ = fields["pose"]
    pm = pv.reshape(-1, 3) if pv.size else np.zeros((0, 3))
    ok_pose = np.isfinite(pm).all(axis=1) & (np.abs(np.where(np.isfinite(pm), pm, 0.0)[:, :2]) <= _MAX_COORD_M).all(axis=1)
    bad[np.flatnonzero(pose[rows])[~ok_pose]] = True
    tv, _ = fields["time"]
    bad[np.flatnonzero(time[rows])[~np.isfinite(tv)]] = True
    for name in ("ve", "cp", "cp_hue", "ex", "c", "b", "w", "w_length", "w_range"):
        fields[name][0].setflags(write=False)
    starts = {name: fields[name][1].tolist() for name in ("ve", "cp", "ex", "c", "b", "w")}
    arrays = {name: fields[name][0] for name in ("ve", "cp", "cp_hue", "ex", "c", "b", "w", "w_length", "w_range")}
    span = {"cp_hue": "cp", "w_length": "w", "w_range": "w"}
    poses = pm.tolist()
    times = tv.tolist()
    p_at = t_at = 0
    dfov_r = dfov[rows].tolist()
    pose_r = pose[rows].tolist()
    time_r = time[rows].tolist()
    bad_r = bad.tolist()
    checked = Observation._checked
    for j, i in enumerate(rows.tolist()):
        p = None
        if pose_r[j]:
            p = tuple(poses[p_at])
            p_at += 1
        t = None
        if time_r[j]:
            t = times[t_at]
            t_at += 1
        if bad_r[j]:
            continue  # the one-by-one path decides
        bearings = {}
        for name, arr in arrays.items():
            st = starts[span.get(name, name)]
            bearings[name] = arr[st[j] : st[j + 1]]
        fov = default_fov if dfov_r[j] and default_fov is not None else FULL_FOV
        obs[i] = checked(bearings, fov=fov, label=labels[i], pose=p, timestamp=t, source=sources[i])  # type: ignore[arg-type]


def record_fingerprints(records: Sequence[bytes], labels: Sequence[str], sources: Sequence[Any], params: dict[str, Any], *, default_fov: Fov | None) -> list[Any]:
    """The fingerprints of the observations of ``records`` with the generation ``params``, in one batch."""
    from .._fingerprints import make_fingerprints

    obs = decode_rows(records, labels, sources, default_fov=default_fov)
    return make_fingerprints(
        obs, empty_step_deg=params["empty_step_deg"], merge_tol_deg=params["merge_tol_deg"], laser_letters=params["laser_letters"]
    )
