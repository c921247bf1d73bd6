"""Small dense linear algebra batched over particles, particle index last.

Matrices are ``(m, m, N)`` and vectors ``(m, N)`` so every entry is a contiguous row of length N.
Symmetric positive definite solves of dimension up to 3 are written in closed form (much faster than
``np.linalg.solve`` on many tiny systems); larger ones fall back to LAPACK. The factorisations of single
small matrices call LAPACK directly: numpy's wrappers cost several times the work on a 9 x 9 matrix, and
the filters factor a few at every step.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg.lapack import dpotrf, dtrtri

from gpf_nav.kernels import covariance


def psd_sqrt(cov: np.ndarray) -> np.ndarray:
    """Square root ``L`` with ``L L^T = cov`` of a symmetric PSD ``(n, n)``; never raises.

    Cholesky when ``cov`` is positive definite; otherwise an eigen-decomposition with negative
    eigenvalues clipped to zero.
    """
    factor = cholesky_or_none(cov)
    if factor is not None:
        return factor
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    return vecs * np.sqrt(np.clip(vals, 0.0, None))


def cholesky_or_none(cov: np.ndarray, symmetric: bool = False) -> np.ndarray | None:
    """Lower Cholesky factor of a symmetric ``(n, n)`` matrix (of its symmetric part, unless ``symmetric``
    says it is exactly symmetric already), or None when it is not positive definite. Check finiteness
    first: a non-finite entry may give a non-finite factor."""
    factor, info = dpotrf(cov if symmetric else 0.5 * (cov + cov.T), lower=1, clean=1)
    return factor if info == 0 else None


def triangular_inverse(factor: np.ndarray) -> np.ndarray:
    """Inverse ``(n, n)`` of a lower-triangular ``factor`` with a positive diagonal and a zero upper
    triangle (a factor of :func:`cholesky_or_none`)."""
    inverse, info = dtrtri(factor, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"triangular factor is singular (dtrtri info={info})")
    return inverse


def solve_spd(S: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``S a = b`` for symmetric positive definite ``S`` ``(m, m, N)`` and ``b`` ``(m, N)``."""
    m = S.shape[0]
    if m == 1:
        return b / S[0]
    if m == 2:
        a, c, d = S[0, 0], S[0, 1], S[1, 1]
        inv_det = 1.0 / (a * d - c * c)
        return np.stack([(d * b[0] - c * b[1]) * inv_det, (a * b[1] - c * b[0]) * inv_det])
    if m == 3:
        a, bb, c = S[0, 0], S[0, 1], S[0, 2]
        d, e, f = S[1, 1], S[1, 2], S[2, 2]
        # cofactors of the symmetric matrix [[a, bb, c], [bb, d, e], [c, e, f]]
        A = d * f - e * e
        B = c * e - bb * f
        C = bb * e - c * d
        inv_det = 1.0 / (a * A + bb * B + c * C)
        x0, x1, x2 = b[0] * inv_det, b[1] * inv_det, b[2] * inv_det
        return np.stack([A * x0 + B * x1 + C * x2,
                         B * x0 + (a * f - c * c) * x1 + (bb * c - a * e) * x2,
                         C * x0 + (bb * c - a * e) * x1 + (a * d - bb * bb) * x2])
    return np.linalg.solve(S.transpose(2, 0, 1), b.T[..., None])[..., 0].T


COVARIANCE_FLOOR_RELATIVE = 1e-10
"""Smallest eigenvalue of a published covariance's correlation matrix, relative to its largest and at
least 1 (see :func:`positive_definite`)."""
COVARIANCE_FLOOR_ABSOLUTE = 1e-12
"""Smallest variance of a published covariance, in the state's own units squared (a collapsed cloud)."""


def positive_definite(cov: np.ndarray) -> np.ndarray:
    """The symmetric part of ``cov`` ``(n, n)``, made positive definite where it is not, whatever the
    units of its components.

    Each variance is raised to at least ``COVARIANCE_FLOOR_ABSOLUTE`` (a component a collapsed cloud
    no longer spreads); then the eigenvalues of the correlation matrix ``D^-1/2 cov D^-1/2``
    (``D`` the variances) are raised to at least ``COVARIANCE_FLOOR_RELATIVE`` times the largest of them
    (itself 1 to ``n`` for a covariance, more only for a matrix that is far from one). The floor is on the
    correlations, not on the matrix itself, so it does not depend on the states' units: a covariance of
    positions of kilometres and accelerations of millimetres per second squared keeps its small
    variances. Any consumer can factor and invert the result (its correlation matrix has a condition
    number of at most about 1e10). A matrix already above both floors is returned as it is
    (symmetrised); a non-finite one unchanged (symmetrised), for the caller's non-finite checks. The
    eigen-decomposition runs only where a Cholesky screen cannot prove the floor already met
    (:func:`gpf_nav.kernels.covariance.screen`): the same result, without its cost at every read.
    """
    outcome, cov = covariance.screen(_matrix(cov), COVARIANCE_FLOOR_ABSOLUTE, _SCREEN_MARGIN)
    if outcome != covariance.UNSURE:  # not finite (unchanged), or certainly above the floor
        return cov
    return _floored(cov)


_SCREEN_MARGIN = 2.0 * COVARIANCE_FLOOR_RELATIVE
"""The eigenvalue floor is ``COVARIANCE_FLOOR_RELATIVE`` times the largest eigenvalue of a correlation
matrix, which is at most its trace: a Cholesky factor of the correlation matrix less twice that times the
identity proves every eigenvalue above the floor, rounding included, and spares the eigen-decomposition."""


def _floored(cov: np.ndarray) -> np.ndarray:
    """:func:`positive_definite` of a finite symmetric ``cov`` with floored variances: the eigenvalues of
    its correlation matrix raised to the floor (``cov`` itself when they are all above it)."""
    scale = np.sqrt(cov.diagonal())
    vals, vecs = np.linalg.eigh(cov / np.outer(scale, scale))
    floor = COVARIANCE_FLOOR_RELATIVE * max(1.0, float(vals[-1]))
    if vals[0] >= floor:
        return cov  # (the variances raised, if any were below their floor)
    floored = (vecs * np.maximum(vals, floor)) @ vecs.T
    floored = 0.5 * (floored + floored.T) * np.outer(scale, scale)
    return floored


def _matrix(a) -> np.ndarray:
    """``a`` as the writeable C-contiguous float64 array a kernel takes (no copy when it is one already:
    numba compiles a kernel again for each layout and for read-only arrays)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()
