"""Feature extraction from raw sensor data (SPEC.md §1): laser scans and panoramic images."""

from __future__ import annotations

from .laser import LaserFeatures, LaserParams, extract_laser_features, observation_from_scan

__all__ = [
    "LaserFeatures",
    "LaserParams",
    "extract_laser_features",
    "observation_from_scan",
]
