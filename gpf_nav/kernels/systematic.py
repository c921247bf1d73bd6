"""Systematic resampling."""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def systematic_ancestors(weights: np.ndarray, uniform: float) -> np.ndarray:
    """Ancestors ``(N,)`` of systematic resampling of the normalised ``weights`` ``(N,)`` with the one
    uniform draw ``uniform`` in [0, 1): particle ``i`` gets ``ceil(N c_i - U) - ceil(N c_{i-1} - U)``
    copies (``c`` the cumulative weights, clipped to [0, N], the last forced to 1)."""
    n = weights.size
    cdf = np.cumsum(weights)
    total = cdf[n - 1]
    ancestors = np.empty(n, np.intp)
    filled = 0
    for i in range(n):
        c = 1.0 if i == n - 1 else cdf[i] / total
        edge = min(max(math.ceil(n * c - uniform), 0.0), float(n))
        while filled < edge:
            ancestors[filled] = i
            filled += 1
    for i in range(filled, n):  # a uniform within rounding of 1 leaves the last point past N - 1
        ancestors[i] = n - 1
    return ancestors
