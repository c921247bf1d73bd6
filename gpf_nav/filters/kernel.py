"""Moment-preserving kernel smoothing of a weighted particle cloud (Liu & West's shrinkage).

A near-deterministic model (process noise of millimetres per step against a posterior of hundreds of
metres) never renews the diversity of a particle cloud: after a few resamplings it is a handful of
copies. The cure used here is to read the predicted cloud as a Gaussian kernel mixture

    sum_i w_i N(x; a x_i + (1 - a) m, h^2 P),      a = sqrt(1 - h^2),

whose centres are shrunk towards the weighted mean ``m`` so that the mixture has exactly the cloud's
mean ``m`` and covariance ``P``. The bandwidth ``h`` defaults to the Gaussian-optimal one
``(4 / (N (d + 2)))^(1 / (d + 4))``, which vanishes as ``N`` grows: the filter stays consistent.
"""
from __future__ import annotations

import numpy as np

from gpf_nav.linalg import cholesky_or_none, triangular_inverse


def optimal_bandwidth(n_particles: int, dim: int) -> float:
    """Gaussian-optimal kernel bandwidth ``h`` for ``n_particles`` points in ``dim`` dimensions."""
    return float((4.0 / (n_particles * (dim + 2.0))) ** (1.0 / (dim + 4.0)))


def weighted_moments(x: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(mean (n,), deviations x - mean (n, N), covariance (n, n))`` of the cloud ``x`` ``(n, N)`` with
    normalised ``weights`` ``(N,)``."""
    mean = x @ weights
    d = x - mean[:, None]
    return mean, d, (d * weights) @ d.T


def shrink(x: np.ndarray, weights: np.ndarray, bandwidth: float) -> tuple[np.ndarray, np.ndarray]:
    """Kernel centres ``(n, N)`` and kernel covariance ``h^2 P`` ``(n, n)`` of the cloud ``x`` ``(n, N)``
    with normalised ``weights`` ``(N,)``."""
    mean, _, cov = weighted_moments(x, weights)
    a = np.sqrt(1.0 - bandwidth ** 2)
    centres = a * x
    centres += ((1.0 - a) * mean)[:, None]
    return centres, bandwidth ** 2 * 0.5 * (cov + cov.T)


def match_moments(x: np.ndarray, weights: np.ndarray, mean: np.ndarray,
                  cov: np.ndarray) -> np.ndarray | None:
    """The cloud ``x`` ``(n, N)`` moved by an affine map so that its weighted mean and covariance are
    ``mean`` ``(n,)`` and ``cov`` ``(n, n)`` exactly: ``mean + L_cov L_x^-1 (x - m_x)``. None when the
    cloud's covariance is singular (nothing to map from) or ``cov`` is not positive definite.

    The map of ``T x + b``, for ``T`` lower triangular with a positive diagonal (such as this map), is
    the map of ``x`` (the Cholesky factor of ``T P T^T`` is ``T L_P``): mapping a cloud, resampling it
    and mapping the copies moves them where mapping the resampled copies once does."""
    _, d, current = weighted_moments(x, weights)
    if not np.isfinite(current).all():
        return None
    source, target = cholesky_or_none(current), cholesky_or_none(cov)
    if source is None or target is None:
        return None
    out = (target @ triangular_inverse(source)) @ d
    out += mean[:, None]
    return out
