"""The core measurement type: one :class:`Observation` at one pose.

An observation holds, per feature type, the bearings (radians, wrapped to
``[-pi, pi)``) at which the sensors saw features, the hue of each colour patch,
and the field of view the sensors covered. It is immutable: its arrays are
read-only and every field is validated on construction.

Feature types (docs/METHOD.md §1):

========  =====================================  ===========
key       feature                                letter
========  =====================================  ===========
``VE``    vertical edge (camera)                 ``v``
``CP``    colour patch with a hue (camera)       ``A``-``P``
``Ex``    extremity of a laser line segment      (none)
``c``     corner (laser)                         ``c``
``B``     beacon (laser, high reflectance)       ``b``
``W``     wall segment with length and range     (laser letters, see
          (laser; our extension)                 :mod:`fingerloc.fingerprint`)
========  =====================================  ===========

An observation may also carry the raw range profile of its laser scan
(``ranges`` at ``range_bearings``), which the range term ``R`` of
:class:`~fingerloc.model.PlaceModel` uses.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from ._types import FArray
from .angles import TWO_PI, deg_to_rad, wrap
from .errors import InvalidParameterError

if TYPE_CHECKING:
    from .keypoints import Keypoints

__all__ = ["FEATURE_TYPES", "FULL_FOV", "Observation", "fov_from_degrees"]

#: Feature-type keys, in the order used everywhere (files, models, output).
FEATURE_TYPES: tuple[str, ...] = ("VE", "CP", "Ex", "c", "B", "W")

#: The full circle as a field of view: one range, start -pi, width 2 pi.
FULL_FOV: tuple[tuple[float, float], ...] = ((-np.pi, TWO_PI),)



def _readonly(a: ArrayLike, name: str) -> FArray:
    arr = np.array(a, dtype=np.float64, copy=True).reshape(-1)
    if not np.all(np.isfinite(arr)):
        bad = arr[~np.isfinite(arr)][0]
        raise InvalidParameterError(f"{name}: bearings must be finite, got {bad!r}")
    arr.setflags(write=False)
    return arr


def fov_from_degrees(ranges: Sequence[Sequence[float]] | None) -> tuple[tuple[float, float], ...]:
    """Convert ``[[start, end], ...]`` in degrees into ``((start, width), ...)`` in radians.

    Each range runs counter-clockwise from ``start`` to ``end``. ``end - start``
    of a multiple of 360 other than 0 (e.g. ``[0, 360]``) is the full circle;
    ``start == end`` is an empty range and an error. ``None`` means the full
    circle.

    Returns
    -------
    tuple of (start_rad, width_rad)
        ``start`` wrapped to ``[-pi, pi)``, ``width`` in ``(0, 2 pi]``.
    """
    if ranges is None:
        return FULL_FOV
    out: list[tuple[float, float]] = []
    for r in ranges:
        if len(r) != 2:
            raise InvalidParameterError(f"fov: each range must be [start, end] in degrees, got {list(r)!r}")
        start, end = float(r[0]), float(r[1])
        if not (np.isfinite(start) and np.isfinite(end)):
            raise InvalidParameterError(f"fov: range bounds must be finite, got {[start, end]!r}")
        if start == end:
            raise InvalidParameterError(f"fov: empty range [{start}, {end}] (start equals end)")
        width = float(np.mod(end - start, 360.0))
        if width < 1e-9 or width > 360.0 - 1e-9:
            width = 360.0
        out.append((float(deg_to_rad(start)), float(np.deg2rad(width))))
    if not out:
        raise InvalidParameterError("fov: at least one range is needed (omit fov for the full circle)")
    return tuple(out)


def _check_label(label: Any) -> None:
    if label is not None and not isinstance(label, str):
        raise InvalidParameterError(f"label: must be a string or None, got {label!r}")


@dataclass(frozen=True, slots=True, eq=False)
class Observation:
    """One measurement: feature bearings seen from one pose.

    Parameters
    ----------
    ve, ex, c, b : array_like of float, shape (n,)
        Bearings in radians of vertical edges, extremities, corners and
        beacons. Wrapped to ``[-pi, pi)`` and sorted on construction.
    cp : array_like of float, shape (m,)
        Bearings in radians of colour patches.
    cp_hue : array_like of float, shape (m,)
        Hue of each colour patch in degrees, in ``[0, 360)``.
    w : array_like of float, shape (k,)
        Bearings in radians of the midpoints of fitted wall segments (laser).
    w_length, w_range : array_like of float, shape (k,)
        Length of each wall segment and range of its midpoint, metres (> 0).
    ranges : array_like of float, shape (r,), optional
        Raw laser ranges in metres (``inf`` where a beam had no return).
    range_bearings : array_like of float, shape (r,), optional
        Bearing of each range in radians (robot frame); required with ``ranges``.
    fov : tuple of (start, width), optional
        Field of view in radians: ranges running counter-clockwise from
        ``start`` for ``width`` (``0 < width <= 2 pi``). Default: full circle.
        Build it from degrees with :func:`fov_from_degrees`.
    label : str, optional
        The place this observation was taken at, when known.
    pose : (x, y, theta), optional
        Pose in metres and radians, when known.
    timestamp : float, optional
        Seconds, when known.
    appearance : array_like of float, shape (d,), optional
        A heading-free appearance descriptor of the view (for the camera: the
        colour and gradient histograms of :func:`fingerloc.features.vision.appearance_descriptor`),
        finite and ``>= 0``; the appearance term ``A`` compares it between views.
    profile : array_like of float, shape (columns, channels), optional
        What the view looks like at each bearing: row ``k`` describes the
        bearings ``[k, k + 1) * 360 / columns`` degrees counter-clockwise
        (for the camera: :func:`fingerloc.features.vision.column_profile`),
        finite. Headings between views and the aligned-profile term ``AP``
        compare it over every rotation.
    source : str, optional
        The file the observation was extracted from (an image, a log), as the
        user gave it.
    keypoints : Keypoints, optional
        Local features of the view (for the camera:
        :func:`fingerloc.features.keypoints.extract_keypoints`: bearings,
        elevations and upright descriptors); the local-feature term ``K``
        counts the keypoints two views share.
    """

    ve: FArray = field(default_factory=lambda: np.empty(0))
    cp: FArray = field(default_factory=lambda: np.empty(0))
    cp_hue: FArray = field(default_factory=lambda: np.empty(0))
    ex: FArray = field(default_factory=lambda: np.empty(0))
    c: FArray = field(default_factory=lambda: np.empty(0))
    b: FArray = field(default_factory=lambda: np.empty(0))
    w: FArray = field(default_factory=lambda: np.empty(0))
    w_length: FArray = field(default_factory=lambda: np.empty(0))
    w_range: FArray = field(default_factory=lambda: np.empty(0))
    ranges: FArray | None = None
    range_bearings: FArray | None = None
    fov: tuple[tuple[float, float], ...] = FULL_FOV
    label: str | None = None
    pose: tuple[float, float, float] | None = None
    timestamp: float | None = None
    appearance: FArray | None = None
    source: str | None = None
    profile: FArray | None = None
    keypoints: Keypoints | None = None

    def __post_init__(self) -> None:
        for name in ("ve", "ex", "c", "b"):
            arr = np.sort(wrap(_readonly(getattr(self, name), name)))
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        cp = wrap(_readonly(self.cp, "cp"))
        hue = _readonly(self.cp_hue, "cp_hue")
        if cp.shape != hue.shape:
            raise InvalidParameterError(
                f"cp_hue: one hue per colour patch is needed, got {hue.size} hues for {cp.size} patches"
            )
        if np.any((hue < 0.0) | (hue >= 360.0)):
            bad = hue[(hue < 0.0) | (hue >= 360.0)][0]
            raise InvalidParameterError(f"cp_hue: hue must be in [0, 360) degrees, got {bad!r}")
        order = np.lexsort((hue, cp))
        for name, arr in (("cp", cp[order]), ("cp_hue", hue[order])):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        self._init_walls_and_ranges()
        fov = tuple((float(s), float(w)) for s, w in self.fov)
        if not fov:
            raise InvalidParameterError("fov: at least one range is needed")
        for s, w in fov:
            if not (np.isfinite(s) and np.isfinite(w)) or not (0.0 < w <= TWO_PI + 1e-12):
                raise InvalidParameterError(f"fov: width must be in (0, 2 pi] radians, got {w!r}")
        object.__setattr__(self, "fov", tuple((float(wrap(s)), min(w, TWO_PI)) for s, w in fov))
        _check_label(self.label)
        if self.pose is not None:
            pose = tuple(float(v) for v in self.pose)
            if len(pose) != 3 or not all(np.isfinite(pose)):
                raise InvalidParameterError(f"pose: must be three finite numbers (x, y, theta), got {self.pose!r}")
            object.__setattr__(self, "pose", pose)
        if self.timestamp is not None:
            ts = float(self.timestamp)
            if not np.isfinite(ts):
                raise InvalidParameterError(f"timestamp: must be finite, got {self.timestamp!r}")
            object.__setattr__(self, "timestamp", ts)
        if self.appearance is not None:
            try:
                app = np.array(self.appearance, dtype=np.float64, copy=True)
            except (TypeError, ValueError) as err:
                raise InvalidParameterError(
                    f"appearance: must be a 1-D array of numbers, got {self.appearance!r}"
                ) from err
            if app.ndim != 1 or app.size == 0:
                raise InvalidParameterError(f"appearance: must be a non-empty 1-D array, got shape {app.shape}")
            if not np.all(np.isfinite(app)) or np.any(app < 0):
                bad = app[~(np.isfinite(app) & (app >= 0))][0]
                raise InvalidParameterError(f"appearance: values must be finite and >= 0, got {float(bad)!r}")
            app.setflags(write=False)
            object.__setattr__(self, "appearance", app)
        if self.source is not None and not isinstance(self.source, str):
            raise InvalidParameterError(f"source: must be a string or None, got {self.source!r}")
        if self.profile is not None:
            try:
                prof = np.array(self.profile, dtype=np.float64, copy=True)
            except (TypeError, ValueError) as err:
                raise InvalidParameterError("profile: must be a 2-D array of numbers (columns, channels)") from err
            if prof.ndim != 2 or prof.shape[0] < 4 or prof.shape[1] < 1:
                raise InvalidParameterError(
                    f"profile: must be a 2-D array with at least 4 columns and 1 channel, got shape {prof.shape}"
                )
            if not np.all(np.isfinite(prof)):
                raise InvalidParameterError("profile: values must be finite")
            prof.setflags(write=False)
            object.__setattr__(self, "profile", prof)
        if self.keypoints is not None:
            from .keypoints import Keypoints

            if not isinstance(self.keypoints, Keypoints):
                raise InvalidParameterError(
                    f"keypoints: must be a fingerloc.keypoints.Keypoints or None, got {type(self.keypoints).__name__}"
                )

    def _init_walls_and_ranges(self) -> None:
        w = wrap(_readonly(self.w, "w"))
        length = _readonly(self.w_length, "w_length")
        rng = _readonly(self.w_range, "w_range")
        if not (w.shape == length.shape == rng.shape):
            raise InvalidParameterError(
                f"w_length, w_range: one length and one range per wall segment are needed, got "
                f"{length.size} and {rng.size} for {w.size} segments"
            )
        if np.any(length <= 0) or np.any(rng <= 0):
            raise InvalidParameterError("w_length, w_range: wall lengths and ranges must be > 0 metres")
        order = np.argsort(w, kind="stable")
        for name, arr in (("w", w[order]), ("w_length", length[order]), ("w_range", rng[order])):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if (self.ranges is None) != (self.range_bearings is None):
            raise InvalidParameterError("ranges and range_bearings must be given together")
        if self.ranges is not None and self.range_bearings is not None:
            r = np.array(self.ranges, dtype=np.float64).reshape(-1)
            rb = np.array(self.range_bearings, dtype=np.float64).reshape(-1)
            if r.shape != rb.shape:
                raise InvalidParameterError(
                    f"range_bearings: one bearing per range is needed, got {rb.size} for {r.size} ranges"
                )
            r = np.where(np.isnan(r), np.inf, r)
            if np.any(r < 0) or not np.all(np.isfinite(rb)):
                raise InvalidParameterError("ranges must be >= 0 (inf for no return) with finite bearings")
            r.setflags(write=False)
            rb.setflags(write=False)
            object.__setattr__(self, "ranges", r)
            object.__setattr__(self, "range_bearings", rb)

    @classmethod
    def _checked(
        cls,
        bearings: dict[str, FArray],
        *,
        fov: tuple[tuple[float, float], ...],
        label: str | None,
        pose: tuple[float, float, float] | None,
        timestamp: float | None,
        source: str | None,
    ) -> Observation:
        """An observation from values already checked, without :meth:`__post_init__` (the JSON Lines fast path).

        ``bearings`` maps ``ve``, ``ex``, ``c``, ``b`` to radians already
        wrapped, sorted and read-only (a missing one is empty); ``fov`` is in
        its final form (``__post_init__``'s), ``pose`` three finite floats
        (radians), ``timestamp`` a finite float. The caller guarantees what
        ``__post_init__`` would check: :func:`fingerloc.io.jsonl.observation_from_record`
        builds the same observation through the validating path whenever its
        fast path has any doubt (``tests/test_io_jsonl.py`` compares the two).
        """
        obs = object.__new__(cls)
        put = object.__setattr__
        for name in ("ve", "cp", "cp_hue", "ex", "c", "b", "w", "w_length", "w_range"):
            put(obs, name, bearings.get(name, _EMPTY))
        put(obs, "ranges", None)
        put(obs, "range_bearings", None)
        put(obs, "fov", fov)
        put(obs, "label", label)
        put(obs, "pose", pose)
        put(obs, "timestamp", timestamp)
        put(obs, "appearance", None)
        put(obs, "source", source)
        put(obs, "profile", None)
        put(obs, "keypoints", None)
        return obs

    # -- convenience -----------------------------------------------------
    @classmethod
    def from_degrees(
        cls,
        features: Mapping[str, Any] | None = None,
        *,
        fov: Sequence[Sequence[float]] | None = None,
        label: str | None = None,
        pose: Sequence[float] | None = None,
        timestamp: float | None = None,
        appearance: ArrayLike | None = None,
        source: str | None = None,
        profile: ArrayLike | None = None,
    ) -> Observation:
        """Build an observation from bearings in degrees.

        Parameters
        ----------
        features : mapping
            Keys among :data:`FEATURE_TYPES`. ``VE``, ``Ex``, ``c``, ``B``:
            sequences of bearings in degrees. ``CP``: a sequence of
            ``(bearing_deg, hue_deg)`` pairs or ``{"bearing": .., "hue": ..}``.
            ``W``: ``(bearing_deg, length_m, range_m)`` triples or
            ``{"bearing": .., "length": .., "range": ..}``.
        fov : list of [start, end] in degrees, optional
            Counter-clockwise ranges; ``None`` for the full circle.
        pose : (x, y, theta_deg), optional
            Metres and degrees.
        appearance, source, profile : optional
            As in :class:`Observation`.
        """
        features = dict(features or {})
        unknown = sorted(set(features) - set(FEATURE_TYPES))
        if unknown:
            raise InvalidParameterError(
                f"unknown feature type {unknown[0]!r} (expected one of {', '.join(FEATURE_TYPES)})"
            )
        w_b, w_l, w_r = _records(features.get("W", []), "W", ("bearing", "length", "range"))
        cp_b, cp_h = _records(features.get("CP", []), "CP", ("bearing", "hue"))
        p3 = None
        if pose is not None:
            if len(pose) != 3:
                raise InvalidParameterError(f"pose: must be [x, y, theta_deg], got {list(pose)!r}")
            p3 = (float(pose[0]), float(pose[1]), float(deg_to_rad(pose[2])))
        return cls(
            ve=deg_to_rad(_numbers(features.get("VE", []), "VE")),
            cp=deg_to_rad(cp_b),
            cp_hue=cp_h,
            ex=deg_to_rad(_numbers(features.get("Ex", []), "Ex")),
            c=deg_to_rad(_numbers(features.get("c", []), "c")),
            b=deg_to_rad(_numbers(features.get("B", []), "B")),
            w=deg_to_rad(w_b),
            w_length=w_l,
            w_range=w_r,
            fov=fov_from_degrees(fov),
            label=label,
            pose=p3,
            timestamp=timestamp,
            appearance=appearance,  # type: ignore[arg-type]  # validated and converted in __post_init__
            source=source,
            profile=profile,  # type: ignore[arg-type]  # validated and converted in __post_init__
        )

    def bearings(self, kind: str) -> FArray:
        """Bearings (radians, shape ``(n,)``) of one feature type of :data:`FEATURE_TYPES`."""
        try:
            attr = _ATTR[kind]
        except KeyError:
            raise InvalidParameterError(
                f"unknown feature type {kind!r} (expected one of {', '.join(FEATURE_TYPES)})"
            ) from None
        arr: FArray = getattr(self, attr)
        return arr

    def counts(self) -> dict[str, int]:
        """Number of features of each type."""
        return {k: int(self.bearings(k).size) for k in FEATURE_TYPES}

    @property
    def full_fov(self) -> bool:
        """True when the field of view covers the whole circle."""
        return any(w >= TWO_PI - 1e-12 for _, w in self.fov)

    def fov_coverage(self) -> float:
        """Covered part of the circle, in ``[0, 1]`` (overlapping ranges counted once)."""
        from .angles import fov_pieces_deg

        return float(sum(hi - lo for lo, hi in fov_pieces_deg(self.fov)) / 360.0)

    def rotated(self, angle: float) -> Observation:
        """The same view seen by a robot turned by ``-angle``: every bearing and the fov move by ``angle`` radians.

        The profile's rows roll by the nearest whole number of rows; the keypoints' bearings turn.
        """
        prof = self.profile
        if prof is not None:
            prof = np.roll(prof, round(float(angle) / TWO_PI * prof.shape[0]), axis=0)
        kps = self.keypoints
        if kps is not None:
            kps = replace(kps, bearing=wrap(kps.bearing + angle))
        return Observation(
            ve=self.ve + angle,
            cp=self.cp + angle,
            cp_hue=self.cp_hue,
            ex=self.ex + angle,
            c=self.c + angle,
            b=self.b + angle,
            w=self.w + angle,
            w_length=self.w_length,
            w_range=self.w_range,
            ranges=self.ranges,
            range_bearings=None if self.range_bearings is None else self.range_bearings + angle,
            fov=tuple((s + angle, w) for s, w in self.fov),
            label=self.label,
            pose=self.pose,
            timestamp=self.timestamp,
            appearance=self.appearance,
            source=self.source,
            profile=prof,
            keypoints=kps,
        )

    def with_label(self, label: str | None) -> Observation:
        """A copy with another place label (the checked arrays shared, read-only as they are)."""
        _check_label(label)
        obs = object.__new__(type(self))
        for name in self.__slots__:
            object.__setattr__(obs, name, getattr(self, name))
        object.__setattr__(obs, "label", label)
        return obs

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Observation):
            return NotImplemented
        return (
            all(np.array_equal(getattr(self, n), getattr(other, n)) for n in _ARRAYS)
            and _same_optional(self.ranges, other.ranges)
            and _same_optional(self.range_bearings, other.range_bearings)
            and self.fov == other.fov
            and self.label == other.label
            and self.pose == other.pose
            and self.timestamp == other.timestamp
            and _same_optional(self.appearance, other.appearance)
            and self.source == other.source
            and _same_optional(self.profile, other.profile)
            and self.keypoints == other.keypoints
        )

    __hash__ = None  # type: ignore[assignment]


#: The empty bearing array every :meth:`Observation._checked` observation shares (read-only).
_EMPTY: FArray = np.empty(0)
_EMPTY.setflags(write=False)

_ATTR = {"VE": "ve", "CP": "cp", "Ex": "ex", "c": "c", "B": "b", "W": "w"}
_ARRAYS = ("ve", "cp", "cp_hue", "ex", "c", "b", "w", "w_length", "w_range")


def _same_optional(a: FArray | None, b: FArray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.array_equal(a, b))


def _numbers(values: Any, kind: str) -> FArray:
    """A feature type's values (degrees or metres) as a 1-D float array; one-line error naming the type otherwise."""
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InvalidParameterError(f"features[{kind!r}] must be a list of numbers, got {values!r}") from None
    if a.ndim != 1:
        raise InvalidParameterError(f"features[{kind!r}] must be a flat list of numbers, got {values!r}")
    return a


def _records(items: Any, kind: str, keys: tuple[str, ...]) -> tuple[FArray, ...]:
    """``CP`` / ``W`` entries, each a mapping with ``keys`` or a sequence in that order, as one array per key."""
    cols: list[list[Any]] = [[] for _ in keys]
    if isinstance(items, str | bytes | Mapping):
        raise InvalidParameterError(f"features[{kind!r}] must be a list of {{{', '.join(keys)}}} entries, got {items!r}")
    for item in items:
        if isinstance(item, Mapping):
            missing = [k for k in keys if k not in item]
            if missing:
                raise InvalidParameterError(f"features[{kind!r}]: an entry lacks {missing[0]!r}: {item!r}")
            vals = [item[k] for k in keys]
        elif isinstance(item, Sequence) and not isinstance(item, str | bytes) and len(item) == len(keys):
            vals = list(item)
        else:
            raise InvalidParameterError(
                f"features[{kind!r}]: each entry must be {{{', '.join(keys)}}} or a list of {len(keys)} numbers, got {item!r}"
            )
        for col, v in zip(cols, vals, strict=True):
            col.append(v)
    return tuple(_numbers(col, kind) for col in cols)
