"""Moment-preserving kernel smoothing of a weighted particle cloud (Liu & West's shrinkage).

A near-deterministic model (process noise of millimetres per step against a posterior of hundreds of
metres) never renews the diversity of a particle cloud: after a few resamplings it is a handful of
copies. The cure used here is to read the predicted cloud as a Gaussian kernel mixture

    sum_i w_i N(x; a x_i + (1 - a) m, h^2 P),      a = sqrt(1 - h^2),

whose centres are shrunk towards the weighted mean ``m`` so that the mixture has exactly the cloud's
mean ``m`` and covariance ``P``. The bandwidth ``h`` defaults to :data:`BANDWIDTH_SCALE` times the
Gaussian-optimal one ``(4 / (N (d + 2)))^(1 / (d + 4))`` (at most :data:`MAX_BANDWIDTH`), which vanishes as
``N`` grows: the filter stays consistent. The optimal bandwidth is the one for estimating a density from
``N`` points (0.57 for N = 500 and nine states). In the GPF the kernel is also the part of the prediction
the projection corrects, and a wider one lets the projection carry more of the update and the weights
less. With the mean-linearised update the Gaussian-optimal ``h`` leaves the covariance too small where the
measurements see little (its draws along a curved measurement's level set land off it and are weighted
down), and 1.6 times it made up for part of that. The flattened update does not lose that spread and
uses the optimal ``h``, and the wider one only while an update is in trouble (docs/filters.md).

Moment matching (:class:`ProposalMixture`): the particles of the GPF's cloud proposal are exact draws of
a mixture of Gaussian proposals whose weighted mean and covariance are known exactly; after weighting,
the cloud is moved to them by an affine map, which replaces the sampling noise of its moments.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gpf_nav.kernels import cloud
from gpf_nav.linalg import cholesky_or_none, triangular_inverse


BANDWIDTH_SCALE = 1.6
"""Default bandwidth over the Gaussian-optimal one with the mean-linearised update (0.92 for N = 500 and
nine states)."""
MAX_BANDWIDTH = 0.95
"""Largest default bandwidth (few particles in many dimensions)."""


def optimal_bandwidth(n_particles: int, dim: int) -> float:
    """Gaussian-optimal kernel bandwidth ``h`` for ``n_particles`` points in ``dim`` dimensions."""
    return float((4.0 / (n_particles * (dim + 2.0))) ** (1.0 / (dim + 4.0)))


def default_bandwidth(n_particles: int, dim: int, flattened: bool = False) -> float:
    """The GPF's default bandwidth: :data:`BANDWIDTH_SCALE` times the optimal one for the mean-linearised
    update, the optimal one for the flattened update; at most :data:`MAX_BANDWIDTH` (module docstring)."""
    scale = 1.0 if flattened else BANDWIDTH_SCALE
    return min(MAX_BANDWIDTH, scale * optimal_bandwidth(n_particles, dim))


def weighted_moments(x: np.ndarray, weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``(mean (n,), covariance (n, n))`` of the cloud ``x`` ``(n, N)`` with normalised ``weights`` ``(N,)``,
    or equal weights when None; the covariance is exactly symmetric (:func:`gpf_nav.kernels.cloud.moments`)."""
    if weights is None:
        weights = np.full(x.shape[1], 1.0 / x.shape[1])
    return cloud.moments(np.ascontiguousarray(x), weights)


