"""The library layer: what the command line and the experiments both call (DESIGN.md).

* :mod:`.presets`: named place-model configurations per sensor;
* :mod:`.places`: places and labelled scans from a trajectory's poses;
* :mod:`.readers`: raw files (CARMEN logs, ROS bags, JSON Lines) -> observations;
* :mod:`.tracker`: the filters' calibration on a mapping run, and the tracker.
"""

from .presets import PRESET_NAMES, PRESETS, ResolvedPreset, choose_preset, model_options, resolve_preset

__all__ = ["PRESETS", "PRESET_NAMES", "ResolvedPreset", "choose_preset", "model_options", "resolve_preset"]
