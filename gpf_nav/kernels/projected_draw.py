"""The cloud proposal's draw (:class:`~gpf_nav.filters.cloud_proposal.CloudProposal`) in one pass: each
particle's projected proposal mean, its draw and the exact weight's correction, block by block, without the
``(n, N)`` temporaries of the five matrix products and two sums of squares it replaces.

Each product is a chain of fused multiply-adds over the inner index in turn, from zero: the order of the
BLAS products of the numpy code (the same numbers bit for bit where those are such chains, as with
OpenBLAS on x86-64 with FMA; to rounding elsewhere). The sums of squares are numpy's (a multiply, then an
add, over the rows in turn). From a few thousand particles it is several times faster than the products
(their temporaries no longer fit the caches); at a few hundred it is as fast.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from gpf_nav.kernels import CHUNK, PARALLEL


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def _products(A, X, start, size, sums, out, add):
    """``out[i, :size] = (A X)[i, start:start + size] + add[i, :size]`` for ``A`` ``(r, k)`` and ``X``
    ``(k, N)``, each product a chain of fused multiply-adds from zero through ``sums`` ``(CHUNK,)``, then
    one add."""
    for i in range(A.shape[0]):
        for t in range(size):
            sums[t] = 0.0
        for k in range(A.shape[1]):
            factor, row = A[i, k], X[k, start:start + size]
            for t in range(size):
                sums[t] += factor * row[t]
        target, plus = out[i], add[i]
        for t in range(size):
            target[t] = sums[t] + plus[t]


@njit(cache=True, error_model="numpy")
def _correction(z, w, start, size, log_det, zz, ww, out):
    """``out[:size] = (|z|^2 - |w|^2) / 2 - log_det`` of the columns ``start`` to ``start + size`` of ``z``
    and the first ``size`` of ``w``, each sum of squares over the rows in turn (multiply, then add)."""
    for t in range(size):
        zz[t] = 0.0
        ww[t] = 0.0
    for k in range(z.shape[0]):
        drawn, moved = z[k, start:start + size], w[k, :size]
        for t in range(size):
            zz[t] += drawn[t] * drawn[t]
        for t in range(size):
            ww[t] += moved[t] * moved[t]
    for t in range(size):
        out[t] = (zz[t] - ww[t]) * 0.5 - log_det


@njit(cache=True, error_model="numpy")
def _draw_block(C, U, Bt, centres, white_r, z, log_det, pair, correction, start, m, w, sums, zz, ww, zero):
    """:func:`projected_draw` of the particles ``start`` to ``start + CHUNK`` through the block buffers
    ``m``, ``w`` ``(n, CHUNK)`` and ``sums``, ``zz``, ``ww`` ``(CHUNK,)``; ``zero`` ``(n, CHUNK)`` of zeros."""
    n = z.shape[0]
    size = min(sums.size, z.shape[1] - start)
    stop = start + size
    block_m, block_w = m[:, :size], w[:, :size]
    _products(Bt, white_r, start, size, sums, block_m, zero[:, :size])
    _products(U, z, start, size, sums, block_w, block_m)
    _products(C, block_m, 0, size, sums, pair[:n, start:stop], centres[:, start:stop])
    _products(C, block_w, 0, size, sums, pair[n:, start:stop], centres[:, start:stop])
    _correction(z, block_w, start, size, log_det, zz, ww, correction[start:stop])


@njit(cache=True, error_model="numpy")
def _draw_serial(C, U, Bt, centres, white_r, z, log_det, pair, correction):
    n = z.shape[0]
    m, w, zero = np.empty((n, CHUNK)), np.empty((n, CHUNK)), np.zeros((n, CHUNK))
    sums, zz, ww = np.empty(CHUNK), np.empty(CHUNK), np.empty(CHUNK)
    for start in range(0, z.shape[1], CHUNK):
        _draw_block(C, U, Bt, centres, white_r, z, log_det, pair, correction, start, m, w, sums, zz, ww, zero)


@njit(cache=True, error_model="numpy", parallel=True)
def _draw_parallel(C, U, Bt, centres, white_r, z, log_det, pair, correction):
    n = z.shape[0]
    zero = np.zeros((n, CHUNK))
    for block in prange((z.shape[1] + CHUNK - 1) // CHUNK):
        _draw_block(C, U, Bt, centres, white_r, z, log_det, pair, correction, block * CHUNK, np.empty((n, CHUNK)),
                    np.empty((n, CHUNK)), np.empty(CHUNK), np.empty(CHUNK), np.empty(CHUNK), zero)


def projected_draw(C: np.ndarray, U: np.ndarray, Bt: np.ndarray, centres: np.ndarray, white_r: np.ndarray,
                   z: np.ndarray, log_det: float) -> tuple[np.ndarray, np.ndarray]:
    """The proposal drawn in the kernel's whitened coordinates and mapped to the state's
    (:meth:`~gpf_nav.filters.cloud_proposal.CloudProposal.draw`), for the kernel's factor ``C`` ``(n, n)``,
    the proposal's factor ``U`` ``(n, n)``, the gain ``B^T`` ``(n, k)``, the kernel ``centres`` ``(n, N)``, the
    whitened innovations ``white_r`` ``(k, N)`` and the standard normals ``z`` ``(n, N)`` (all C-contiguous):
    with ``m = B^T white_r`` and ``w = U z + m``, ``([C m + centres; C w + centres] (2 n, N), (|z|^2 - |w|^2)
    / 2 - log_det (N,))``, the proposal means and the draws stacked, and the weights' correction. On every
    core from :data:`~gpf_nav.kernels.PARALLEL` particles."""
    n, count = z.shape
    pair, correction = np.empty((2 * n, count)), np.empty(count)
    kernel = _draw_parallel if count >= PARALLEL else _draw_serial
    kernel(C, U, Bt, centres, white_r, z, float(log_det), pair, correction)
    return pair, correction