def paired_moments(x: np.ndarray, weights: np.ndarray, n: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`weighted_moments` of the two clouds stacked in ``x`` ``(2 n, N)`` (rows ``:n`` and ``n:``)
    with normalised ``weights`` ``(N,)``: ``(mean of the first (n,), of the second (n,), covariance of the
    first (n, n), of the second (n, n))``."""
    first_mean, first = cloud.moments(x[:n], weights)
    second_mean, second = cloud.moments(x[n:], weights)
    return first_mean, second_mean, first, second


def shrink(x: np.ndarray, mean: np.ndarray, cov: np.ndarray, bandwidth: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted mean ``m`` ``(n,)`` (the centres' too), kernel centres ``(n, N)`` and kernel covariance
    ``h^2 P`` ``(n, n)`` of the cloud ``x`` ``(n, N)`` whose weighted mean and covariance are ``mean`` and
    ``cov`` (:func:`weighted_moments`)."""
    a = math.sqrt(1.0 - bandwidth ** 2)
    centres = a * x
    centres += ((1.0 - a) * mean)[:, None]
    return mean, centres, bandwidth ** 2 * cov


def match_moments(x: np.ndarray, weights: np.ndarray | None, mean: np.ndarray,
                  cov: np.ndarray, symmetric: bool = False) -> np.ndarray | None:
    """The cloud ``x`` ``(n, N)`` moved by an affine map so that its weighted mean and covariance (equal
    weights when ``weights`` is None) are ``mean`` ``(n,)`` and ``cov`` ``(n, n)`` exactly:
    ``mean + L_cov L_x^-1 (x - m_x)``. None when the cloud's covariance is singular (nothing to map from)
    or ``cov`` is not positive definite. ``symmetric`` says ``cov`` is exactly symmetric (else its
    symmetric part is used).

    The map of ``T x + b``, for ``T`` lower triangular with a positive diagonal (such as this map), is
    the map of ``x`` (the Cholesky factor of ``T P T^T`` is ``T L_P``): mapping a cloud, resampling it
    and mapping the copies moves them where mapping the resampled copies once does."""
    x = np.ascontiguousarray(x)
    current_mean, current = weighted_moments(x, weights)
    return map_moments(x, current_mean, current, mean, cov, symmetric)


def map_moments(x: np.ndarray, current_mean: np.ndarray, current: np.ndarray, mean: np.ndarray,
                cov: np.ndarray, symmetric: bool = False) -> np.ndarray | None:
    """:func:`match_moments` of a cloud ``x`` ``(n, N)`` (C-contiguous) whose weighted mean ``(n,)`` and
    exactly symmetric covariance ``(n, n)`` are ``current_mean`` and ``current`` (as
    :func:`weighted_moments` gives them): ``mean + L_cov L_current^-1 (x - current_mean)``, or None."""
    if not np.isfinite(current).all():
        return None
    source, target = cholesky_or_none(current, symmetric=True), cholesky_or_none(cov, symmetric)
    if source is None or target is None:
        return None
    out = (target @ triangular_inverse(source)) @ (x - current_mean[:, None])  # (BLAS: faster than a kernel)
    out += np.asarray(mean, dtype=float)[:, None]
    return out


@dataclass(frozen=True)
class MixtureMoments:
    """The exact ``mean`` ``(n,)`` and ``cov`` ``(n, n)`` of a weighted mixture of proposals, and the
    ``sampled_mean`` and ``sampled_cov`` of its weighted particles (:meth:`ProposalMixture.moments`)."""

    mean: np.ndarray
    cov: np.ndarray
    sampled_mean: np.ndarray
    sampled_cov: np.ndarray

    def match(self, x: np.ndarray) -> np.ndarray:
        """The weighted particles ``x`` ``(n, N)`` mapped to the exact moments (``x`` itself when the map
        does not exist)."""
        matched = map_moments(x, self.sampled_mean, self.sampled_cov, self.mean, self.cov, symmetric=True)
        return x if matched is None else matched

    def match_resampled(self, resampled: np.ndarray, weighted: np.ndarray, weights: np.ndarray,
                        ancestors: np.ndarray) -> np.ndarray:
        """The cloud ``resampled`` ``(n, N)`` (equal weights; ``weighted[:, ancestors]``) mapped to the
        exact moments; when it has too few distinct particles to be mapped, the ``weighted`` cloud with
        its ``weights`` ``(N,)`` is mapped and resampled instead. Mapping the resampled cloud once lands
        where mapping the weighted cloud and resampling it would (:func:`match_moments`)."""
        matched = match_moments(resampled, None, self.mean, self.cov, symmetric=True)
        if matched is None:
            matched = match_moments(weighted, weights, self.mean, self.cov, symmetric=True)
            matched = None if matched is None else matched[:, ancestors]
        return resampled if matched is None else matched


@dataclass(frozen=True)
class ProposalMixture:
    """The mixture of proposals ``sum_i w_i N(mu_i, spread)`` a cloud was drawn from.

    Attributes:
        pair: ``(2 n, N)``: the proposal means ``mu_i`` (rows ``:n``) above the particles (rows ``n:``,
            the filter's cloud itself, so what the filter does to its cloud in place shows here).
        spread: the proposals' common covariance ``(n, n)``.
    """

    pair: np.ndarray
    spread: np.ndarray

    def moments(self, weights: np.ndarray) -> MixtureMoments | None:
        """The mixture's and the particles' moments under the normalised ``weights`` ``(N,)``; None when
        the mixture's are not finite (a runaway proposal: the sampled cloud is left as it is)."""
        mean, sampled_mean, cov, sampled_cov = paired_moments(self.pair, weights, self.spread.shape[0])
        cov += self.spread
        if not np.isfinite(cov).all():  # (a non-finite mean makes the covariance non-finite)
            return None
        return MixtureMoments(mean, cov, sampled_mean, sampled_cov)
