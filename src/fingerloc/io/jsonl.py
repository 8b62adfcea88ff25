"""Observations as JSON Lines (docs/FORMATS.md §1).

One observation a line, bearings and angles in degrees::

    {"place": "office-3", "pose": [x, y, theta_deg], "fov": [[-90, 90]],
     "features": {"VE": [12.5, 80.0], "CP": [{"bearing": 40.0, "hue": 130.0}],
                  "Ex": [...], "c": [...], "B": [...]},
     "timestamp": 12.5}

``fov`` lists counter-clockwise ``[start, end]`` ranges in degrees; a record
without it saw the full circle. Two optional laser extensions (ours):
``features.W`` lists wall segments ``{"bearing": deg, "length": m, "range": m}``,
and ``"scan": {"bearings": [deg, ...], "ranges": [m or null, ...]}`` holds the
raw range profile (``null`` where a beam had no return). Two optional camera
extensions: ``"appearance": [x, ...]`` is the heading-free appearance
descriptor of the view (numbers >= 0, see
:func:`fingerloc.features.vision.appearance_descriptor`), ``"source"`` the
file an observation was extracted from, and ``"profile": [[x, ...], ...]`` the
view at each bearing (rows: equal sectors counter-clockwise from bearing 0,
see :func:`fingerloc.features.vision.column_profile`; written with three
decimals), and ``"keypoints": {"n", "dim", "pos", "desc"}`` the view's local
features (base64 arrays, see :func:`fingerloc.features.keypoints.encode_keypoints`). ``place``, ``pose`` and ``timestamp`` are
optional; ``features`` is required (it may be empty). Blank lines are skipped.
Other top-level keys are ignored, so tools may carry their own.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..angles import TWO_PI, deg_to_rad, rad_to_deg360, wrap
from ..errors import DataFormatError, EmptyInputError, FingerlocError
from ..observation import FEATURE_TYPES, FULL_FOV, Observation, fov_from_degrees

__all__ = [
    "MAX_LINE_BYTES",
    "check_text",
    "iter_lines",
    "iter_observations",
    "observation_from_record",
    "observation_to_record",
    "parse_record",
    "read_observations",
    "write_observations",
]


#: Most digits of an integer in a record (a longer one is refused before Python converts it).
MAX_INT_DIGITS = 40


def _parse_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise _LimitError(f"integer of {len(text.lstrip('-'))} digits (at most {MAX_INT_DIGITS})")
    return int(text)


#: Largest |x| or |y| of a pose, metres (beyond it, distances overflow; no map is that large).
MAX_COORD_M = 1e9

#: Longest line (bytes) of a JSON Lines file: a view with 500 keypoints, a profile and a 3600-beam scan takes
#: under 1 MB; a longer line (a file of NUL bytes, ``/dev/zero``) is refused before it fills the memory.
MAX_LINE_BYTES = 16 << 20


class _LimitError(ValueError):
    """A record exceeds a parsing limit (raised inside ``json.loads``)."""


_DECODER = json.JSONDecoder(parse_int=_parse_int)


def parse_record(line: str) -> Any:
    """Decode one JSON Lines record with fingerloc's limits.

    Integers of more than :data:`MAX_INT_DIGITS` digits are refused (they
    would overflow a float or cost quadratic time), and so is nesting deeper
    than the interpreter's recursion limit. ``NaN`` and ``Infinity`` decode
    (as Python's json does) and are refused by the field checks.

    Raises
    ------
    DataFormatError
        Without a location (callers add it).
    """
    try:
        if not isinstance(line, str):
            return json.loads(line, parse_int=_parse_int)
        if line.startswith("\ufeff"):  # what json.loads checks before decoding
            raise json.JSONDecodeError("Unexpected UTF-8 BOM (decode using utf-8-sig)", line, 0)
        return _DECODER.decode(line)  # json.loads(line, parse_int=...) without building a decoder per line
    except json.JSONDecodeError as err:
        raise DataFormatError(f"malformed JSON ({err.msg} at column {err.colno})") from err
    except _LimitError as err:
        raise DataFormatError(str(err)) from err
    except RecursionError as err:
        raise DataFormatError("record nested too deeply (arrays or objects inside each other)") from err


def check_text(value: str, what: str) -> str:
    """A string of a record must be valid Unicode text: lone surrogates (``"\\ud800"``) are refused."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError as err:
        raise DataFormatError(f"{what} holds an unpaired surrogate ({value!r}); use valid Unicode text") from err
    return value


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DataFormatError(f"{what} must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise DataFormatError(f"{what} must be finite, got {value!r}")
    return x


def _bearing_list(value: Any, key: str) -> list[float]:
    if not isinstance(value, list):
        raise DataFormatError(f"features.{key} must be a list of bearings in degrees, got {value!r}")
    return [_number(v, f"bearing in features.{key}") for v in value]


#: Feature keys the fast path reads (plain bearing lists) -> the Observation attribute.
_FAST_KEYS = {"VE": "ve", "Ex": "ex", "c": "c", "B": "b"}
#: Top-level keys the fast path understands; a record with another known key takes the validating path.
_SLOW_KEYS = frozenset({"scan", "appearance", "profile", "keypoints"})


def _fast_numbers(values: Any) -> list[float] | None:
    """``values`` as floats when it is a list of plain finite numbers that need no conversion check; else None."""
    if type(values) is not list:
        return None
    for v in values:
        t = type(v)
        if t is not float and (t is not int or not -(2**53) <= v <= 2**53):
            return None
    out = [float(v) for v in values]
    return out if all(map(math.isfinite, out)) else None


def _fast_observation(record: Any) -> Observation | None:
    """The observation of a plain record (bearing lists, place, pose, fov, timestamp, source), or None.

    None whenever anything is unusual (another feature type, a value that is
    not a plain finite number, a key it does not read, a wrong type...): the
    validating path then builds the observation or names the error. What it
    returns equals, bit for bit, what the validating path builds
    (``tests/test_io_jsonl.py`` checks both on drawn and hostile records).
    """
    if type(record) is not dict or "features" not in record or not _SLOW_KEYS.isdisjoint(record):
        return None
    feats = record["features"]
    if type(feats) is not dict:
        return None
    lists: list[tuple[str, list[float]]] = []
    for key, value in feats.items():
        attr = _FAST_KEYS.get(key)
        vals = None if attr is None else _fast_numbers(value)
        if vals is None:
            return None
        if vals:
            lists.append((attr, vals))  # type: ignore[arg-type]
    place = record.get("place")
    if place is not None and (type(place) is not str or not _valid_text(place)):
        return None
    source = record.get("source")
    if source is not None and type(source) is not str:
        return None
    pose = record.get("pose")
    if pose is not None:
        p = _fast_numbers(pose)
        if p is None or len(p) != 3 or max(abs(p[0]), abs(p[1])) > MAX_COORD_M:
            return None
        pose = (p[0], p[1], float(deg_to_rad(p[2])))
    ts = record.get("timestamp")
    if ts is not None:
        t = _fast_numbers([ts])
        if t is None:
            return None
        ts = t[0]
    fov = record.get("fov")
    if fov is None:
        fov_t = FULL_FOV
    else:
        if type(fov) is not list or not fov:
            return None
        bounds = []
        for r in fov:
            b = _fast_numbers(r)
            if b is None or len(b) != 2 or b[0] == b[1]:
                return None
            bounds.append(b)
        # Observation.from_degrees, then Observation.__post_init__'s normal form (the same calls)
        fov_t = tuple((float(wrap(s)), min(w, TWO_PI)) for s, w in fov_from_degrees(bounds))
    bearings: dict[str, Any] = {}
    if lists:
        # deg_to_rad (from_degrees), then wrap again (__post_init__): elementwise, so one call for all types
        flat = wrap(deg_to_rad(np.array([v for _, vals in lists for v in vals], dtype=np.float64)))
        k = 0
        for attr, vals in lists:
            arr = np.sort(flat[k : k + len(vals)])
            arr.setflags(write=False)
            bearings[attr] = arr
            k += len(vals)
    return Observation._checked(bearings, fov=fov_t, label=place, pose=pose, timestamp=ts, source=source)


def _valid_text(value: str) -> bool:
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def observation_from_record(record: Any) -> Observation:
    """Build an :class:`Observation` from one decoded JSON record.

    Raises
    ------
    DataFormatError
        Naming the bad key or value (without a location: callers add it).
    """
    fast = _fast_observation(record)
    if fast is not None:
        return fast
    if not isinstance(record, Mapping):
        raise DataFormatError(f"a record must be a JSON object, got {type(record).__name__}")
    if "features" not in record:
        raise DataFormatError('missing key "features" (use {} for an observation without features)')
    feats = record["features"]
    if not isinstance(feats, Mapping):
        raise DataFormatError(f'"features" must be an object, got {feats!r}')
    out: dict[str, Any] = {}
    for key, value in feats.items():
        if key not in FEATURE_TYPES:
            raise DataFormatError(f"unknown feature type {key!r} (expected one of {', '.join(FEATURE_TYPES)})")
        if key == "CP":
            if not isinstance(value, list):
                raise DataFormatError(f"features.CP must be a list of {{bearing, hue}} objects, got {value!r}")
            cps = []
            for p in value:
                if not isinstance(p, Mapping) or "bearing" not in p or "hue" not in p:
                    raise DataFormatError(f'each colour patch must be {{"bearing": .., "hue": ..}}, got {p!r}')
                b = _number(p["bearing"], "bearing in features.CP")
                h = _number(p["hue"], "hue in features.CP")
                if not 0.0 <= h < 360.0:
                    raise DataFormatError(f"hue must be in [0, 360) degrees, got {p['hue']!r}")
                cps.append((b, h))
            out[key] = cps
        elif key == "W":
            if not isinstance(value, list):
                raise DataFormatError(f"features.W must be a list of {{bearing, length, range}} objects, got {value!r}")
            walls = []
            for p in value:
                if not isinstance(p, Mapping) or not {"bearing", "length", "range"} <= set(p):
                    raise DataFormatError(f'each wall must be {{"bearing": .., "length": .., "range": ..}}, got {p!r}')
                vals = tuple(_number(p[k], f"{k} in features.W") for k in ("bearing", "length", "range"))
                if vals[1] <= 0 or vals[2] <= 0:
                    raise DataFormatError(f"wall length and range must be > 0 metres, got {p!r}")
                walls.append(vals)
            out[key] = walls
        else:
            out[key] = _bearing_list(value, key)
    place = record.get("place")
    if place is not None and not isinstance(place, str):
        raise DataFormatError(f'"place" must be a string or null, got {place!r}')
    if place is not None:
        check_text(place, '"place"')
    pose = record.get("pose")
    if pose is not None:
        if not isinstance(pose, list) or len(pose) != 3:
            raise DataFormatError(f'"pose" must be [x, y, theta_deg], got {pose!r}')
        pose = [_number(v, "pose value") for v in pose]
        if max(abs(pose[0]), abs(pose[1])) > MAX_COORD_M:
            raise DataFormatError(f'"pose" x and y must be within +-{MAX_COORD_M:g} metres, got {record["pose"]!r}')
    fov = record.get("fov")
    if fov is not None:
        if not isinstance(fov, list) or not fov:
            raise DataFormatError(f'"fov" must be a non-empty list of [start, end] ranges in degrees, got {fov!r}')
        for r in fov:
            if not isinstance(r, list) or len(r) != 2:
                raise DataFormatError(f'each "fov" range must be [start, end] in degrees, got {r!r}')
        fov = [[_number(r[0], "fov bound"), _number(r[1], "fov bound")] for r in fov]
    ts = record.get("timestamp")
    if ts is not None:
        ts = _number(ts, '"timestamp"')
    ranges = range_bearings = None
    scan = record.get("scan")
    if scan is not None:
        if not isinstance(scan, Mapping) or not isinstance(scan.get("bearings"), list) or not isinstance(
            scan.get("ranges"), list
        ):
            raise DataFormatError('"scan" must be {"bearings": [deg, ...], "ranges": [m or null, ...]}')
        if len(scan["bearings"]) != len(scan["ranges"]):
            raise DataFormatError('"scan": one range per bearing is needed')
        range_bearings = np.deg2rad([_number(b, "scan bearing") for b in scan["bearings"]])
        ranges = np.array([np.inf if r is None else _number(r, "scan range") for r in scan["ranges"]])
        if np.any(ranges < 0):
            raise DataFormatError(f'"scan": ranges must be >= 0 metres, got {float(ranges[ranges < 0][0])!r}')
    appearance = record.get("appearance")
    if appearance is not None:
        if not isinstance(appearance, list) or not appearance:
            raise DataFormatError(f'"appearance" must be a non-empty list of numbers >= 0, got {appearance!r}')
        appearance = [_number(v, '"appearance" value') for v in appearance]
        if min(appearance) < 0:
            raise DataFormatError(f'"appearance" values must be >= 0, got {min(appearance)!r}')
    source = record.get("source")
    if source is not None and not isinstance(source, str):
        raise DataFormatError(f'"source" must be a string or null, got {source!r}')
    profile = record.get("profile")
    if profile is not None:
        if (
            not isinstance(profile, list)
            or len(profile) < 4
            or not all(isinstance(r, list) and r and len(r) == len(profile[0]) for r in profile)
        ):
            raise DataFormatError(
                '"profile" must be a list of at least 4 rows, each a non-empty list of numbers of one length'
            )
        profile = [[_number(v, '"profile" value') for v in r] for r in profile]
    keypoints = record.get("keypoints")
    if keypoints is not None:
        from ..features.keypoints import decode_keypoints

        if not isinstance(keypoints, Mapping):
            raise DataFormatError('"keypoints" must be {"n", "dim", "pos", "desc"} (see docs/FORMATS.md)')
        try:
            keypoints = decode_keypoints(keypoints)
        except DataFormatError:
            raise
        except FingerlocError as err:
            raise DataFormatError(f'"keypoints": {err}') from err
    try:
        obs = Observation.from_degrees(
            out,
            fov=fov,
            label=place,
            pose=pose,
            timestamp=ts,
            appearance=appearance,
            source=source,
            profile=profile,
        )
        if ranges is not None:
            obs = replace(obs, ranges=ranges, range_bearings=range_bearings)
        if keypoints is not None:
            obs = replace(obs, keypoints=keypoints)
        return obs
    except DataFormatError:
        raise
    except FingerlocError as err:
        raise DataFormatError(str(err)) from err


def observation_to_record(obs: Observation, *, ndigits: int = 9) -> dict[str, Any]:
    """The JSON-ready record of an observation (degrees)."""

    def degs(a: np.ndarray) -> list[float]:
        return [round(float(x), ndigits) for x in rad_to_deg360(a)]

    feats: dict[str, Any] = {}
    for key in FEATURE_TYPES:
        if key == "CP":
            if obs.cp.size:
                feats["CP"] = [
                    {"bearing": b, "hue": round(float(h), ndigits)}
                    for b, h in zip(degs(obs.cp), obs.cp_hue, strict=True)
                ]
        elif key == "W":
            if obs.w.size:
                feats["W"] = [
                    {"bearing": b, "length": round(float(ln), ndigits), "range": round(float(r), ndigits)}
                    for b, ln, r in zip(degs(obs.w), obs.w_length, obs.w_range, strict=True)
                ]
        elif obs.bearings(key).size:
            feats[key] = degs(obs.bearings(key))
    rec: dict[str, Any] = {}
    if obs.label is not None:
        rec["place"] = obs.label
    if obs.pose is not None:
        x, y, th = obs.pose
        rec["pose"] = [x, y, round(float(np.rad2deg(th)), ndigits)]
    if not obs.full_fov:
        rec["fov"] = []
        for s, w in obs.fov:
            start = round(float(np.rad2deg(s)), ndigits)
            rec["fov"].append([start, round(start + float(np.rad2deg(w)), ndigits)])
    if obs.timestamp is not None:
        rec["timestamp"] = obs.timestamp
    if obs.source is not None:
        rec["source"] = obs.source
    rec["features"] = feats
    if obs.appearance is not None:
        rec["appearance"] = [round(float(x), ndigits) for x in obs.appearance]
    if obs.profile is not None:  # standardised values: three decimals are plenty
        rec["profile"] = [[round(float(x), min(ndigits, 3)) for x in r] for r in obs.profile]
    if obs.keypoints is not None:
        from ..features.keypoints import encode_keypoints

        rec["keypoints"] = encode_keypoints(obs.keypoints)
    if obs.ranges is not None and obs.range_bearings is not None:
        rec["scan"] = {
            "bearings": [round(float(b), ndigits) for b in np.rad2deg(obs.range_bearings)],
            "ranges": [None if not np.isfinite(r) else round(float(r), 4) for r in obs.ranges],
        }
    return rec


def iter_lines(path: str | Path) -> Iterator[tuple[int, str]]:
    """The non-blank lines of a text file with their 1-based numbers, each at most :data:`MAX_LINE_BYTES`.

    The file is opened once (a pipe or a FIFO works) and read as UTF-8.

    Raises
    ------
    DataFormatError
        The file cannot be read, is binary (a NUL byte), is not UTF-8, or has a line too long (naming the line).
    """
    p = Path(path)
    try:
        fh = open(p, "rb")
    except OSError as err:
        raise DataFormatError(f"cannot read: {err.strerror or err}", path=p) from err
    with fh:
        lineno = 0
        while True:
            try:
                raw = fh.readline(MAX_LINE_BYTES + 1)
            except OSError as err:
                raise DataFormatError(f"cannot read after line {lineno}: {err.strerror or err}", path=p) from err
            if not raw:
                return
            lineno += 1
            if len(raw) > MAX_LINE_BYTES:
                what = "binary data (NUL bytes), not JSON Lines" if b"\x00" in raw[:4096] else (
                    f"line longer than {MAX_LINE_BYTES:,} bytes")  # fmt: skip
                raise DataFormatError(what, path=p, line=lineno)
            if not raw.strip():
                continue
            if b"\x00" in raw:
                raise DataFormatError("binary data (a NUL byte), not JSON Lines", path=p, line=lineno)
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError as err:
                raise DataFormatError("not a UTF-8 text file", path=p, line=lineno) from err
            yield lineno, text


def iter_observations(path: str | Path) -> Iterator[Observation]:
    """Stream the observations of a JSON Lines file, one per non-blank line (:func:`iter_lines`).

    Raises
    ------
    DataFormatError
        On a malformed line, naming the path, the line number and the bad value.
    EmptyInputError
        When the file holds no observation.
    """
    p = Path(path)
    count = 0
    for lineno, line in iter_lines(p):
        try:
            record = parse_record(line)
            obs = observation_from_record(record)
        except DataFormatError as err:
            raise err.at(path=p, line=lineno) from err
        count += 1
        yield obs
    if count == 0:
        raise EmptyInputError("no observation in file (empty)", path=p)


def read_observations(path: str | Path) -> list[Observation]:
    """Read every observation of a JSON Lines file (see :func:`iter_observations`)."""
    return list(iter_observations(path))


def write_observations(path: str | Path, observations: Iterable[Observation]) -> int:
    """Write observations as JSON Lines, atomically (a temporary file renamed over ``path``).

    ``-`` writes to standard output. A symbolic link at ``path`` stays a link
    (its target is replaced); a device, FIFO or link loop is refused
    (:func:`fingerloc.atomic.check_target`); inside an
    :class:`~fingerloc.atomic.OutputGroup` the rename waits for the group's end.

    Returns
    -------
    int
        Number of observations written.
    """
    import sys

    from ..atomic import check_target, replacing

    n = 0
    if str(path) == "-":
        for obs in observations:
            sys.stdout.write(json.dumps(observation_to_record(obs), separators=(", ", ": "), allow_nan=False) + "\n")
            n += 1
        sys.stdout.flush()
        return n
    target = check_target(path, str(path))
    with replacing(target) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        for obs in observations:
            fh.write(json.dumps(observation_to_record(obs), separators=(", ", ": "), allow_nan=False) + "\n")
            n += 1
    return n
