"""Readers and writers: JSON Lines observations, CARMEN logs, ROS bags."""

from .jsonl import (
    iter_observations,
    observation_from_record,
    observation_to_record,
    read_observations,
    write_observations,
)

__all__ = [
    "iter_observations",
    "observation_from_record",
    "observation_to_record",
    "read_observations",
    "write_observations",
]
