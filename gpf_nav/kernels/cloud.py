"""Weighted moments of a particle cloud."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from gpf_nav.kernels import CHUNK


@njit(cache=True, error_model="numpy")
def weighted_mean(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted mean ``(n,)`` of the cloud ``x`` ``(n, N)`` with weights ``w`` ``(N,)``: each row summed in
    four interleaved partial sums, in a fixed order (the mean is the same number whether or not the
    covariance is formed with it, :func:`moments`)."""
    n, count = x.shape
    mean = np.empty(n)
    body = count - count % 4
    for a in range(n):
        s0 = s1 = s2 = s3 = 0.0
        for j in range(0, body, 4):
            s0 += x[a, j] * w[j]
            s1 += x[a, j + 1] * w[j + 1]
            s2 += x[a, j + 2] * w[j + 2]
            s3 += x[a, j + 3] * w[j + 3]
        for j in range(body, count):
            s0 += x[a, j] * w[j]
        mean[a] = (s0 + s1) + (s2 + s3)
    return mean


@njit(cache=True, error_model="numpy")
def _outside_block(x, start, limit, sums):
    """Particles ``start`` to ``start + CHUNK`` of ``x`` whose component sum (in ``sums`` ``(CHUNK,)``, added
    row after row as numpy's ``x.sum(axis=0)`` adds them) is not below ``limit`` in magnitude, or NaN."""
    size = min(sums.size, x.shape[1] - start)
    first = x[0, start:start + size]
    for t in range(size):
        sums[t] = first[t]
    for a in range(1, x.shape[0]):
        row = x[a, start:start + size]
        for t in range(size):
            sums[t] += row[t]
    outside = 0
    for t in range(size):
        outside += 0 if abs(sums[t]) < limit else 1  # (an integer count: a branch would keep it scalar)
    return outside


@njit(cache=True, error_model="numpy")
def count_outside(x: np.ndarray, limit: float) -> int:
    """How many particles of the cloud ``x`` ``(n, N)`` have a component sum that is NaN or at least
    ``limit`` in magnitude: ``(~(abs(x.sum(axis=0)) < limit)).sum()`` in one pass, without the ``(N,)``
    temporaries."""
    sums = np.empty(CHUNK)
    outside = 0
    for start in range(0, x.shape[1], CHUNK):
        outside += _outside_block(x, start, limit, sums)
    return outside


@njit(cache=True, error_model="numpy")
def _scaled_block(x, mean, w, start, root, scale):
    """Rows ``sqrt(w) (x - mean)`` of the particles ``start`` to ``start + CHUNK`` into ``root`` ``(n, CHUNK)``
    (``scale`` ``(CHUNK,)``: the square roots); returns how many particles the block has. Rows indexed
    through views, so the loops vectorise."""
    size = min(scale.size, x.shape[1] - start)
    weights = w[start:start + size]
    for t in range(size):
        scale[t] = math.sqrt(weights[t])
    for a in range(x.shape[0]):
        row, centre, out = x[a, start:start + size], mean[a], root[a, :size]
        for t in range(size):
            out[t] = (row[t] - centre) * scale[t]
    return size


@njit(cache=True, error_model="numpy", fastmath={"reassoc"})
def _add_products(root, size, cov):
    """Add the products of the first ``size`` columns of ``root`` ``(n, CHUNK)``, row by row, to the upper
    triangle of ``cov`` ``(n, n)`` (sums in any order: they vectorise)."""
    n = root.shape[0]
    for a in range(n):
        for b in range(a, n):
            s = 0.0
            for t in range(size):
                s += root[a, t] * root[b, t]
            cov[a, b] += s


@njit(cache=True, error_model="numpy")
def _moments(x, w):
    n, count = x.shape
    mean = weighted_mean(x, w)
    cov = np.zeros((n, n))
    root = np.empty((n, CHUNK))
    scale = np.empty(CHUNK)
    for start in range(0, count, CHUNK):  # rows of sqrt(w) (x - mean) in a small buffer, their products
        _add_products(root, _scaled_block(x, mean, w, start, root, scale), cov)
    for a in range(n):
        for b in range(a):
            cov[a, b] = cov[b, a]
    return mean, cov


def moments(x: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean ``(n,)`` and covariance ``(n, n)``, exactly symmetric, of the cloud ``x`` ``(n, N)``
    (C-contiguous) with normalised ``weights`` ``(N,)``: the mean of :func:`weighted_mean`, the covariance's
    sums in any order (they vectorise); equal to the numpy ones to rounding."""
    return _moments(x, weights)
