"""Mean and covariance of a Gaussian mixture in one compiled pass: the model averages of the compensated
filters and of the multiple model (:func:`gpf_nav.filters.model_averaging.mixture_moments`) take them
several times a step, on a few rows, where numpy's per-call cost is most of the work. The sums run in
the components' order, as the numpy code's Python sums did: bit for bit its results."""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def moments(weights: np.ndarray, means: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(mean (d,), covariance (d, d))`` of ``sum_k weights_k N(means_k, covariances_k)`` (``weights``
    ``(K,)``, ``means`` ``(K, d)``, ``covariances`` ``(K, d, d)``), the covariance symmetrised. A component
    of weight 0 takes no part, whatever its moments (``0 * inf`` would be NaN)."""
    count, d = means.shape
    mean = np.zeros(d)
    for k in range(count):
        if weights[k] != 0.0:
            for i in range(d):
                mean[i] += weights[k] * means[k, i]
    cov = np.zeros((d, d))
    deviation = np.empty(d)
    for k in range(count):
        w = weights[k]
        if w != 0.0:
            for i in range(d):
                deviation[i] = means[k, i] - mean[i]
            for i in range(d):
                for j in range(d):
                    cov[i, j] += w * (covariances[k, i, j] + deviation[i] * deviation[j])
    symmetric = np.empty((d, d))
    for i in range(d):
        for j in range(d):
            symmetric[i, j] = 0.5 * (cov[i, j] + cov[j, i])
    return mean, symmetric
