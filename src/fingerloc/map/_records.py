"""Observations as compact binary records (place database schema version 3; docs/FORMATS.md §2).

A record holds an :class:`~fingerloc.observation.Observation`'s numbers
exactly, as little-endian float64 in radians, without the place label (the
row's place gives it) or the source (a column of its own)::

    byte 0        codec version (1)
    byte 1        flags: 1 pose, 2 timestamp, 4 field of view, 8 appearance, 16 scan, 32 wide counts,
                  64 the database's default field of view (none stored), 128 wall lengths and
                  ranges as float32
    9 counts      VE, CP, Ex, c, B, W, fov ranges, appearance values, scan beams:
                  uint8 each, or uint32 each with the "wide counts" flag
    float64 data  VE, CP bearings, CP hues, Ex, c, B, W bearings, W lengths, W ranges
                  (with flag 128 these two as float32, after the float64 values),
                  pose (x, y, theta) if flagged, timestamp if flagged,
                  fov (start, width) pairs, appearance, scan ranges, scan bearings

Codec version 2 is version 1 plus a column profile (``Observation.profile``,
shape rows x channels): right after the counts, ``uint8 encoding, uint16
rows, uint16 channels``; the values come last, after everything above, as
int16 thousandths (encoding 2: used only when every value is a whole number of
thousandths that decodes bit for bit, as profiles read from JSON Lines are) or
float64 (encoding 1). An observation without a profile is written as version 1.

Codec version 3 is version 2 plus keypoints (``Observation.keypoints``):
the profile header is always there (encoding 0, 0 rows, 0 channels: no
profile), followed by ``uint32 n, uint16 dim``; the keypoints come last,
after the profile's values: ``3 n`` little-endian uint16 positions then
``n x dim`` uint8 descriptors, exactly the arrays of
:func:`fingerloc.features.keypoints.encode_keypoints` (bit for bit: the
extractor puts positions on that grid). An observation without keypoints is
written as version 1 or 2, so databases of older versions read as before.

Codec version 4 has the layout of version 3, with keypoints of
:data:`fingerloc.features.keypoints.KEYPOINT_VERSION` 2 (OpenCV SIFT; the
elevation stored as an angle). A version 3 record (keypoints of the former
hand-written detector) is refused with a message to extract the features
again.

Decoding gives back the very observation (every array bit for bit: the
stored bearings are already wrapped and sorted, and wrapping them again
changes nothing), so what the place database recomputes from it (the
fingerprints) equals what was computed before saving. The one quantised
encoding, float32 wall lengths and ranges (7 significant digits: 1 micrometre
at 10 m), is used by the database only when the fingerprint computed from
the decoded observation is bit for bit the one computed before (the wall
letters depend on them).
"""

from __future__ import annotations

import struct

import numpy as np

from ..errors import DatabaseError, FingerlocError
from ..observation import FULL_FOV, Observation

__all__ = ["decode_observation", "encode_observation"]

_VERSION = 1
_VERSION_PROFILE = 2
_VERSION_OLD_KEYPOINTS = 3
_VERSION_KEYPOINTS = 4
_PROFILE_NONE, _PROFILE_F64, _PROFILE_MILLI = 0, 1, 2
_PROFILE_HEAD = "<BHH"
_KEYPOINT_HEAD = "<IH"
_POSE, _TIME, _FOV, _APPEARANCE, _SCAN, _WIDE, _DEFAULT_FOV, _WALLS32 = 1, 2, 4, 8, 16, 32, 64, 128
Fov = tuple[tuple[float, float], ...]
_N_COUNTS = 9


