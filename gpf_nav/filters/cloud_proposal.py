"""The navigation-grade GPF's proposal: the projection in the metric of the kernel-smoothed predicted cloud.

The predicted cloud is read as a moment-preserving kernel mixture (:mod:`gpf_nav.filters.kernel`) with
centres ``c_i`` and covariance ``D`` (plus ``Q(dt)``). Each particle's innovation is projected with the
gain of that smoothed prediction, the measurement linearised once at the cloud's mean,

    x = c + D H^T (H D H^T + eps R)^-1 r + draw of N(0, (I - K H) D),

the linearised locally optimal proposal: it corrects every state the measurement is correlated with
(velocity and an estimated unmodelled acceleration, not only position), the perturbed draw keeps the
posterior spread, and the weights ``p(y | x) N(x; c, D) / q(x)`` are exact.

:class:`FlattenedProposal` runs the same update in coordinates where the measurement, now and along the
flow, is exactly its linearisation at the cloud's mean (:mod:`gpf_nav.filters.flattening`).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from gpf_nav.filters.flattening import Flattening, flattening
from gpf_nav.filters.kernel import ProposalMixture, shrink
from gpf_nav.filters.normal_draws import NormalDraws
from gpf_nav.filters.proposal import Move, Proposal, Stage, prior_draw
from gpf_nav.linalg import cholesky_or_none, triangular_inverse

if TYPE_CHECKING:
    from gpf_nav.filters.gpf import GeometricProjectionPF

ILL_CONDITIONED = 1e12
"""``trace(S) / eps`` beyond which the projection is skipped (the update only weights)."""


class CloudProposal(Proposal):
    """The projection with the gain of the kernel-smoothed prediction, linearised at the cloud's mean.

    Args:
        regularization: Tikhonov ``eps`` > 0, in units of the measurement noise (1: the noise itself).
        bandwidth: the kernel's ``h`` in (0, 1).
        troubled_bandwidth: ``h`` while an update is tempered or a measured component was beyond the
            gate in a recent update: a wider kernel lets the projection carry more of a large correction.
        weighting: ``corrected`` (exact weights) or ``likelihood`` (no correction).
        moment_matching: hand the filter the mixture of proposals, whose exact mean and covariance the
            weighted cloud then gets (:class:`~gpf_nav.filters.kernel.ProposalMixture`).
    """

    def __init__(self, regularization: float, bandwidth: float, troubled_bandwidth: float,
                 weighting: str, moment_matching: bool):
        self.regularization = regularization
        self.bandwidth = bandwidth
        self.troubled_bandwidth = troubled_bandwidth
        self.weighting = weighting
        self.moment_matching = moment_matching

    def draw(self, pf: GeometricProjectionPF, stage: Stage) -> Move:
        """Each particle's innovation projected with the gain of the kernel-smoothed prediction, and a draw
        of the resulting Gaussian proposal; the prior transition when there is nothing to project with.

        In whitened coordinates (``x = centre + C w``, ``D = C C^T``; ``W R W^T = I``; ``G = W H C``;
        ``S = G G^T + eps I = L L^T``, ``B = L^-1 G``) the proposal ``q = N(centre + K r, (I - K H) D)``,
        ``K = C G^T S^-1 W``, is ``N(m, I - B^T B)`` with ``m = B^T L^-1 W r``. By Woodbury
        ``I - B^T B = (I + G^T G / eps)^-1 = U U^T`` with ``U = R^-T`` and ``R R^T = I + G^T G / eps``, a
        matrix at least the identity, so its Cholesky factor never fails: the draw is ``w = m + U z`` with
        ``n`` standard normals ``z`` (in antithetic pairs, :func:`antithetic_normals`), and the exact
        weight's correction ``log N(x; centre, D) - log q(x) = (|z|^2 - |w|^2) / 2 + log det U``.
        """
        x_pred, rows, dt = stage.x, stage.rows, stage.dt
        if not rows.any():
            return Move(prior_draw(pf, x_pred, dt)[0], 0.0, rows, None, rows)
        troubled = stage.fraction < 1.0 or any(streak.any() for streak in pf._gate_streaks.values())
        h = self.troubled_bandwidth if troubled else self.bandwidth
        mean, centres, D = shrink(x_pred, *pf._cloud_moments(), h)  # (x_pred is the filter's cloud)
        if dt > 0.0:
            D += pf.model.process_noise(dt, pf._pending_t)
        C = cholesky_or_none(D, symmetric=True) if np.isfinite(D).all() else None  # (its lower triangle)
        if C is None:  # a collapsed cloud on a noise-free model, or a runaway one: nothing to project with
            return Move(prior_draw(pf, x_pred, dt)[0], 0.0, rows, None, rows)
        n, eps = pf.model.state_dim, self.regularization
        H, r = self._linearise(pf, stage, mean, centres)
        whitened = self._whitened(pf, H, r, rows, C, stage.fraction)
        if whitened is None:
            return Move(prior_draw(pf, x_pred, dt)[0], 0.0, rows, None, rows)
        G, wr, S, L_inv = whitened
        white_r = L_inv @ wr  # (k, N)
        # the co-state S^-1 W r / dt, outliers included (the division folded into the small factor)
        costate = ((L_inv.T / dt if dt > 0.0 else L_inv.T) @ white_r).T
        # the gate judges the whole measurement against the prediction: the first draw only
        used = (pf._gate(wr @ pf._weights, S, rows, pf._sensor.name, pf._whitening(rows, stage.fraction)[0])
                if stage.first else rows)
        if not used.any():  # every component refused: a prediction
            return Move(prior_draw(pf, x_pred, dt)[0], 0.0, used, costate, rows)
        if used is not rows:  # outliers left out (a principal block of a sound S is sound)
            G, wr, S, L_inv = self._whitened(pf, H, r, used, C, stage.fraction)
            white_r = L_inv @ wr
        # the proposal in whitened coordinates w = C^-1 (x - centre): N(m, I - B^T B), B = L^-1 G,
        # m = B^T L^-1 W r; and I - B^T B = (I + G^T G / eps)^-1 (Woodbury) = U U^T with U = R^-T,
        # R R^T = I + G^T G / eps (>= I: its factor never fails)
        B = L_inv @ G  # (k, n)
        M = G.T @ G  # exactly symmetric (numpy forms A^T A as such)
        M *= 1.0 / eps
        M.flat[::n + 1] += 1.0
        R = cholesky_or_none(M, symmetric=True)  # never None: M >= I, and the check of S bounds G G^T / eps
        U = triangular_inverse(R).T  # (n, n)
        z = antithetic_normals(pf.normal_draws, n, pf.n_particles)
        m = B.T @ white_r  # (n, N)
        w = U @ z
        w += m
        pair = np.empty((2 * n, pf.n_particles))  # [proposal means; x]: weighed together after the update
        proposal_means = np.matmul(C, m, out=pair[:n])
        proposal_means += centres
        x = np.matmul(C, w, out=pair[n:])
        x += centres
        mixture = None
        if self.moment_matching:
            spread = C @ U  # (I - K H) D = C U (C U)^T
            mixture = ProposalMixture(pair, spread @ spread.T)
        if self.weighting == "likelihood":
            correction = 0.0
        else:
            # log N(x; centre, D) - log q(x) = (|z|^2 - |w|^2) / 2 + log det U (x - centre = C w, and
            # x - proposal mean = C U z)
            correction = np.einsum("kn,kn->n", z, z)
            correction -= np.einsum("kn,kn->n", w, w)
            correction *= 0.5
            correction -= sum(map(math.log, R.diagonal().tolist()))  # log det U
        return Move(x, correction, used, costate, rows, mixture)

    def _linearise(self, pf: GeometricProjectionPF, stage: Stage, mean: np.ndarray, centres: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """``(H (m, n), r (N, m))``: the Jacobian at the cloud's ``mean`` ``(n,)`` and the innovations of
        the kernel ``centres`` ``(n, N)``."""
        sensor = pf._sensor
        H = sensor.jacobian(mean[None], pf.time)[0]
        r = sensor.measurement_residual(stage.y, centres.T, pf.time)
        return H, r

    def _whitened(self, pf: GeometricProjectionPF, H: np.ndarray, r: np.ndarray, rows: np.ndarray,
                  C: np.ndarray, fraction: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """``(G = W H C (k, n), W r (k, N), S = G G^T + eps I (k, k), L^-1 (k, k))`` (``S = L L^T``) of the
        measured ``rows`` from the Jacobian ``H`` ``(m, n)`` and the innovations ``r`` ``(N, m)``, ``W``
        the whitener of this stage's likelihood ``p(y | x)^fraction``.

        None when ``S`` is not sound to project with: ``S >= eps I`` in exact arithmetic, but when the
        prediction is beyond ~1e6 measurement sigmas, or a Jacobian overflowed, the identity is lost to
        rounding."""
        if not rows.all():
            H, r = H[rows], r[:, rows]
        W = pf._whitening(rows, fraction)[0]
        if W.ndim == 1:
            G, wr = (H * W[:, None]) @ C, r.T * W[:, None]
        else:
            G, wr = W @ H @ C, W @ r.T
        S = G @ G.T  # exactly symmetric (numpy forms A A^T as such)
        S.flat[::S.shape[0] + 1] += self.regularization  # the diagonal
        # S = G G^T + eps I: a finite trace bounds every entry, and a NaN fails the comparison
        if not S.trace() < ILL_CONDITIONED * self.regularization:
            return None
        L = cholesky_or_none(S, symmetric=True)
        return None if L is None else (G, wr, S, triangular_inverse(L))


class FlattenedProposal(CloudProposal):
    """:class:`CloudProposal` in flattened coordinates (:mod:`gpf_nav.filters.flattening`).

    The whole update (kernel, projection, weights, moment matching, resampling, the observability
    constraint) runs where the measured rows, now and of the state flowed half the ``horizon`` and the
    whole of it ahead, are exactly their linearisation at the cloud's mean: the update of a linear
    measurement, for which the kernel's straight-line draws, the one gain and the exact weights are
    right. The filter maps the cloud back after it. A cloud whose curvature is negligible stays in the
    state's coordinates.

    Args:
        horizon: the time ahead the coordinates also make the measured rows linear at, s (0: now only).
        Other arguments as :class:`CloudProposal`.
    """

    def __init__(self, regularization: float, bandwidth: float, troubled_bandwidth: float,
                 weighting: str, moment_matching: bool, horizon: float):
        super().__init__(regularization, bandwidth, troubled_bandwidth, weighting, moment_matching)
        self.horizon = horizon

    @property
    def lags(self) -> tuple[float, ...]:
        """The times ahead the flattened coordinates also make the measured rows linear at, s."""
        return (0.5 * self.horizon, self.horizon) if self.horizon > 0.0 else ()

    def flatten(self, pf: GeometricProjectionPF, rows: np.ndarray) -> Flattening | None:
        flattened = flattening(pf._x, pf._weights, rows, pf._sensor, pf.model, pf.time, pf._input,
                               self.lags, pf.model.base_state_dim)
        if flattened is None:
            return None
        flat, pf._x = flattened
        return flat

    def _linearise(self, pf, stage, mean, centres):
        """The measurement is linear in the flattened coordinates: its Jacobian and value at the
        linearisation point give every centre's innovation."""
        flat = stage.flat
        if flat is None:
            return super()._linearise(pf, stage, mean, centres)
        H = flat.jacobian
        r = pf._sensor.residual(stage.y, flat.measured)[None] - (centres.T - flat.mean) @ H.T
        return H, r


def antithetic_normals(draws: NormalDraws, rows: int, count: int) -> np.ndarray:
    """Standard normal draws ``(rows, count)`` in antithetic pairs: column ``i + ceil(count / 2)`` is minus
    column ``i``. Each column is still an exact standard normal draw (so each particle's draw is exactly
    from its own proposal and the exact weights stay exact); the pairs halve the draws, the costliest
    part of the cloud proposal at a few hundred particles, and make the unweighted mean of the noise
    zero (antithetic variates)."""
    half = (count + 1) // 2
    z = draws(rows, half)
    out = np.empty((rows, count))
    out[:, :half] = z
    np.negative(z[:, :count - half], out=out[:, half:])
    return out
