"""What one measurement saw, as plain data, and its thumbnail (a small PNG drawn with Pillow, fast enough for thousands).

A :class:`FeatureView` holds the bearings of each feature type, the colour
patches' hues, the fingerprint string with its letters' bearings and the field
of view. :func:`draw_view_thumbnail` draws it around the robot: one ring per
feature type, a tick at each bearing, bearing 0 (straight ahead) pointing up,
bearings growing counter-clockwise; the unseen part of the circle is shaded.
"""

from __future__ import annotations

import colorsys
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from .._types import FArray
from ..errors import InvalidParameterError

if TYPE_CHECKING:
    from ..observation import Observation

__all__ = ["FEATURE_STYLE", "FeatureView", "draw_view_thumbnail"]


#: Feature type -> (ring radius as a fraction of the thumbnail's, RGB colour, description).
FEATURE_STYLE: dict[str, tuple[float, tuple[int, int, int], str]] = {
    "VE": (0.92, (31, 119, 180), "vertical edges (blue)"),
    "CP": (0.80, (0, 0, 0), "colour patches (their hue)"),
    "c": (0.68, (214, 39, 40), "corners (red)"),
    "Ex": (0.56, (148, 103, 189), "extremities (purple)"),
    "B": (0.44, (255, 127, 14), "beacons (orange)"),
}


def _ro(a: ArrayLike) -> FArray:
    x = np.array(a, dtype=np.float64, copy=True).reshape(-1)
    x.setflags(write=False)
    return x


@dataclass(frozen=True)
class FeatureView:
    """The features of one measurement, for drawing.

    Parameters
    ----------
    bearings : mapping of str to array_like, shape (n_t,)
        Feature type (``VE``, ``CP``, ``c``, ``Ex``, ``B``) -> bearings in radians, robot frame.
    hues_deg : array_like, shape (n_CP,)
        Hue of each colour patch in degrees (same order as ``bearings["CP"]``).
    fingerprint : str
        The fingerprint string (docs/METHOD.md §2).
    fov : sequence of (start, width)
        Seen bearing ranges in radians (default: the full circle).
    """

    bearings: Mapping[str, FArray]
    hues_deg: FArray = field(default_factory=lambda: _ro([]))
    fingerprint: str = ""
    fov: tuple[tuple[float, float], ...] = ((-math.pi, 2 * math.pi),)

    def __post_init__(self) -> None:
        b = {str(k): _ro(v) for k, v in self.bearings.items()}
        for k, v in b.items():
            if not np.all(np.isfinite(v)):
                raise InvalidParameterError(f"bearings[{k!r}]: must be finite radians")
        hues = _ro(self.hues_deg)
        if "CP" in b and hues.size and hues.size != b["CP"].size:
            raise InvalidParameterError(f"hues_deg: one hue per colour patch, got {hues.size} for {b['CP'].size}")
        object.__setattr__(self, "bearings", b)
        object.__setattr__(self, "hues_deg", hues)
        object.__setattr__(self, "fov", tuple((float(s), float(w)) for s, w in self.fov))

    @classmethod
    def from_observation(cls, obs: Observation, *, laser_letters: bool = False) -> FeatureView:
        """The view of an :class:`~fingerloc.observation.Observation`, with its fingerprint."""
        from ..fingerprint import make_fingerprint

        kinds = {"VE": obs.ve, "CP": obs.cp, "c": obs.c, "Ex": obs.ex, "B": obs.b}
        fp = make_fingerprint(obs, laser_letters=laser_letters).letters
        return cls({k: v for k, v in kinds.items() if v.size}, obs.cp_hue, fp, obs.fov)

    def counts(self) -> dict[str, int]:
        """Number of features per type."""
        return {k: int(v.size) for k, v in self.bearings.items()}


def _hue_rgb(hue_deg: float) -> tuple[int, int, int]:
    r, g, b = colorsys.hsv_to_rgb((hue_deg % 360.0) / 360.0, 0.85, 0.9)
    return (int(255 * r), int(255 * g), int(255 * b))


def draw_view_thumbnail(view: FeatureView, path: str | Path, *, size: int = 120) -> Path:
    """Draw a view's features around the robot into a small PNG; return the path.

    Parameters
    ----------
    view : FeatureView
    path : str or Path
        Output PNG.
    size : int, default 120
        Width and height in pixels.
    """
    from PIL import Image, ImageDraw

    if size < 32:
        raise InvalidParameterError(f"size must be >= 32 pixels, got {size}")
    scale = 2  # drawn at twice the size, then reduced: smooth lines without a vector library
    s = size * scale
    img = Image.new("RGB", (s, s), (255, 255, 255))
    d = ImageDraw.Draw(img)
    c = s / 2.0
    r_max = 0.48 * s
    box = [c - r_max, c - r_max, c + r_max, c + r_max]
    # bearing 0 points up, bearings grow counter-clockwise: screen angle (PIL, clockwise from +x) = -90 - deg
    d.ellipse(box, fill=(235, 235, 235))
    for start, width in view.fov:  # the seen part, white
        a0 = math.degrees(start)
        a1 = a0 + math.degrees(width)
        if width >= 2 * math.pi - 1e-9:
            d.ellipse(box, fill=(255, 255, 255))
        else:
            d.pieslice(box, -90 - a1, -90 - a0, fill=(255, 255, 255))
    d.ellipse(box, outline=(170, 170, 170), width=scale)

    def point(bearing: float, frac: float) -> tuple[float, float]:
        return (c - frac * r_max * math.sin(bearing), c - frac * r_max * math.cos(bearing))

    for kind, (ring, colour, _) in FEATURE_STYLE.items():
        arr = view.bearings.get(kind)
        if arr is None or not arr.size:
            continue
        d.ellipse(
            [c - ring * r_max, c - ring * r_max, c + ring * r_max, c + ring * r_max], outline=(225, 225, 225), width=1
        )
        for k, a in enumerate(arr):
            col = _hue_rgb(float(view.hues_deg[k])) if kind == "CP" and k < view.hues_deg.size else colour
            d.line([point(float(a), ring - 0.11), point(float(a), ring + 0.05)], fill=col, width=3 * scale)
    # the robot, pointing along bearing 0 (up)
    t = 0.12 * r_max
    d.polygon([(c, c - 1.4 * t), (c - t, c + t), (c + t, c + t)], fill=(40, 40, 40))
    # box-reduced (smooth enough, and fast), then a 64-colour palette: a thousand thumbnails in seconds, ~2 kB each
    small = img.reduce(scale).quantize(64, method=Image.Quantize.FASTOCTREE)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    small.save(p, format="PNG", compress_level=6)
    return p


def legend_text() -> str:
    """One line telling what the thumbnails' rings are."""
    rings = ", ".join(desc for _, _, desc in FEATURE_STYLE.values())
    return (
        f"Thumbnails: the robot at the centre facing up (bearing 0), bearings counter-clockwise; rings from the "
        f"outside in: {rings}; the shaded part of the circle was not seen."
    )


def stack_bearings(views: Sequence[FeatureView], kind: str) -> FArray:
    """All bearings of one feature type over several views (radians), shape (n,)."""
    parts = [v.bearings[kind] for v in views if kind in v.bearings]
    return np.concatenate(parts) if parts else np.empty(0)
