"""Weighted moments of a particle cloud."""
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
