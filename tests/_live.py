"""A stand-in for the streaming tracker (``step(item, odometry=, stamp=) -> answer``), for the node and stream tests.

Its answer is a pure function of what it was given, so that two runs over the
same steps (one live, one offline) must agree answer for answer: the place is
the count of beams with a return modulo five, the pose is the odometry pose
turned and moved into a "map" frame, the covariance grows with the step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

MAP_FROM_ODOM = (2.0, -1.0, 0.3)


@dataclass(frozen=True)
class StandInAnswer:
    step: int
    stamp: float | None
    name: str
    place: str
    probability: float
    pose: tuple[float, float, float] | None
    covariance: tuple[tuple[float, ...], ...] | None
    returns: int
    observed: bool = True

    def to_json(self):
        return {
            "step": self.step,
            "stamp": self.stamp,
            "name": self.name,
            "best": self.place,
            "probability": self.probability,
            "pose": None if self.pose is None else list(self.pose),
            "covariance": None if self.covariance is None else [list(r) for r in self.covariance],
            "returns": self.returns,
        }


@dataclass
class StandInTracker:
    steps: list = field(default_factory=list)

    def step(self, item=None, odometry=None, stamp=None):
        k = len(self.steps)
        returns = int(np.isfinite(item.ranges).sum()) if item is not None and hasattr(item, "ranges") else -1
        pose = None
        if odometry is not None:
            x, y, th = odometry
            mx, my, mth = MAP_FROM_ODOM
            c, s = math.cos(mth), math.sin(mth)
            pose = (mx + c * x - s * y, my + s * x + c * y, math.remainder(th + mth, 2 * math.pi))
        cov = ((0.01 * (k + 1), 0.002, 0.0), (0.002, 0.02 * (k + 1), 0.001), (0.0, 0.001, 0.003))
        ans = StandInAnswer(k, stamp, f"step{k}", f"p{returns % 5}", 1.0 / (1 + k), pose, cov, returns)
        self.steps.append(ans)
        return ans
