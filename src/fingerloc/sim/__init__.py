"""``fingerloc.sim``: simulated offices and the raw sensors that see them.

- :func:`make_offices` draws offices that resemble each other by a chosen amount;
  each is an immutable :class:`World` (wall segments with materials, decals,
  furniture, pillars, doors, beacons, sun patches).
- :func:`simulate_scan`: a 360 deg laser of two 180 deg heads, with intensities.
- :func:`render_panorama` and :func:`render_omni`: the camera, as a cylindrical
  panorama or as the raw donut image of an equiangular mirror (:class:`OmniImage`).
- :func:`true_features` / :func:`true_observation`: ground truth bearings for
  evaluation only; feature extractors never see it.
- :func:`make_office_sessions`: the same offices at a training and at a later
  test visit, changed as a :class:`SessionChange` says (chairs moved, doors
  closed, people in the room, other daylight; :data:`OFFICE_DAY`).
- :class:`PerceptionNoise` and :func:`perceive`: what a real robot's extractors
  get wrong beyond the rendered sensors (missed, moved and spurious features);
  :data:`PAPER_ROBOT`, calibrated on the paper's Table III with the later
  visit's heading (:data:`PAPER_VISIT`).
- :func:`protocol_poses`: the paper's measurement poses (8 on a 40-70 cm
  circle around the office's anchor, 2 inside it).

Conventions: metres and radians; a pose is ``(x, y, theta)`` in the world
frame; bearings are relative to the heading, counter-clockwise. Panoramas use
``clockwise=True, bearing_offset=pi`` (heading at the centre column); an
:class:`OmniImage` says how its pixels map to bearing and elevation.

The simulator does not depend on :mod:`fingerloc.features`.
"""

from __future__ import annotations

from .camera import CAMERA_HEIGHT, ELEVATION_DEG, OmniImage, render_omni, render_panorama
from .laser import LASER_HEIGHT, simulate_scan
from .offices import WORLDS, make_office, make_offices
from .perception import PAPER_ROBOT, PerceptionNoise, perceive
from .poses import protocol_poses
from .sessions import OFFICE_DAY, PAPER_VISIT, SessionChange, make_office_sessions
from .truth import true_features, true_observation
from .world import PARTS, Material, World, cast_rays

__all__ = [
    "CAMERA_HEIGHT",
    "ELEVATION_DEG",
    "LASER_HEIGHT",
    "OFFICE_DAY",
    "PAPER_ROBOT",
    "PAPER_VISIT",
    "PARTS",
    "WORLDS",
    "Material",
    "OmniImage",
    "PerceptionNoise",
    "SessionChange",
    "World",
    "cast_rays",
    "make_office",
    "make_office_sessions",
    "make_offices",
    "perceive",
    "protocol_poses",
    "render_omni",
    "render_panorama",
    "simulate_scan",
    "true_features",
    "true_observation",
]
