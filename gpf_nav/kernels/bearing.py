"""Range, azimuth and elevation seen from a station (the lunar model's measurement): their residuals and
their Jacobian.

The residual is the measurement, its residual and the angles' wrapping
(:func:`gpf_nav.models.state_space.wrapped_residual`) without the numpy code's ``(N, 3)`` temporaries. Below
:data:`~gpf_nav.kernels.VECTOR_MATH` particles it is one pass, ``math.atan2`` the C library's, as
``np.arctan2`` is where numpy has no SIMD version of its own (x86-64 without AVX-512): there the result is
the numpy one bit for bit, elsewhere equal to rounding. From it the arctangents are numpy's own over the
whole cloud (its SIMD loops, several times faster than the C library's one at a time) between two
passes, and the result is the numpy one bit for bit on every machine (``test_kernels`` checks both). The
Jacobian is built from the line of sight (:func:`gpf_nav.kernels.orbit.line_of_sight`) with the numpy
code's operations, one particle at a time: no transcendental function, so it too is the numpy one bit for
bit. One pass writes every entry, the zero ones included, instead of zeroing the ``(3, 6, N)`` array first
and filling it row by row.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from gpf_nav.kernels import CHUNK, PARALLEL, VECTOR_MATH
from gpf_nav.kernels.angles import INVERSE_TWO_PI, TWO_PI
from gpf_nav.kernels.orbit import line_of_sight


@njit(cache=True, error_model="numpy")
def _wrap_angles(out) -> None:
    for c in range(1, 3):
        row = out[c]
        for j in range(row.size):
            row[j] -= TWO_PI * np.ceil((row[j] - math.pi) * INVERSE_TWO_PI)


@njit(cache=True, error_model="numpy")
def _residual_scalar(r, station, y, reverse, out):
    """The residuals in one pass over the particles, the angles wrapped after it when any needs it (NaN
    counts, as in :func:`~gpf_nav.kernels.angles.wrap_columns`)."""
    s0, s1, s2 = station[0], station[1], station[2]
    wrap = False
    for j in range(out.shape[1]):
        d0, d1, d2 = r[0, j] - s0, r[1, j] - s1, r[2, j] - s2
        horizontal = d0 * d0 + d1 * d1
        h = (math.sqrt(horizontal + d2 * d2), math.atan2(d1, d0), math.atan2(d2, math.sqrt(horizontal)))
        for c in range(3):
            value = h[c] - y[c] if reverse else y[c] - h[c]
            out[c, j] = value
            if c > 0:
                wrap |= np.ceil((value - math.pi) * INVERSE_TWO_PI) != 0.0
    if wrap:
        _wrap_angles(out)


@njit(cache=True, error_model="numpy")
def _difference(h, y, reverse, out):
    """``y - h`` (``reverse``: ``h - y``) of the measurements ``h`` ``(3, N)`` into ``out``, both angles
    wrapped when either needs it anywhere; row by row, so the loops vectorise."""
    wrap = False
    for c in range(3):
        measured, target, value = h[c], out[c], y[c]
        for j in range(measured.size):
            target[j] = measured[j] - value if reverse else value - measured[j]
        if c > 0:
            for j in range(target.size):
                wrap |= np.ceil((target[j] - math.pi) * INVERSE_TWO_PI) != 0.0
    if wrap:
        _wrap_angles(out)


def range_bearing_residual(r: np.ndarray, station: np.ndarray, y: np.ndarray, reverse: bool) -> np.ndarray:
    """``(3, N)``: ``y - h`` (``reverse``: ``h - y``) of the range, azimuth and elevation ``h`` of the
    positions ``r`` ``(3, N)`` (C-contiguous) seen from ``station`` ``(3,)``, for the measurement ``y``
    ``(3,)``; both angles wrapped to (-pi, pi] when either needs it anywhere, neither otherwise (the numpy
    code's rule). From :data:`~gpf_nav.kernels.VECTOR_MATH` particles with numpy's arctangent."""
    out = np.empty((3, r.shape[1]))
    if r.shape[1] < VECTOR_MATH:
        _residual_scalar(r, station, y, bool(reverse), out)
        return out
    geometry = line_of_sight(r, station)  # d (3 rows), horizontal length, range
    h = out  # (the measurement, then its residual in place)
    np.arctan2(geometry[1], geometry[0], out=h[1])
    np.arctan2(geometry[2], geometry[3], out=h[2])
    h[0] = geometry[4]
    _difference(h, y, bool(reverse), out)
    return out


def range_bearing_jacobian(d: np.ndarray, horizontal: np.ndarray, rho: np.ndarray, min_horizontal: float,
                           min_range: float) -> np.ndarray:
    """``(3, 6, N)``: ``d(range, azimuth, elevation) / d(r, v)`` for the lines of sight ``d`` ``(3, N)``,
    their horizontal lengths and ranges ``(N,)``; the horizontal length floored at ``min_horizontal``
    and the range at ``min_range`` (NaN kept, as ``np.maximum`` keeps it). The velocity columns are
    zero. On every core from :data:`~gpf_nav.kernels.PARALLEL` particles."""
    jac = np.empty((3, 6, rho.size))
    kernel = _jacobian_parallel if rho.size >= PARALLEL else _jacobian_serial
    kernel(d, horizontal, rho, min_horizontal, min_range, jac)
    return jac


@njit(cache=True, error_model="numpy")
def _jacobian_block(d, horizontal, rho, min_horizontal, min_range, jac, start, stop):
    for j in range(start, stop):
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


@njit(cache=True, error_model="numpy")
def _jacobian_serial(d, horizontal, rho, min_horizontal, min_range, jac):
    _jacobian_block(d, horizontal, rho, min_horizontal, min_range, jac, 0, rho.size)


@njit(cache=True, error_model="numpy", parallel=True)
def _jacobian_parallel(d, horizontal, rho, min_horizontal, min_range, jac):
    for block in prange((rho.size + CHUNK - 1) // CHUNK):
        _jacobian_block(d, horizontal, rho, min_horizontal, min_range, jac, block * CHUNK,
                        min(block * CHUNK + CHUNK, rho.size))
