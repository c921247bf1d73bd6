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
    for i in range(r.shape[0]):
        for c in columns:
            wrap = wrap or np.ceil((r[i, c] - math.pi) * INVERSE_TWO_PI) != 0.0
    if not wrap:
        return
    for i in range(r.shape[0]):
        for c in columns:
            r[i, c] -= TWO_PI * np.ceil((r[i, c] - math.pi) * INVERSE_TWO_PI)
