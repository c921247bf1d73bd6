"""Small dense linear algebra batched over particles: factors and solves of ``m x m`` systems.

Matrices are ``(N, m, m)`` and vectors ``(N, m)``. Solves of dimension up to 3 are written in closed form
(faster than ``np.linalg.solve`` on many tiny systems); larger ones fall back to LAPACK.
"""
from __future__ import annotations

import numpy as np


def psd_sqrt(cov: np.ndarray) -> np.ndarray:
    """Lower-triangular-like square root ``L`` with ``L L^T = cov`` for a symmetric PSD ``(n, n)``.

    Cholesky when ``cov`` is positive definite; otherwise an eigen-decomposition with negative
    eigenvalues clipped to zero, so a singular (or slightly indefinite) covariance never raises.
    """
    cov = 0.5 * (cov + cov.T)
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        vals, vecs = np.linalg.eigh(cov)
        return vecs * np.sqrt(np.clip(vals, 0.0, None))


def solve_spd(S: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``S a = b`` for symmetric positive definite ``S`` ``(N, m, m)``, ``b`` ``(N, m)``."""
    m = S.shape[-1]
    if m == 1:
        return b / S[:, 0, 0:1]
    if m == 2:
        a, c, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
        det = a * d - c * c
        out = np.empty_like(b)
        out[:, 0] = (d * b[:, 0] - c * b[:, 1]) / det
        out[:, 1] = (a * b[:, 1] - c * b[:, 0]) / det
        return out
    if m == 3:
        a, bb, c = S[:, 0, 0], S[:, 0, 1], S[:, 0, 2]
        d, e, f = S[:, 1, 1], S[:, 1, 2], S[:, 2, 2]
        # cofactors of the symmetric matrix [[a, bb, c], [bb, d, e], [c, e, f]]
        A = d * f - e * e
        B = c * e - bb * f
        C = bb * e - c * d
        D = a * f - c * c
        E = bb * c - a * e
        F = a * d - bb * bb
        det = a * A + bb * B + c * C
        x0, x1, x2 = b[:, 0], b[:, 1], b[:, 2]
        out = np.empty_like(b)
        out[:, 0] = (A * x0 + B * x1 + C * x2) / det
        out[:, 1] = (B * x0 + D * x1 + E * x2) / det
        out[:, 2] = (C * x0 + E * x1 + F * x2) / det
        return out
    return np.linalg.solve(S, b[..., None])[..., 0]


def gram(H: np.ndarray) -> np.ndarray:
    """``H H^T`` ``(N, m, m)`` of ``H`` ``(N, m, n)``, one column pair at a time (contiguous when H is)."""
    N, m, _ = H.shape
    S = np.empty((m, m, N)).transpose(2, 0, 1)
    for i in range(m):
        for j in range(i, m):
            S[:, i, j] = sum(H[:, i, k] * H[:, j, k] for k in range(H.shape[2]))
            S[:, j, i] = S[:, i, j]
    return S
