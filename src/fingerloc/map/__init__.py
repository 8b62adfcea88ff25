"""The map: the place database (SQLite), the place graph and the Markov filter over it."""

from .database import SCHEMA_VERSION, load_model, save_model

__all__ = ["SCHEMA_VERSION", "load_model", "save_model"]
