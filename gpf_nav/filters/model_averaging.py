"""Is there an unmodelled acceleration at all? The nominal hypothesis tested on a compensated posterior.

A filter with model-error compensation (:mod:`gpf_nav.models.compensation`) estimates an unmodelled
acceleration ``a`` beside the user's state ``x``. When the user's model is right, those three extra
states cost accuracy: the filter keeps learning an ``a`` that is zero. The nominal model (``a = 0``) is
nested in the compensated one, so its evidence needs no second filter. With the compensated posterior
``N(m, P)`` over ``[x, a]`` and the prior of ``a`` ``N(0, sigma^2 I)`` (the Gauss-Markov process is
stationary), the Savage-Dickey density ratio gives the Bayes factor of "no unmodelled acceleration":

    B = N(0; m_a, P_aa) / N(0; 0, sigma^2 I),

and the posterior of ``x`` under that hypothesis is the compensated one conditioned on ``a = 0``:

    m_0 = m_x - P_xa P_aa^-1 m_a,        P_0 = P_xx - P_xa P_aa^-1 P_ax.

Both are exact for a linear-Gaussian model with a constant ``a``; with the slow Gauss-Markov drift of
``a`` the hypothesis is "no unmodelled acceleration now". The estimate is the model average
``pi_0 N(m_0, P_0) + (1 - pi_0) N(m_x, P_xx)`` with ``pi_0 = B rho / (B rho + 1 - rho)`` and ``rho`` the
prior probability of the nominal model. Nothing here knows what the error is; it only asks whether the
measurements need the extra acceleration.
"""
from __future__ import annotations

import math

import numpy as np

from gpf_nav.kernels import mixture
from gpf_nav.linalg import cholesky_or_none, triangular_inverse

NOMINAL_PRIOR = 0.5
"""Default prior probability that the user's model needs no unmodelled acceleration."""
NEGLIGIBLE = 1e-12
"""A model probability below this is taken as zero (the average is then the other model's estimate)."""


def mixture_moments(weights, moments: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(d,)`` and covariance ``(d, d)`` of ``sum_i weights_i N(m_i, P_i)``. A component of weight 0 takes
    no part, whatever its moments (a member of a multiple model that followed garbage to 1e154 has probability
    0, and ``0 * inf`` would be NaN). One compiled pass (:func:`gpf_nav.kernels.mixture.moments`)."""
    return mixture.moments(np.asarray(weights, dtype=float), np.array([m for m, _ in moments], dtype=float),
                           np.array([P for _, P in moments], dtype=float))


def _nominal_hypothesis(mean: np.ndarray, cov: np.ndarray, n: int, sigma: float,
                        prior: float) -> tuple[float, np.ndarray, np.ndarray]:
    """``(pi_0, m_0 (n,), P_0 (n, n))``: the posterior probability of ``a = 0`` and the posterior of the
    user's state under it, from the compensated posterior ``N(mean (n + p,), cov (n + p, n + p))`` (the
    user's ``n`` states first), the prior std ``sigma`` of each of the ``p`` components of ``a`` and the
    prior probability ``prior`` of the nominal model. ``pi_0`` is 0 (and the moments those of ``x``) when
    ``prior`` is 0, the posterior is not finite or ``P_aa`` is not positive definite."""
    m_x, P_xx = mean[:n], cov[:n, :n]
    if prior <= 0.0 or not (np.isfinite(mean).all() and np.isfinite(cov).all()):
        return 0.0, m_x, P_xx
    L = cholesky_or_none(cov[n:, n:])
    if L is None:
        return 0.0, m_x, P_xx
    L_inv = triangular_inverse(L)  # (p, p): two products cost less than two general solves
    white_a = L_inv @ mean[n:]  # L^-1 m_a
    white_xa = L_inv @ cov[n:, :n]  # L^-1 P_ax  (p, n)
    p = L.shape[0]
    log_bayes = (-0.5 * float(white_a @ white_a) - float(np.log(L.diagonal()).sum())
                 + p * math.log(sigma))
    log_odds = log_bayes + math.log(prior) - math.log1p(-prior)  # prior in (0, 1)
    probability = 1.0 / (1.0 + math.exp(-log_odds)) if log_odds > -700.0 else 0.0
    m_0 = m_x - white_xa.T @ white_a
    P_0 = P_xx - white_xa.T @ white_xa
    return probability, m_0, 0.5 * (P_0 + P_0.T)


def model_average(mean: np.ndarray, cov: np.ndarray, n: int, sigma: float, prior: float
                  ) -> tuple[float, np.ndarray, np.ndarray]:
    """``(pi_0, mean (n,), cov (n, n))``: the model-averaged estimate of the user's state (module
    docstring) from the compensated posterior ``N(mean (n + p,), cov (n + p, n + p))``."""
    probability, m_0, P_0 = _nominal_hypothesis(mean, cov, n, sigma, prior)
    if probability < NEGLIGIBLE:
        return probability, mean[:n], cov[:n, :n]
    if probability > 1.0 - NEGLIGIBLE:
        return probability, m_0, P_0
    average_mean, average_cov = mixture_moments((probability, 1.0 - probability),
                                                [(m_0, P_0), (mean[:n], cov[:n, :n])])
    return probability, average_mean, average_cov
