"""The screen of :func:`gpf_nav.linalg.positive_definite`: a published covariance's symmetric part, its
variances floored, and whether its correlation matrix is certainly above the eigenvalue floor, so the
eigen-decomposition runs only where it may change something.

Every filter passes its covariance through that function at each read (the default GPF 3 times a
step); on 6 to 9 rows numpy's eigh and the dozen calls around it cost about 30 us, the screen 1."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

NOT_FINITE, ABOVE, UNSURE = 0, 1, 2
"""Outcomes of :func:`screen`."""


@njit(cache=True, error_model="numpy")
def screen(cov: np.ndarray, floor_absolute: float, margin: float):
    """``(outcome, sym)``: ``sym`` the symmetric part ``(cov + cov^T) / 2`` of ``cov`` ``(n, n)`` with its
    variances raised to at least ``floor_absolute``; :data:`NOT_FINITE` (``sym`` not floored) when an
    entry is not finite, :data:`ABOVE` when the correlation matrix ``C`` of ``sym`` minus
    ``margin * trace(C)`` times the identity has a Cholesky factor (then every eigenvalue of ``C`` is above
    ``margin`` times its largest, less rounding), else :data:`UNSURE`."""
    n = cov.shape[0]
    sym = np.empty((n, n))
    finite = True
    for i in range(n):
        for j in range(n):
            v = 0.5 * (cov[i, j] + cov[j, i])
            sym[i, j] = v
            finite = finite and math.isfinite(v)
    if not finite:
        return NOT_FINITE, sym
    scale = np.empty(n)
    for i in range(n):
        if sym[i, i] < floor_absolute:
            sym[i, i] = floor_absolute
        scale[i] = math.sqrt(sym[i, i])
    corr = np.empty((n, n))
    trace = 0.0
    for i in range(n):
        for j in range(n):
            corr[i, j] = sym[i, j] / (scale[i] * scale[j])
        trace += corr[i, i]
    shift = margin * max(1.0, trace)
    for i in range(n):
        corr[i, i] -= shift
    for j in range(n):  # Cholesky in place (lower triangle)
        d = corr[j, j]
        for k in range(j):
            d -= corr[j, k] * corr[j, k]
        if not d > 0.0:
            return UNSURE, sym
        d = math.sqrt(d)
        corr[j, j] = d
        for i in range(j + 1, n):
            t = corr[i, j]
            for k in range(j):
                t -= corr[i, k] * corr[j, k]
            corr[i, j] = t / d
    return ABOVE, sym
