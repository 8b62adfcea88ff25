"""The map: the place database (SQLite), the place graph, the Markov filter over it and the pose filter."""

from .database import SCHEMA_VERSION, load_model, save_model
from .filter import MarkovFilter, TransitionModel, run_filter
from .graph import PlaceGraph, load_graph
from .pose_filter import PoseFilter, run_pose_filter

__all__ = [
    "SCHEMA_VERSION",
    "MarkovFilter",
    "PlaceGraph",
    "PoseFilter",
    "TransitionModel",
    "load_graph",
    "load_model",
    "run_filter",
    "run_pose_filter",
    "save_model",
]
