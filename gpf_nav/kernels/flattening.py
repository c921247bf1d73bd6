"""The flattened update's tests of size (:mod:`gpf_nav.filters.flattening`): the largest departure from
the linearisation, or change of it, in noise standard deviations, in one pass without temporaries."""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def largest_scaled(nu: np.ndarray, previous: np.ndarray, scale: np.ndarray) -> float:
    """``max |(nu - previous) / scale|`` over ``nu`` ``(N, K)`` (``previous`` ``(N, K)``, or ``(0, 0)``:
    none) with ``scale`` ``(K,)``, each term the numpy code's; NaN when any term is NaN (numpy's
    ``max``). A running maximum per column, so the loop vectorises (the divisions bound it)."""
    largest = np.zeros(nu.shape[1])
    change = previous.size > 0
    nan = False
    for j in range(nu.shape[0]):
        for k in range(nu.shape[1]):
            value = abs(((nu[j, k] - previous[j, k]) if change else nu[j, k]) / scale[k])
            largest[k] = value if value > largest[k] else largest[k]
            nan |= value != value
    return math.nan if nan else largest.max()
