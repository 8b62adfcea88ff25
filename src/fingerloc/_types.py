"""Array type aliases shared by the package: float64 and int64 numpy arrays (shapes and units in each docstring)."""

import numpy as np
from numpy.typing import NDArray

__all__ = ["FArray", "IArray"]

FArray = NDArray[np.float64]
IArray = NDArray[np.int64]
