"""Feature extraction from raw sensor data (docs/METHOD.md §1): laser scans and panoramic images.

- :mod:`fingerloc.features.laser`: corners ``c``, extremities ``Ex`` and
  beacons ``B`` of a :class:`~fingerloc.sensors.Scan`.
- :mod:`fingerloc.features.vision`: vertical edges ``VE`` and colour patches
  ``CP`` of a :class:`~fingerloc.sensors.Panorama`, and the unwarping of an
  omnidirectional image; :mod:`fingerloc.features.appearance`: the
  appearance descriptor (``A``) and the column profile (``AP``).
- :mod:`fingerloc.features.keypoints`: OpenCV SIFT keypoints on the sphere
  (``K``); :mod:`fingerloc.features.sphere`: two-view geometry on bearing
  vectors (relative pose by RANSAC, headings).
"""

from __future__ import annotations

from .laser import LaserFeatures, LaserParams, extract_laser_features, observation_from_scan
from .vision import (
    EdgeParams,
    PatchParams,
    VisionFeatures,
    colour_patches,
    extract_vision_features,
    observation_from_views,
    unwarp_omni,
    vertical_edges,
)

__all__ = [
    "EdgeParams",
    "LaserFeatures",
    "LaserParams",
    "PatchParams",
    "VisionFeatures",
    "colour_patches",
    "extract_laser_features",
    "extract_vision_features",
    "observation_from_scan",
    "observation_from_views",
    "unwarp_omni",
    "vertical_edges",
]
