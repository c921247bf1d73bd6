"""The gravity field's spherical harmonics (:mod:`gpf_nav.models.gravity`): Cunningham's recursion of the
unnormalised solid harmonics ``V_nm``, ``W_nm`` and the acceleration they give, per particle.

Montenbruck and Gill, *Satellite Orbits* (2000), Section 3.2.5: with ``x0 = x R / r^2`` (and ``y0``,
``z0``) and ``rho = R^2 / r^2``, ``V_00 = R / r``, the sectorial terms
``V_mm = (2m - 1)(x0 V_{m-1,m-1} - y0 W_{m-1,m-1})``, ``W_mm = (2m - 1)(x0 W_{m-1,m-1} + y0 V_{m-1,m-1})``,
and down each order ``V_nm = ((2n - 1) z0 V_{n-1,m} - (n + m - 1) rho V_{n-2,m}) / (n - m)`` (``W`` alike).
Positions are Moon-fixed, particle-last ``(3, N)``; no pole singularity.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def acceleration(r, C, S, radius, gm, out):
    """Write into ``out`` ``(3, N)`` the acceleration of the terms of degree 2 to ``n`` of the unnormalised
    coefficients ``C``, ``S`` ``(n + 1, n + 1)`` at the Moon-fixed positions ``r`` ``(3, N)`` (``|r|^2``
    floored at 1 m^2)."""
    n_max = C.shape[0] - 1
    size = n_max + 2  # V_nm, W_nm through degree and order n_max + 1
    V = np.zeros((size, size))
    W = np.zeros((size, size))
    scale = gm / (radius * radius)
    for i in range(r.shape[1]):
        x, y, z = r[0, i], r[1, i], r[2, i]
        r2 = max(x * x + y * y + z * z, 1.0)
        rho = radius * radius / r2
        x0, y0, z0 = x * radius / r2, y * radius / r2, z * radius / r2
        V[0, 0] = radius / math.sqrt(r2)
        W[0, 0] = 0.0
        for m in range(size):
            if m > 0:
                V[m, m] = (2 * m - 1) * (x0 * V[m - 1, m - 1] - y0 * W[m - 1, m - 1])
                W[m, m] = (2 * m - 1) * (x0 * W[m - 1, m - 1] + y0 * V[m - 1, m - 1])
            if m + 1 < size:
                V[m + 1, m] = (2 * m + 1) * z0 * V[m, m]
                W[m + 1, m] = (2 * m + 1) * z0 * W[m, m]
            for n in range(m + 2, size):
                V[n, m] = ((2 * n - 1) * z0 * V[n - 1, m] - (n + m - 1) * rho * V[n - 2, m]) / (n - m)
                W[n, m] = ((2 * n - 1) * z0 * W[n - 1, m] - (n + m - 1) * rho * W[n - 2, m]) / (n - m)
        ax = ay = az = 0.0
        for n in range(2, n_max + 1):
            c0 = C[n, 0]
            ax -= c0 * V[n + 1, 1]
            ay -= c0 * W[n + 1, 1]
            az -= (n + 1) * c0 * V[n + 1, 0]
            for m in range(1, n + 1):
                c, s = C[n, m], S[n, m]
                if c == 0.0 and s == 0.0:
                    continue
                f = (n - m + 2) * (n - m + 1)
                ax += 0.5 * (-c * V[n + 1, m + 1] - s * W[n + 1, m + 1]
                             + f * (c * V[n + 1, m - 1] + s * W[n + 1, m - 1]))
                ay += 0.5 * (-c * W[n + 1, m + 1] + s * V[n + 1, m + 1]
                             + f * (-c * W[n + 1, m - 1] + s * V[n + 1, m - 1]))
                az += (n - m + 1) * (-c * V[n + 1, m] - s * W[n + 1, m])
        out[0, i] = scale * ax
        out[1, i] = scale * ay
        out[2, i] = scale * az
