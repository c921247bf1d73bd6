"""The draw of the GPF's cloud proposal in whitened coordinates, with its exact-weight correction."""
from __future__ import annotations

import numpy as np
from numba import njit

from gpf_nav.kernels import CHUNK


@njit(cache=True, error_model="numpy")
def _draw(centres, C, m, U, z, log_det):
    n, count = centres.shape
    pair = np.empty((2 * n, count))
    correction = np.empty(count)
    zb, mb, w = np.zeros((n, CHUNK)), np.zeros((n, CHUNK)), np.empty((n, CHUNK))
    mean_row, x_row, zz, ww = np.empty(CHUNK), np.empty(CHUNK), np.empty(CHUNK), np.empty(CHUNK)
    for start in range(0, count, CHUNK):
        size = min(CHUNK, count - start)
        for a in range(n):
            for t in range(size):
                zb[a, t] = z[a, start + t]
                mb[a, t] = m[a, start + t]
        for a in range(n):  # w = m + U z (U upper triangular)
            for t in range(CHUNK):
                w[a, t] = mb[a, t]
            for b in range(a, n):
                c = U[a, b]
                for t in range(CHUNK):
                    w[a, t] += c * zb[b, t]
        for a in range(n):  # [centres + C m; centres + C w] (C lower triangular)
            for t in range(CHUNK):  # (loops, not slice assignments: those take seconds to compile)
                mean_row[t] = 0.0
                x_row[t] = 0.0
            for b in range(a + 1):
                c = C[a, b]
                for t in range(CHUNK):
                    mean_row[t] += c * mb[b, t]
                    x_row[t] += c * w[b, t]
            for t in range(size):
                pair[a, start + t] = mean_row[t] + centres[a, start + t]
                pair[n + a, start + t] = x_row[t] + centres[a, start + t]
        for t in range(CHUNK):
            zz[t] = 0.0
            ww[t] = 0.0
        for a in range(n):  # (|z|^2 - |w|^2) / 2 + log det U
            for t in range(CHUNK):
                zz[t] += zb[a, t] * zb[a, t]
                ww[t] += w[a, t] * w[a, t]
        for t in range(size):
            correction[start + t] = 0.5 * (zz[t] - ww[t]) + log_det
    return pair, correction


def draw(centres: np.ndarray, C: np.ndarray, m: np.ndarray, U: np.ndarray, z: np.ndarray,
         log_det: float) -> tuple[np.ndarray, np.ndarray]:
    """``(pair (2 n, N), correction (N,))``: with ``w = m + U z``, ``pair[:n] = centres + C m`` (the
    proposal means) and ``pair[n:] = centres + C w`` (the particles), and the exact weight's correction
    ``(|z|^2 - |w|^2) / 2 + log_det``. ``centres``, ``m`` and the standard normals ``z`` are ``(n, N)``
    (C-contiguous), ``C`` ``(n, n)`` lower and ``U`` ``(n, n)`` upper triangular (zeros elsewhere),
    ``log_det = log det U``. Each particle's sums run over the state in index order, a block of
    :data:`~gpf_nav.kernels.CHUNK` particles at a time."""
    return _draw(centres, np.ascontiguousarray(C), m, np.ascontiguousarray(U), z, float(log_det))
