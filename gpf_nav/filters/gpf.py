"""The Geometric Projection Particle Filter (paper Algorithm 1, projection written consistently).

Each update moves the predicted particles ``x^-`` towards the measurement-consistent subspace,

    x = x^- + M H^T (H M H^T + eps R)^-1 r + noise,

with ``r = y - h(x^-)`` (angles wrapped), then weights them. ``metric`` chooses ``M``:

* ``"cloud"`` (default, the navigation-grade configuration): ``M = D``, the covariance of the predicted
  cloud read as a moment-preserving kernel mixture (:mod:`gpf_nav.filters.kernel`) plus ``Q(dt)``, with
  ``eps = 1``. The projection is then the linearised locally optimal proposal of the smoothed prediction:
  it corrects every state the measurement is correlated with (velocity and the unmodelled acceleration,
  not only position), the perturbed draw keeps the posterior spread, and the weights
  ``p(y | x) N(x; centre, D) / q(x)`` are exact, so the cloud's covariance means what it says. The model
  is augmented with an estimated unmodelled acceleration (:class:`ModelErrorCompensation`) unless
  ``unmodelled_acceleration_std = 0``: the co-state drives its correction.
* ``"euclidean"`` (the paper): ``M = I``, ``H^T (H H^T + eps I)^-1`` with ``H`` and ``r`` whitened and
  ``eps`` relative, noise ``L z`` (``Q = L L^T``) added. It moves position only.
* ``"process_noise"``: ``M = Q(dt)``; with ``eps = 1`` the mean of the locally optimal proposal of the
  nominal model (noise still ``L z``).

Options of the paper's configurations: ``reference="increment"`` uses
``r = (y_k - y_{k-1}) - eta(x^-) dt`` with ``eta = H f(x^-)``, the increment as printed in Algorithm 1 (no
projection on the first update, or for a component not measured last time); ``weighting="likelihood"``
multiplies the weights by ``p(y | x)`` only, as in the paper's experiments (not exact: the posterior is
biased by the proposal); ``weighting="corrected"`` also by ``p(x | x_prev) / q(x | x_prev, y)``. For the
Euclidean and process-noise metrics that needs ``Q(dt)`` positive definite; where it is not
(``dt = 0``, a noise-free model), the update does not project.

The geometric co-state ``lambda = (H_w M_w H_w^T + eps I)^-1 W r / dt`` is kept per particle (whitened
measurement units per second).
"""
from __future__ import annotations

import math

import numpy as np

from gpf_nav.filters.flattening import flattening
from gpf_nav.filters.compensated import (UNMODELLED_ACCELERATION_STD, UNMODELLED_ACCELERATION_TIME,
                                         ModelErrorCompensated)
from gpf_nav.filters.gating import OUTLIER_GATE, OUTLIER_GATE_LIMIT, InnovationGated
from gpf_nav.filters.kernel import default_bandwidth, map_moments, match_moments, paired_moments, shrink
from gpf_nav.filters.model_averaging import NOMINAL_PRIOR
from gpf_nav.filters.particle import ParticleFilter, gaussian_shift_correction, select_rows
from gpf_nav.filters.projection import project
from gpf_nav.linalg import cholesky_or_none, triangular_inverse
from gpf_nav.models.state_space import StateSpaceModel

REFERENCES = ("innovation", "increment")
METRICS = ("cloud", "euclidean", "process_noise")
WEIGHTINGS = ("corrected", "likelihood")
LINEARIZATIONS = ("mean", "flattened")
ILL_CONDITIONED = 1e12
"""Cloud metric: ``trace(S) / eps`` beyond which the projection is skipped (the update only weights)."""
DEFAULT_REGULARIZATION = {"cloud": 1.0, "euclidean": 1e-6, "process_noise": 1e-6}
"""Tikhonov ``eps`` of each metric when none is given (1: the measurement noise itself, for ``cloud``)."""
OBSERVABILITY_CONSTRAINT = 1e-3
"""Cloud metric: default ``observability_constraint`` (:class:`~gpf_nav.filters.particle.ParticleFilter`):
the update keeps the prediction along directions the data carried less information about than this
fraction of the prior's."""
TEMPERING_ESS = 0.1
"""Cloud metric: default ``tempering_ess`` (:class:`~gpf_nav.filters.particle.ParticleFilter`): an update
that would leave fewer than this fraction of effective particles is tempered."""


