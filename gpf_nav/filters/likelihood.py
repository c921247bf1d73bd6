"""The Gaussian measurement likelihood of a particle cloud, and the whitening it shares with the proposals.

``W`` whitens the noise of the measured rows, ``W R_rows W^T = I``, so measurement components in metres
and radians are commensurate; the log-likelihood of a residual ``e`` is then
``log N(e; 0, R) = c - |W e|^2 / 2``. A tempered stage weights by ``p(y | x)^f``, the likelihood of the
noise ``R / f``: its whitener is ``sqrt(f) W`` and its constant ``f c``.
"""
from __future__ import annotations

import math

import numpy as np

from gpf_nav.kernels.log_weights import whitened_log_likelihood


class Whitening:
    """``(W, log of the Gaussian normalising constant)`` per mask of measured rows, for the noise ``R``
    ``(m, m)`` of the sensor in use; cached until ``R`` changes (:meth:`use`)."""

    def __init__(self, R: np.ndarray):
        self.R = R
        self._cache: dict[bytes, tuple[np.ndarray, float]] = {}

    def use(self, R: np.ndarray) -> None:
        """Whiten the noise ``R`` from now on."""
        if R is not self.R and not np.array_equal(R, self.R):
            self._cache = {}
        self.R = R

    def of(self, rows: np.ndarray, fraction: float = 1.0) -> tuple[np.ndarray, float]:
        """``(W, constant)`` of the measured ``rows`` ``(m,)`` bool for the likelihood ``p(y | x)^fraction``:
        ``W`` ``(k, k)``, or its diagonal ``(k,)`` when ``R_rows`` is diagonal (what
        :func:`~gpf_nav.filters.projection.project` and :func:`log_likelihood` take)."""
        key = rows.tobytes()
        if key not in self._cache:
            r = self.R[np.ix_(rows, rows)]
            w = np.linalg.inv(np.linalg.cholesky(r))
            constant = np.log(np.diag(w)).sum() - 0.5 * rows.sum() * np.log(2.0 * np.pi)
            if np.count_nonzero(w) == np.count_nonzero(np.diag(w)):
                w = np.diag(w).copy()
            self._cache[key] = (w, float(constant))
        w, constant = self._cache[key]
        if fraction == 1.0:
            return w, constant
        return math.sqrt(fraction) * w, fraction * constant


def log_likelihood(e: np.ndarray, rows: np.ndarray, whitening: tuple[np.ndarray, float]) -> np.ndarray:
    """Gaussian ``log p(y_rows | x)`` ``(N,)`` from the residuals ``e = y - h(x)`` ``(m, N)`` of every
    component, the measured ``rows`` ``(m,)`` bool and their ``whitening`` ``(W, constant)``."""
    w, constant = whitening
    e = e if rows.all() else e[rows]
    # a diagonal whitener in one compiled pass, the numpy code's numbers (from two particles: einsum sums one
    # particle's rows in another order; and with no row the constant alone)
    if w.ndim == 1 and e.shape[0] and e.shape[1] > 1:
        out = np.empty(e.shape[1])
        whitened_log_likelihood(e, w, constant, out)
        return out
    ew = e * w[:, None] if w.ndim == 1 else w @ e  # (k, N)
    return constant - 0.5 * np.einsum("kn,kn->n", ew, ew)
