"""The library layer: what the command line and the experiments both call (docs/FORMATS.md).

* :mod:`.presets`: named place-model configurations per sensor (``paper``,
  ``laser2d``, ``panorama``, ``multimodal``, ``auto``);
* :mod:`.places`: places and labelled scans from a trajectory's poses;
* :mod:`.readers`: raw runs (CARMEN logs, ROS bags, JSON Lines) -> scans / observations;
* :mod:`.files`: sensor files of ``fingerloc features`` (images, logs, bags) -> observations;
* :mod:`.calibration`, :mod:`.calibrate`: what the filters learn on a mapping part, and the one
  sequence that learns it;
* :mod:`.filters`: the filters built from a calibration and a :class:`~fingerloc.config.Config`;
* :mod:`.tracker`: the streaming tracker (one step per scan or observation);
* :mod:`.localize`: single-shot answers in chunks;
* :mod:`.placemap`: :class:`~fingerloc.pipeline.placemap.PlaceMap`, the front door
  (save, load, localize, track, tracker);
* :mod:`.mapping`: a place map from a run (places, model, graph, calibration).

Import the submodules; this package imports only the presets.
"""

from .presets import PRESET_NAMES, PRESETS, ResolvedPreset, choose_preset, model_options, resolve_preset

__all__ = ["PRESETS", "PRESET_NAMES", "ResolvedPreset", "choose_preset", "model_options", "resolve_preset"]
