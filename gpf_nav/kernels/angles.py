"""Residuals' angle wrapping (:func:`gpf_nav.models.state_space.wrapped_residual`) in one pass, in place."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

TWO_PI = 2.0 * math.pi
INVERSE_TWO_PI = 1.0 / TWO_PI


@njit(cache=True, error_model="numpy")
def wrap_columns(r: np.ndarray, columns: np.ndarray) -> None:
    """Wrap the ``columns`` ``(k,)`` of the residuals ``r`` ``(K, m)`` to (-pi, pi] in place: ``r - 2 pi t``,
    ``t = ceil((r - pi) / (2 pi))``, every one of them when any ``t`` is not zero (the numpy code's
    arithmetic, signed zeros included), none otherwise."""
    wrap = False
    for c in columns:  # (column by column, without a short-circuit: the loops vectorise)
        column = r[:, c]
        for i in range(column.size):
            wrap |= np.ceil((column[i] - math.pi) * INVERSE_TWO_PI) != 0.0
    if not wrap:
        return
    for c in columns:
        column = r[:, c]
        for i in range(column.size):
            column[i] -= TWO_PI * np.ceil((column[i] - math.pi) * INVERSE_TWO_PI)
