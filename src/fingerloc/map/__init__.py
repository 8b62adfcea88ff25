"""The map: the place database (SQLite), the place graph and the Markov filter over it."""

from .database import SCHEMA_VERSION, load_model, save_model
from .filter import MarkovFilter, TransitionModel, run_filter
from .graph import PlaceGraph, load_graph

__all__ = [
    "SCHEMA_VERSION",
    "MarkovFilter",
    "PlaceGraph",
    "TransitionModel",
    "load_graph",
    "load_model",
    "run_filter",
    "save_model",
]
