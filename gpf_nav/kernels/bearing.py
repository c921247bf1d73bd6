"""The Jacobian of range, azimuth and elevation seen from a station (the lunar model's measurement).

Built from the line of sight (:func:`gpf_nav.kernels.orbit.line_of_sight`) with the numpy code's
operations, one particle at a time: no transcendental function, so the result is the numpy one bit for
bit. One pass writes every entry, the zero ones included, instead of zeroing the ``(3, 6, N)`` array first
and filling it row by row.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def range_bearing_jacobian(d: np.ndarray, horizontal: np.ndarray, rho: np.ndarray, min_horizontal: float,
                           min_range: float) -> np.ndarray:
    """``(3, 6, N)``: ``d(range, azimuth, elevation) / d(r, v)`` for the lines of sight ``d`` ``(3, N)``,
    their horizontal lengths and ranges ``(N,)``; the horizontal length floored at ``min_horizontal``
    and the range at ``min_range`` (NaN kept, as ``np.maximum`` keeps it). The velocity columns are
    zero."""
    count = rho.size
    jac = np.empty((3, 6, count))
    for j in range(count):
        d0, d1, d2, h, length = d[0, j], d[1, j], d[2, j], horizontal[j], rho[j]
        hor = min_horizontal if h < min_horizontal else h
        inv_rho = 1.0 / (min_range if length < min_range else length)
        inv_rho2 = inv_rho * inv_rho
        inv_h2 = 1.0 / (hor * hor)
        k = d2 * inv_rho2 / -hor
        jac[0, 0, j], jac[0, 1, j], jac[0, 2, j] = d0 * inv_rho, d1 * inv_rho, d2 * inv_rho
        jac[1, 0, j], jac[1, 1, j], jac[1, 2, j] = -(d1 * inv_h2), d0 * inv_h2, 0.0
        jac[2, 0, j], jac[2, 1, j], jac[2, 2, j] = k * d0, k * d1, hor * inv_rho2
        for a in range(3):
            jac[a, 3, j] = jac[a, 4, j] = jac[a, 5, j] = 0.0
    return jac
