"""The observability-constrained update of a particle cloud.

An update keeps the prediction ``N(m^-, P^-)`` along the directions the data carried too little
information about (:mod:`gpf_nav.integrity.observability` finds them). With ``s = V^T x`` the determined
coordinates (``V`` spans the complement of the undetermined subspace ``U``), a likelihood that depends on
``s`` alone leaves the prediction's conditional ``p(x | s)`` unchanged: the posterior is
``p(s | y) p(x | s)``. Its moments are the update's for ``s`` and the prediction's regression for the rest,

    m = m^- + B (V^T m^+ - V^T m^-),   P = P^- - B V^T P^- + B (V^T P^+ V) B^T,   B = P^- V (V^T P^- V)^-1,

and the cloud is moved to them by an affine map. The particle update is exact only in the limit; along
an undetermined direction of a curved problem its approximations (a Gaussian kernel, one linearisation
for the whole cloud) manufacture information there is none of, which this removes.
"""
from __future__ import annotations

import numpy as np

from gpf_nav.filters.kernel import map_moments


def constrain(x: np.ndarray, basis: np.ndarray, prior: tuple[np.ndarray, np.ndarray],
              posterior: tuple[np.ndarray, np.ndarray], jacobian: np.ndarray | None = None
              ) -> np.ndarray | None:
    """The updated cloud ``x`` ``(n, N)`` moved so that it keeps the prediction along the undetermined
    directions ``basis`` ``(n, d)``; None when there is nothing to move (or no sound map).

    ``prior`` and ``posterior`` are the ``(mean (n,), covariance (n, n))`` of the predicted and of the
    updated cloud (the latter exactly symmetric, as :func:`~gpf_nav.filters.kernel.weighted_moments` gives
    it). Computed in units of the prediction's standard deviations. When the update's measurement
    ``jacobian`` ``(k, n)`` is given (the flattened update), each undetermined direction loses its part that
    this measurement moves: the tracker's directions come from a reference that may be tens of kilometres
    from the cloud, and a direction tilted towards the measured one would give the measured coordinate the
    prediction's spread."""
    mean, cov = prior
    n = cov.shape[0]
    scale = np.sqrt(np.maximum(cov.diagonal(), 1e-300))
    P_prior = cov / np.outer(scale, scale)
    m_prior = mean / scale
    m_post, P_post = posterior[0] / scale, posterior[1] / np.outer(scale, scale)
    if jacobian is not None and basis.shape[1]:
        # a direction the measurement moves is not undetermined in this update: keep its part that the
        # measurement does not see (in the scaled coordinates the map works in)
        scaled = basis / scale[:, None]
        scaled = scaled / np.linalg.norm(scaled, axis=0)
        Hs = jacobian * scale
        try:
            scaled = scaled - np.linalg.solve(Hs @ Hs.T, Hs).T @ (Hs @ scaled)
        except np.linalg.LinAlgError:
            return None
        keep = np.linalg.norm(scaled, axis=0) > 0.5
        basis = scaled[:, keep] * scale[:, None]
        if not basis.shape[1]:
            return None
    if basis.shape[1] >= n:
        m, P = m_prior, P_prior
    else:
        q, _ = np.linalg.qr(np.column_stack([basis / scale[:, None], np.eye(n)]))
        V = q[:, basis.shape[1]:]  # (n, n - d) the determined coordinates
        PV = P_prior @ V
        try:
            B = np.linalg.solve(V.T @ PV, PV.T).T
        except np.linalg.LinAlgError:
            return None
        m = m_prior + B @ (V.T @ (m_post - m_prior))
        P = P_prior - B @ PV.T + B @ (V.T @ P_post @ V) @ B.T
    P = 0.5 * (P + P.T) * np.outer(scale, scale)
    if not (np.isfinite(P).all() and np.isfinite(m).all()):
        return None
    return map_moments(x, *posterior, m * scale, P, symmetric=True)
