"""Weighted moments of a particle cloud and the affine map of a cloud onto given moments."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from gpf_nav.kernels import CHUNK


@njit(cache=True, error_model="numpy", fastmath={"reassoc"})
def _moments(x, w):
    n, count = x.shape
    mean = np.zeros(n)
    for a in range(n):
        s = 0.0
        for j in range(count):
            s += x[a, j] * w[j]
        mean[a] = s
    cov = np.zeros((n, n))
    root = np.empty((n, CHUNK))
    scale = np.empty(CHUNK)
    for start in range(0, count, CHUNK):  # rows of sqrt(w) (x - mean) in a small buffer, their products
        size = min(CHUNK, count - start)
        for t in range(size):
            scale[t] = math.sqrt(w[start + t])
        for a in range(n):
            for t in range(size):
                root[a, t] = (x[a, start + t] - mean[a]) * scale[t]
        for a in range(n):
            for b in range(a, n):
                s = 0.0
                for t in range(size):
                    s += root[a, t] * root[b, t]
                cov[a, b] += s
    for a in range(n):
        for b in range(a):
            cov[a, b] = cov[b, a]
    return mean, cov


def moments(x: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean ``(n,)`` and covariance ``(n, n)``, exactly symmetric, of the cloud ``x`` ``(n, N)``
    (C-contiguous) with normalised ``weights`` ``(N,)``. The sums run in any order (they vectorise):
    equal to the numpy ones to rounding."""
    return _moments(x, weights)


@njit(cache=True, error_model="numpy")
def _affine(x, centre, T, offset):
    n, count = x.shape
    out = np.empty_like(x)
    d = np.empty((n, CHUNK))
    acc = np.empty(CHUNK)
    for start in range(0, count, CHUNK):
        size = min(CHUNK, count - start)
        for a in range(n):
            for t in range(size):
                d[a, t] = x[a, start + t] - centre[a]
        for a in range(n):
            for t in range(CHUNK):  # (loops, not slice assignments: those take seconds to compile)
                acc[t] = 0.0
            for b in range(a + 1):  # T lower triangular
                c = T[a, b]
                for t in range(CHUNK):
                    acc[t] += c * d[b, t]
            for t in range(size):
                out[a, start + t] = acc[t] + offset[a]
    return out


def affine(x: np.ndarray, centre: np.ndarray, T: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """``offset + T (x - centre)`` ``(n, N)`` of the cloud ``x`` ``(n, N)`` (C-contiguous), ``centre`` and
    ``offset`` ``(n,)``, ``T`` ``(n, n)`` lower triangular (its upper triangle is not read); a new
    array."""
    return _affine(x, centre, np.ascontiguousarray(T), offset)
