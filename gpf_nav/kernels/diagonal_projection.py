"""The Euclidean projection of :func:`gpf_nav.filters.projection.project` when ``H_w H_w^T`` is diagonal
(mutually orthogonal Jacobian rows, a diagonal whitener): per particle, a division instead of a solve.

One pass over blocks of :data:`~gpf_nav.kernels.CHUNK` particles: the diagonal ``S``, its trace, the
relative damping, the co-state increment ``a`` and the shift, added straight into the particles, without
the whole ``(k, N)`` and ``(n, N)`` temporaries of the numpy reference (``test/numpy_reference.py``). Each
particle's sums are the ones numpy's ``einsum`` and ``sum(axis=0)`` form on the particle-last Jacobians
the models build (from 0, term after term in order), so the numbers are the numpy ones bit for bit. On
every core from :data:`~gpf_nav.kernels.PARALLEL` particles, with the same arithmetic.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from gpf_nav.kernels import CHUNK, PARALLEL


@njit(cache=True, error_model="numpy")
def _diagonal_block(Ht, columns, w, start, size, diagonal, damping, damping_scale):
    """``diag(H_w H_w^T)`` of the particles ``start`` to ``start + size`` into ``diagonal`` ``(k, CHUNK)``
    and their damping into ``damping`` ``(CHUNK,)``."""
    k = diagonal.shape[0]
    for i in range(k):
        row = diagonal[i, :size]
        for t in range(size):
            row[t] = 0.0
        for c in columns:
            h = Ht[i, c, start:start + size]
            for t in range(size):
                row[t] += h[t] * h[t]
        scale = w[i] * w[i]
        for t in range(size):
            row[t] *= scale
    trace = damping[:size]
    first = diagonal[0, :size]
    for t in range(size):
        trace[t] = first[t]
    for i in range(1, k):
        row = diagonal[i, :size]
        for t in range(size):
            trace[t] += row[t]
    for t in range(size):  # (NaN stays NaN)
        trace[t] = 1.0 if trace[t] <= 0.0 else trace[t] * damping_scale


@njit(cache=True, error_model="numpy")
def _shift_block(Ht, columns, r, w, start, size, diagonal, damping, shift, a, out):
    """``a`` of the particles ``start`` to ``start + size`` (into ``a`` ``(k, N)``) and their shift, summed
    in ``shift`` ``(CHUNK,)`` and added into ``out`` ``(n, N)``."""
    k = diagonal.shape[0]
    for i in range(k):
        ai, ri, si, wi = a[i, start:start + size], r[i, start:start + size], diagonal[i, :size], w[i]
        for t in range(size):
            value = ri[t] * wi / (si[t] + damping[t])
            ai[t] = value if math.isfinite(value) else 0.0
    total = shift[:size]
    for c in columns:
        for t in range(size):
            total[t] = 0.0
        for i in range(k):
            h, ai, wi = Ht[i, c, start:start + size], a[i, start:start + size], w[i]
            for t in range(size):
                total[t] += h[t] * (ai[t] * wi)
        moved = out[c, start:start + size]
        for t in range(size):
            moved[t] += total[t]


def orthogonal_projection(Ht: np.ndarray, columns: np.ndarray, r: np.ndarray, w: np.ndarray,
                          damping_scale: float, out: np.ndarray) -> np.ndarray:
    """Add ``H^T (H_w H_w^T + eps I)^-1 W r`` (whitened) into ``out`` ``(n, N)`` and return
    ``a = (H_w H_w^T + eps I)^-1 W r`` ``(k, N)``.

    Args:
        Ht: the Jacobians particle-last, ``(k, n, N)``: ``Ht[i, c, j] = H_j[i, c]``.
        columns: ``(p,)`` the state components ``h`` depends on (the others' columns of ``H`` are zero
            and get no shift).
        r: innovations ``(k, N)``.
        w: the diagonal of the whitener ``(k,)``.
        damping_scale: ``eps / k``: the damping is ``eps`` times the mean of the diagonal of
            ``H_w H_w^T``; 1 where that trace is not positive (a zero Jacobian gets a zero shift).
        out: the particles ``(n, N)``, shifted in place.

    Entries of ``a`` that are not finite are 0.
    """
    kernel = _projection_parallel if r.shape[1] >= PARALLEL else _projection_serial
    a = np.empty(r.shape)
    kernel(Ht, columns, r, w, damping_scale, a, out)
    return a


@njit(cache=True, error_model="numpy")
def _projection_block(Ht, columns, r, w, damping_scale, a, out, start, diagonal, damping, shift):
    """The particles ``start`` to ``start + CHUNK``, with the scratch rows ``diagonal`` ``(k, CHUNK)``,
    ``damping`` and ``shift`` ``(CHUNK,)``."""
    size = min(CHUNK, r.shape[1] - start)
    _diagonal_block(Ht, columns, w, start, size, diagonal, damping, damping_scale)
    _shift_block(Ht, columns, r, w, start, size, diagonal, damping, shift, a, out)


@njit(cache=True, error_model="numpy")
def _projection_serial(Ht, columns, r, w, damping_scale, a, out):
    diagonal, damping, shift = np.empty((r.shape[0], CHUNK)), np.empty(CHUNK), np.empty(CHUNK)
    for start in range(0, r.shape[1], CHUNK):
        _projection_block(Ht, columns, r, w, damping_scale, a, out, start, diagonal, damping, shift)


@njit(cache=True, error_model="numpy", parallel=True)
def _projection_parallel(Ht, columns, r, w, damping_scale, a, out):
    for block in prange((r.shape[1] + CHUNK - 1) // CHUNK):
        _projection_block(Ht, columns, r, w, damping_scale, a, out, block * CHUNK, np.empty((r.shape[0], CHUNK)),
                          np.empty(CHUNK), np.empty(CHUNK))
