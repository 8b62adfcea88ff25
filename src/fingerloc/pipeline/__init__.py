"""The library layer: what the command line and the experiments both call (docs/FORMATS.md).

* :mod:`.presets`: named place-model configurations per sensor (``paper``,
  ``laser2d``, ``panorama``, ``multimodal``, ``auto``);
* :mod:`.places`: places and labelled scans from a trajectory's poses;
* :mod:`.readers`: raw runs (CARMEN logs, ROS bags, JSON Lines) -> scans / observations;
* :mod:`.files`: sensor files of ``fingerloc features`` (images, logs, bags) -> observations;
* :mod:`.tracker`: the filters' calibration on a mapping part, and the calibrated tracker;
* :mod:`.mapping`: a place map from a run (places, model, graph, calibration), saved and loaded.

Import the submodules; this package imports only the presets.
"""

from .presets import PRESET_NAMES, PRESETS, ResolvedPreset, choose_preset, model_options, resolve_preset

__all__ = ["PRESETS", "PRESET_NAMES", "ResolvedPreset", "choose_preset", "model_options", "resolve_preset"]