def encode_observation(
    obs: Observation, *, scan: bool = True, default_fov: Fov | None = None, walls32: bool = False
) -> bytes:
    """The binary record of an observation (module docstring).

    ``scan=False`` leaves its range profile out; an observation whose field
    of view is ``default_fov`` stores none (the database keeps it once);
    ``walls32`` stores wall lengths and ranges as float32 when they stay
    positive and finite.
    """
    flags = 0
    fov: list[float] = []
    if default_fov is not None and obs.fov == default_fov:
        flags |= _DEFAULT_FOV
    elif obs.fov != FULL_FOV:
        fov = [v for pair in obs.fov for v in pair]
        flags |= _FOV
    tail: list[object] = []
    if obs.pose is not None:
        flags |= _POSE
        tail.append(np.asarray(obs.pose, dtype=np.float64))
    if obs.timestamp is not None:
        flags |= _TIME
        tail.append(np.asarray([obs.timestamp], dtype=np.float64))
    tail.append(np.asarray(fov, dtype=np.float64))
    app = np.empty(0) if obs.appearance is None else obs.appearance
    if obs.appearance is not None:
        flags |= _APPEARANCE
    tail.append(app)
    ranges = bearings = np.empty(0)
    if scan and obs.ranges is not None and obs.range_bearings is not None:
        flags |= _SCAN
        ranges, bearings = obs.ranges, obs.range_bearings
    tail += [ranges, bearings]
    walls: list[object] = [obs.w_length, obs.w_range]
    short = b""
    if walls32 and obs.w.size:
        w32 = np.concatenate([obs.w_length, obs.w_range]).astype("<f4")
        if np.all(np.isfinite(w32)) and np.all(w32 > 0):
            flags |= _WALLS32
            walls, short = [], w32.tobytes()
    counts = [obs.ve.size, obs.cp.size, obs.ex.size, obs.c.size, obs.b.size, obs.w.size, len(fov) // 2, app.size, ranges.size]
    wide = max(counts) > 255
    if wide:
        flags |= _WIDE
    kps = obs.keypoints
    if kps is not None:
        version = _VERSION_KEYPOINTS
    else:
        version = _VERSION if obs.profile is None else _VERSION_PROFILE
    head = struct.pack(f"<BB{_N_COUNTS}{'I' if wide else 'B'}", version, flags, *counts)
    prof_head = prof_data = kp_head = kp_data = b""
    if obs.profile is not None:
        mode, prof_data = _encode_profile(obs.profile)
        rows, cols = obs.profile.shape
        if rows > 0xFFFF or cols > 0xFFFF:
            raise DatabaseError(f"a view's profile is too large to store ({rows} x {cols})")
        prof_head = struct.pack(_PROFILE_HEAD, mode, rows, cols)
    elif kps is not None:
        prof_head = struct.pack(_PROFILE_HEAD, _PROFILE_NONE, 0, 0)
    if kps is not None:
        from ..features.keypoints import keypoint_arrays

        pos, desc = keypoint_arrays(kps)
        if len(kps) > 0xFFFFFFFF or kps.dim > 0xFFFF:
            raise DatabaseError(f"a view's keypoints are too many to store ({len(kps)} x {kps.dim})")
        kp_head = struct.pack(_KEYPOINT_HEAD, len(kps), kps.dim)
        kp_data = pos.tobytes() + desc.tobytes()
    arrays = [obs.ve, obs.cp, obs.cp_hue, obs.ex, obs.c, obs.b, obs.w, *walls, *tail]
    body = b"".join(np.ascontiguousarray(a, dtype="<f8").tobytes() for a in arrays)  # type: ignore[call-overload]
    return head + prof_head + kp_head + body + short + prof_data + kp_data


def _encode_profile(profile: np.ndarray) -> tuple[int, bytes]:
    """The profile's values: int16 thousandths when that is exact bit for bit, else float64."""
    with np.errstate(invalid="ignore", over="ignore"):
        milli = np.rint(profile * 1000.0)
    if np.all(np.abs(milli) <= 32767):
        m16 = milli.astype("<i2")
        if np.array_equal(m16.astype(np.float64) / 1000.0, profile):
            return _PROFILE_MILLI, m16.tobytes()
    return _PROFILE_F64, np.ascontiguousarray(profile, dtype="<f8").tobytes()


#: Largest |x| or |y| of a stored pose, metres (the JSON Lines reader's bound).
_MAX_COORD_M = 1e9


def _check_pose_time(pose: tuple[float, ...] | None, timestamp: float | None) -> None:
    """A decoded pose must be finite and within +-1e9 m, a timestamp finite."""
    if pose is not None and not (
        all(np.isfinite(v) for v in pose) and abs(pose[0]) <= _MAX_COORD_M and abs(pose[1]) <= _MAX_COORD_M
    ):
        raise DatabaseError(
            f"corrupt observation record in the place database (pose {pose!r}: finite, x and y within +-1e9 m)"
        )
    if timestamp is not None and not np.isfinite(timestamp):
        raise DatabaseError(f"corrupt observation record in the place database (timestamp {timestamp!r})")


def decode_observation(
    data: object, *, label: str | None = None, source: str | None = None, default_fov: Fov | None = None
) -> Observation:
    """The observation of a binary record (:func:`encode_observation`), with its place label and source.

    Raises
    ------
    DatabaseError
        When the record is not one (wrong type, version, length, or values an observation refuses).
    """
    if not isinstance(data, bytes) or len(data) < 2 + _N_COUNTS:
        raise DatabaseError(f"corrupt observation record in the place database (got {type(data).__name__})")
    version, flags = data[0], data[1]
    if version == _VERSION_OLD_KEYPOINTS:
        from ..features.keypoints import OLD_KEYPOINTS_MESSAGE

        raise DatabaseError(f"the place database holds {OLD_KEYPOINTS_MESSAGE}")
    if version not in (_VERSION, _VERSION_PROFILE, _VERSION_KEYPOINTS) or (flags & _FOV and flags & _DEFAULT_FOV) or (flags & _DEFAULT_FOV and default_fov is None):
        raise DatabaseError(f"corrupt observation record in the place database (version {version}, flags {flags})")
    fmt = f"<{_N_COUNTS}{'I' if flags & _WIDE else 'B'}"
    start = 2 + struct.calcsize(fmt)
    if len(data) < start:
        raise DatabaseError("corrupt observation record in the place database (truncated)")
    n_ve, n_cp, n_ex, n_c, n_b, n_w, n_fov, n_app, n_scan = struct.unpack_from(fmt, data, 2)
    prof_mode = prof_rows = prof_cols = prof_bytes = kp_n = kp_dim = kp_bytes = 0
    if version in (_VERSION_PROFILE, _VERSION_KEYPOINTS):
        if len(data) < start + struct.calcsize(_PROFILE_HEAD):
            raise DatabaseError("corrupt observation record in the place database (truncated)")
        prof_mode, prof_rows, prof_cols = struct.unpack_from(_PROFILE_HEAD, data, start)
        start += struct.calcsize(_PROFILE_HEAD)
        modes = (_PROFILE_F64, _PROFILE_MILLI) + ((_PROFILE_NONE,) if version == _VERSION_KEYPOINTS else ())
        if prof_mode not in modes or (prof_mode == _PROFILE_NONE and (prof_rows or prof_cols)):
            raise DatabaseError(f"corrupt observation record in the place database (profile encoding {prof_mode})")
        prof_bytes = prof_rows * prof_cols * (8 if prof_mode == _PROFILE_F64 else 2)
    if version == _VERSION_KEYPOINTS:
        if len(data) < start + struct.calcsize(_KEYPOINT_HEAD):
            raise DatabaseError("corrupt observation record in the place database (truncated)")
        kp_n, kp_dim = struct.unpack_from(_KEYPOINT_HEAD, data, start)
        start += struct.calcsize(_KEYPOINT_HEAD)
        kp_bytes = 6 * kp_n + kp_n * kp_dim
    w32 = bool(flags & _WALLS32)
    sizes = [n_ve, n_cp, n_cp, n_ex, n_c, n_b, n_w] + ([] if w32 else [n_w, n_w])
    sizes += [3] if flags & _POSE else []
    sizes += [1] if flags & _TIME else []
    sizes += [2 * n_fov, n_app, n_scan, n_scan]
    n64 = sum(sizes)
    if (
        len(data) != start + 8 * n64 + (8 * n_w if w32 else 0) + prof_bytes + kp_bytes
        or bool(n_fov) != bool(flags & _FOV)
        or bool(n_app) != bool(flags & _APPEARANCE)
    ):
        raise DatabaseError("corrupt observation record in the place database (its length does not match its counts)")
    values = np.frombuffer(data, dtype="<f8", offset=start, count=n64).astype(np.float64)
    parts = np.split(values, np.cumsum(sizes)[:-1])
    ve, cp, hue, ex, c, b, w = parts[:7]
    if w32:
        with np.errstate(invalid="ignore"):  # a NaN pattern: the observation refuses it below
            short = np.frombuffer(data, dtype="<f4", offset=start + 8 * n64, count=2 * n_w).astype(np.float64)
        w_len, w_rng = short[:n_w], short[n_w:]
        rest = parts[7:]
    else:
        w_len, w_rng = parts[7], parts[8]
        rest = parts[9:]
    pose = tuple(float(v) for v in rest.pop(0)) if flags & _POSE else None
    timestamp = float(rest.pop(0)[0]) if flags & _TIME else None
    _check_pose_time(pose, timestamp)
    fov_v, app, ranges, bearings = rest
    fov = tuple((float(fov_v[2 * k]), float(fov_v[2 * k + 1])) for k in range(n_fov)) if n_fov else FULL_FOV
    if flags & _DEFAULT_FOV and default_fov is not None:
        fov = default_fov
    scan = bool(flags & _SCAN)
    profile = None
    keypoints = None
    if version == _VERSION_KEYPOINTS:
        from ..features.keypoints import keypoints_from_arrays

        at = len(data) - kp_bytes
        pos = np.frombuffer(data, dtype="<u2", offset=at, count=3 * kp_n)
        desc = np.frombuffer(data, dtype=np.uint8, offset=at + 6 * kp_n, count=kp_n * kp_dim)
        try:
            keypoints = keypoints_from_arrays(pos, desc, kp_n, kp_dim)
        except FingerlocError as err:
            raise DatabaseError(f"corrupt observation record in the place database ({err})") from err
    if prof_mode != _PROFILE_NONE:
        at = len(data) - kp_bytes - prof_bytes
        if prof_mode == _PROFILE_MILLI:
            profile = np.frombuffer(data, dtype="<i2", offset=at, count=prof_rows * prof_cols).astype(np.float64).reshape(prof_rows, prof_cols) / 1000.0
        else:
            with np.errstate(invalid="ignore"):  # a NaN pattern: the observation refuses it below
                profile = np.frombuffer(data, dtype="<f8", offset=at, count=prof_rows * prof_cols).astype(np.float64).reshape(prof_rows, prof_cols)
    try:
        return Observation(
            ve=ve, cp=cp, cp_hue=hue, ex=ex, c=c, b=b, w=w, w_length=w_len, w_range=w_rng,
            ranges=ranges if scan else None, range_bearings=bearings if scan else None,
            fov=fov, label=label, pose=pose, timestamp=timestamp,  # type: ignore[arg-type]
            appearance=app if flags & _APPEARANCE else None, source=source, profile=profile,
            keypoints=keypoints,
        )  # fmt: skip
    except FingerlocError as err:
        raise DatabaseError(f"corrupt observation record in the place database ({err})") from err