class GeometricProjectionPF(ModelErrorCompensated, InnovationGated, ParticleFilter):
    """GPF: the SMC loop with the geometric projection proposal.

    ``GeometricProjectionPF(model)`` is the navigation-grade configuration (cloud metric, exact weights,
    unmodelled-acceleration compensation). The paper's filter is
    ``GeometricProjectionPF(model, metric="euclidean", weighting="likelihood", unmodelled_acceleration_std=0)``.
    The default estimator is not this class but :class:`~gpf_nav.filters.multiple_model.MultipleModelGPF`
    (``make_filter("gpf", model)``, two of these filters): alone, the compensated filter can invent an
    unobservable acceleration and diverge, e.g. with range only (docs/filters.md, *Robust by construction*).

    With compensation on, the filter runs on ``ModelErrorCompensation(model)``: :attr:`model` is that
    augmented model, :attr:`particles` are augmented ``(N, n + p)``, but :meth:`initialize` takes the
    user's prior (``(n,)``; an augmented ``(n + p,)`` prior is accepted too) and :attr:`mean` /
    :attr:`covariance` are those of the user's state; :attr:`unmodelled_acceleration` and its covariance
    give the estimated extra acceleration.

    Args:
        model: the state-space model.
        n_particles: number of particles N.
        reference: ``innovation`` (default) or ``increment`` (Algorithm 1 as printed; not with ``cloud``).
        weighting: ``corrected`` (default, exact) or ``likelihood`` (the paper's experiments).
        metric: ``cloud`` (default), ``euclidean`` (the paper) or ``process_noise``.
        regularization: Tikhonov ``eps`` > 0 of the projection (dimensionless; relative for the
            Euclidean metric, in units of the measurement noise otherwise); default per metric,
            :data:`DEFAULT_REGULARIZATION`.
        unmodelled_acceleration_std: stationary std of the estimated unmodelled acceleration (state units
            per s^2); 0 turns the compensation off.
        unmodelled_acceleration_time: its correlation time, s.
        nominal_prior: prior probability that the model needs no unmodelled acceleration; the estimate
            (:attr:`mean`, :attr:`covariance`) is the model average of the two hypotheses
            (:mod:`gpf_nav.filters.model_averaging`); 0 gives the compensated posterior as it is.
        kernel_bandwidth: ``h`` of the cloud metric's kernel in (0, 1); default
            :func:`~gpf_nav.filters.kernel.default_bandwidth`: 1.6 times the Gaussian-optimal one with
            the mean-linearised update; with the flattened one the optimal one, and 1.6 times it while an
            update is tempered or a measured component was beyond the gate in a recent update.
        outlier_gate: cloud metric: a measured component whose innovation is beyond this many standard
            deviations is not used (counted in :attr:`gated`; its co-state is still computed, so the
            integrity monitor sees it); 0 disables the gate.
        outlier_gate_limit: consecutive refusals of a component after which it is used anyway.
        moment_matching: cloud metric: give the weighted cloud the exact mean and covariance of the
            mixture of proposals after each update (and back after a resampling); False leaves the
            sampled moments (for comparison: docs/filters.md).
        tempering_ess: cloud metric: likelihood tempering below this ESS/N
            (:meth:`ParticleFilter.update`; the kernel of the cloud metric moves the particles between
            stages); default :data:`TEMPERING_ESS`, 0 turns it off. The other metrics have no move
            between stages and take 0 only.
        observability_constraint: the update keeps the prediction along the directions the data carried
            less information about than this fraction of the prior's (:class:`ParticleFilter`); default
            :data:`OBSERVABILITY_CONSTRAINT` for the cloud metric, 0 (off) for the others.
        linearization: cloud metric: ``mean`` (default) linearises the measurement once at the cloud's
            mean; ``flattened`` runs the whole update (kernel, projection, weights, moment matching,
            resampling, the observability constraint) in coordinates where the measurement is exactly
            that linearisation, and maps the cloud back after it (:meth:`_begin_update`): a measurement
            curved in the state's coordinates (a range about a centre) then no longer narrows the cloud
            along the directions it cannot see (issue 23).
        flattening_horizon: ``linearization="flattened"``: the flattened coordinates also make the
            measured rows of the state flowed half this time and this time ahead linear (s; 0: the rows
            measured now only), so the kernel's draws also keep what the dynamics will turn the
            measurement into (:mod:`gpf_nav.filters.flattening`). Choose it well inside the time over
            which the dynamics stay near their linearisation across the cloud (the navigation default,
            :data:`gpf_nav.registry.NAVIGATION_GPF`, takes 100 s for the lunar descent).
        resampling: resampling scheme name.
        ess_threshold: tau in (0, 1].
        seed: seed of the filter's random generator.
        collapse_steps: see :class:`ParticleFilter`.
    """

    def __init__(self, model: StateSpaceModel, n_particles: int = 500, reference: str = "innovation",
                 weighting: str = "corrected", metric: str = "cloud", regularization: float | None = None,
                 unmodelled_acceleration_std: float = UNMODELLED_ACCELERATION_STD,
                 unmodelled_acceleration_time: float = UNMODELLED_ACCELERATION_TIME,
                 nominal_prior: float = NOMINAL_PRIOR, kernel_bandwidth: float | None = None,
                 outlier_gate: float = OUTLIER_GATE,
                 outlier_gate_limit: int = OUTLIER_GATE_LIMIT, moment_matching: bool = True,
                 resampling: str = "systematic",
                 ess_threshold: float = 0.5, seed: int | np.random.Generator | None = None,
                 collapse_steps: int = 0, tempering_ess: float | None = None,
                 observability_constraint: float | None = None, linearization: str = "mean",
                 flattening_horizon: float = 0.0):
        if reference not in REFERENCES:
            raise ValueError(f"reference must be one of {REFERENCES}, got {reference!r}")
        if weighting not in WEIGHTINGS:
            raise ValueError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
        if metric not in METRICS:
            raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
        if linearization not in LINEARIZATIONS:
            raise ValueError(f"linearization must be one of {LINEARIZATIONS}, got {linearization!r}")
        if not (math.isfinite(flattening_horizon) and flattening_horizon >= 0.0):
            raise ValueError(f"flattening_horizon must be a finite time >= 0, got {flattening_horizon}")
        if metric == "cloud" and reference == "increment":
            raise ValueError("reference='increment' needs metric 'euclidean' or 'process_noise'")
        if regularization is None:
            regularization = DEFAULT_REGULARIZATION[metric]
        if not float(regularization) > 0.0:
            raise ValueError(f"regularization must be positive, got {regularization}")
        if tempering_ess is None:
            tempering_ess = TEMPERING_ESS if metric == "cloud" else 0.0
        elif tempering_ess and metric != "cloud":
            raise ValueError(f"tempering_ess needs metric 'cloud' (its kernel moves the particles between "
                             f"stages), got {tempering_ess} with metric {metric!r}")
        if kernel_bandwidth is not None and not 0.0 < float(kernel_bandwidth) < 1.0:
            raise ValueError(f"kernel_bandwidth must lie in (0, 1), got {kernel_bandwidth}")
        model = self._compensate(model, unmodelled_acceleration_std, unmodelled_acceleration_time, nominal_prior)
        if observability_constraint is None:
            observability_constraint = OBSERVABILITY_CONSTRAINT if metric == "cloud" else 0.0
        super().__init__(model, n_particles, resampling, ess_threshold, seed, collapse_steps, tempering_ess,
                         observability_constraint)
        self.reference = reference
        self.weighting = weighting
        self.metric = metric
        self.regularization = float(regularization)
        flattened = metric == "cloud" and linearization == "flattened"
        self.kernel_bandwidth = (default_bandwidth(self.n_particles, model.state_dim, flattened)
                                 if kernel_bandwidth is None else float(kernel_bandwidth))
        # the bandwidth while an update is in trouble (tempered, or beyond the gate): the wider kernel lets
        # the projection carry more of a large correction (a 3-sigma prior against gated ranges diverged
        # with the optimal one)
        self._troubled_bandwidth = (default_bandwidth(self.n_particles, model.state_dim)
                                    if kernel_bandwidth is None else self.kernel_bandwidth)
        self._previous_y: dict[str, np.ndarray] = {}
        self._input = None
        self._proposal = None
        self._moment_target = None
        self.moment_matching = bool(moment_matching)
        self.linearization = linearization
        self.flattening_horizon = float(flattening_horizon)
        self._flat = None
        self._init_gate(outlier_gate, outlier_gate_limit)  # (gating.py)

    def initialize(self, mean, cov, t0=0.0):
        super().initialize(mean, cov, t0)
        self._previous_y = {}
        # an update that recovered (re-initialised) before weighting left its proposal behind: the new
        # cloud is not the one it drew
        self._proposal = self._moment_target = self._flat = None

    # --- the proposal ---------------------------------------------------------------------------------
    def predict(self, dt, u=None):
        super().predict(dt, u)
        self._input = u

    def _sample(self, x_pred, y, rows, dt):
        """Cloud metric: each particle's innovation projected with the gain of the kernel-smoothed
        prediction, linearised once at the cloud's mean, and a draw of the resulting Gaussian proposal.

        In whitened coordinates (``x = centre + C w``, ``D = C C^T``; ``W R W^T = I``; ``G = W H C``;
        ``S = G G^T + eps I = L L^T``, ``B = L^-1 G``) the proposal ``q = N(centre + K r, (I - K H) D)``,
        ``K = C G^T S^-1 W``, is ``N(m, I - B^T B)`` with ``m = B^T L^-1 W r``. By Woodbury
        ``I - B^T B = (I + G^T G / eps)^-1 = U U^T`` with ``U = R^-T`` and ``R R^T = I + G^T G / eps``, a
        matrix at least the identity, so its Cholesky factor never fails: the draw is ``w = m + U z`` with ``n``
        standard normals ``z`` (in antithetic pairs, :func:`antithetic_normals`), and the exact weight's
        correction ``log N(x; centre, D) - log q(x) = (|z|^2 - |w|^2) / 2 + log det U``.
        """
        if self.metric != "cloud" or not rows.any():
            return super()._sample(x_pred, y, rows, dt)
        flat = self._flat  # the cloud is in flattened coordinates (:meth:`_begin_update`)
        troubled = self._fraction < 1.0 or any(streak.any() for streak in self._gate_streaks.values())
        h = self._troubled_bandwidth if troubled else self.kernel_bandwidth
        mean, centres, D = shrink(x_pred, *self._cloud_moments(), h)  # (x_pred is self._x)
        if dt > 0.0:
            D += self.model.process_noise(dt, self._pending_t)
        C = cholesky_or_none(D, symmetric=True) if np.isfinite(D).all() else None  # (its lower triangle)
        if C is None:  # a collapsed cloud on a noise-free model, or a runaway one: nothing to project with
            self._set_costate(None, rows, dt)
            return super()._sample(x_pred, y, rows, dt)
        n, eps = self.model.state_dim, self.regularization
        sensor = self._sensor
        if flat is None:
            H = sensor.jacobian(mean[None], self.time)[0]  # (m, n), at the cloud's mean
            r = sensor.residual(y, sensor.measure(centres.T, self.time))  # (N, m)
        else:  # the measurement is linear in the flattened coordinates
            H = flat.jacobian
            r = sensor.residual(y, flat.measured)[None] - (centres.T - flat.mean) @ H.T
        whitened = self._whitened(H, r, rows, C)
        if whitened is None:
            self._set_costate(None, rows, dt)
            return super()._sample(x_pred, y, rows, dt)
        G, wr, S, L_inv = whitened
        white_r = L_inv @ wr  # (k, N)
        # S^-1 W r / dt, outliers included (the division folded into the small factor)
        costate = (((L_inv.T / dt if dt > 0.0 else L_inv.T) @ white_r).T, rows, 1.0)
        # the gate judges the whole measurement against the prediction: the first draw only
        used = self._gate(wr @ self._weights, S, rows, sensor.name) if self._first_draw else rows
        if not used.any():  # every component refused: a prediction
            x, correction, _ = ParticleFilter._sample(self, x_pred, y, used, dt)
            self._set_costate(*costate)
            return x, correction, used
        self._set_costate(*costate)
        if used is not rows:  # outliers left out (a principal block of a sound S is sound)
            G, wr, S, L_inv = self._whitened(H, r, used, C)
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
        z = antithetic_normals(self.rng, n, self.n_particles)
        m = B.T @ white_r  # (n, N)
        w = U @ z
        w += m
        pair = np.empty((2 * n, self.n_particles))  # [proposal means; x]: weighed together after the update
        proposal_means = np.matmul(C, m, out=pair[:n])
        proposal_means += centres
        x = np.matmul(C, w, out=pair[n:])
        x += centres
        if self.moment_matching:
            spread = C @ U  # (I - K H) D = C U (C U)^T
            self._proposal = (pair, spread @ spread.T)
        if self.weighting == "likelihood":
            correction = 0.0
        else:
            # log N(x; centre, D) - log q(x) = (|z|^2 - |w|^2) / 2 + log det U (x - centre = C w, and
            # x - proposal mean = C U z)
            correction = np.einsum("kn,kn->n", z, z)
            correction -= np.einsum("kn,kn->n", w, w)
            correction *= 0.5
            correction -= sum(map(math.log, R.diagonal().tolist()))  # log det U
        return x, correction, used

    def _begin_update(self, rows):
        """``linearization="flattened"``: move the predicted cloud to the flattened coordinates
        (:mod:`gpf_nav.filters.flattening`), where the measured rows, now and of the state flowed half the
        ``flattening_horizon`` and the whole of it ahead, are exactly their linearisation at the cloud's
        mean: the update is then the update of a linear measurement, for which the kernel's straight-line
        draws, the one gain and the exact weights are right. A cloud whose curvature is negligible stays
        in the state's coordinates."""
        if self.metric != "cloud" or self.linearization != "flattened":
            return
        flattened = flattening(self._x, self._weights, rows, self._sensor, self.model, self.time, self._input,
                               self._flattening_lags, self.model.base_state_dim)
        if flattened is not None:
            self._flat, self._x = flattened

    @property
    def _flattening_lags(self) -> tuple[float, ...]:
        """The times ahead the flattened coordinates also make the measured rows linear at, s."""
        horizon = self.flattening_horizon
        return (0.5 * horizon, horizon) if horizon > 0.0 else ()

    def _end_update(self):
        """Map the cloud back from the flattened coordinates."""
        flat, self._flat = self._flat, None
        if flat is not None:
            x = flat.unflatten(self._x)
            if np.isfinite(x).all():
                self._x = np.ascontiguousarray(x)

    def _constraint_jacobian(self):
        flat = self._flat
        return None if flat is None else flat.jacobian[flat.rows]

    def _log_likelihood(self, x, y, rows):
        """In flattened coordinates, the likelihood of the measurement linearised at the cloud's mean (the
        particle's own measurement once mapped back)."""
        flat = self._flat
        if flat is None:
            return super()._log_likelihood(x, y, rows)
        e = self._sensor.residual(y, flat.measured)[:, None] - flat.jacobian @ (x - flat.mean[:, None])  # (m, N)
        w, constant = self._whitening(rows)
        e = e if rows.all() else e[rows]
        ew = e * w[:, None] if w.ndim == 1 else w @ e
        return constant - 0.5 * np.einsum("kn,kn->n", ew, ew)

    def _whitened(self, H: np.ndarray, r: np.ndarray, rows: np.ndarray, C: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """``(G = W H C (k, n), W r (k, N), S = G G^T + eps I (k, k), L^-1 (k, k))`` (``S = L L^T``) of the
        measured ``rows`` from the Jacobian ``H`` ``(m, n)`` and the innovations ``r`` ``(N, m)``.

        None when ``S`` is not sound to project with: ``S >= eps I`` in exact arithmetic, but when the
        prediction is beyond ~1e6 measurement sigmas, or a Jacobian overflowed, the identity is lost to
        rounding."""
        if not rows.all():
            H, r = H[rows], r[:, rows]
        W = self._whitener(rows)
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

    def _after_weighting(self, resampling):
        """Cloud metric: replace the sampling noise of the weighted mean and covariance by their exact
        values for the mixture of proposals ``sum_i w_i N(mu_i, Sigma)``. When the cloud is about to be
        resampled, :meth:`_on_resample` moves the resampled cloud instead: one map where two would land
        in the same place (:func:`match_moments`)."""
        if self._proposal is None:
            return
        pair, spread = self._proposal  # the proposal means and the particles (self._x is pair[n:])
        self._proposal = None
        n = spread.shape[0]
        mean, current_mean, cov, current = paired_moments(pair, self._weights, n)
        cov += spread
        if not np.isfinite(cov).all():  # (a non-finite mean makes the covariance non-finite)
            return  # a runaway proposal: leave the sampled cloud to the non-finite checks
        if resampling:
            self._moment_target = (self._x, mean, cov)
            return
        matched = map_moments(self._x, current_mean, current, mean, cov, symmetric=True)
        if matched is not None:
            self._x = matched

    def _on_resample(self, ancestors):
        """The resampled cloud gets the weighted moments of the mixture back; when it has too few
        distinct particles to be mapped, it is resampled from the mapped weighted cloud instead."""
        super()._on_resample(ancestors)
        if self._moment_target is None:
            return
        weighted, mean, cov = self._moment_target
        self._moment_target = None
        matched = match_moments(self._x, None, mean, cov, symmetric=True)  # equal weights after resampling
        if matched is None:
            matched = match_moments(weighted, self._weights, mean, cov, symmetric=True)
            matched = None if matched is None else matched[:, ancestors]
        if matched is not None:
            self._x = matched

    def _propose(self, x_pred, y, rows, dt, inverse_factor, z):
        if self.metric == "cloud":  # a fallback of the cloud proposal: the prior transition this time
            self._set_costate(None, rows, dt)
            return None, 0.0
        sensor = self._sensor
        if self.reference == "increment":
            previous_y = self._previous_y.get(sensor.name, np.full(sensor.dim, np.nan))
            rows = rows & np.isfinite(previous_y)
        if dt == 0.0 or not rows.any() or (self.weighting == "corrected" and inverse_factor is None):
            self._set_costate(None, rows, dt)
            return None, 0.0
        states = x_pred.T
        if self.reference == "innovation":
            H, r = self._innovation(states, y, rows)
        else:
            H = select_rows(sensor.jacobian(states, self.time), rows)
            eta = np.einsum("nkj,nj->nk", H, self.model.drift(states, self.time, self._input))
            r = sensor.residual(y, previous_y)[rows] - eta * dt
        metric_factor = self._noise_factors(dt)[0] if self.metric == "process_noise" else None
        shift, a = project(H, r, self._whitener(rows), self.regularization, metric_factor,
                           sensor.measured_state_index, sensor.orthogonal_jacobian_rows)
        self._set_costate(a, rows, dt)
        if self.weighting == "likelihood":
            return shift, 0.0
        return shift, gaussian_shift_correction(shift, inverse_factor, z)

    def _after_update(self, y, rows):
        if self.reference == "increment":  # the only reader of the previous measurement
            self._previous_y[self._sensor.name] = np.where(rows, y, np.nan)


def antithetic_normals(rng: np.random.Generator, rows: int, count: int) -> np.ndarray:
    """Standard normal draws ``(rows, count)`` in antithetic pairs: column ``i + ceil(count / 2)`` is minus
    column ``i``. Each column is still an exact standard normal draw (so each particle's draw is exactly
    from its own proposal and the exact weights stay exact); the pairs halve the draws, the costliest
    part of the cloud proposal at a few hundred particles, and make the unweighted mean of the noise
    zero (antithetic variates)."""
    half = (count + 1) // 2
    z = rng.standard_normal((rows, half))
    out = np.empty((rows, count))
    out[:, :half] = z
    np.negative(z[:, :count - half], out=out[:, half:])
    return out
