"""The sequential Monte Carlo loop shared by the bootstrap PF and the GPF (the paper's Algorithm 1).

A particle filter here differs from another only in its *proposal* (:mod:`gpf_nav.filters.proposal`):
how it moves the predicted particles, and the log-weight correction that move needs. The loop (the
deterministic drift in ``predict``; the proposal, the weights, their normalisation, the ESS and the
resampling in ``update``) is written once, in :class:`ParticleFilter`; :meth:`ParticleFilter._assimilate`
holds Algorithm 1's steps in order.

Particles are stored as ``(n, N)`` so numpy works on long contiguous rows; models see the transposed
``(N, n)`` view, whose columns are then contiguous. Weighted sums over the particles are ``np.einsum``,
never a BLAS vector product, which a threaded BLAS can stall on a busy machine (:mod:`gpf_nav.blas`).

The process noise of the last predicted interval is drawn at the next ``update`` (``predict`` moves
the particles along the deterministic flow). This keeps the proposal a proper Gaussian density
``q(x_k | x_{k-1}, y_k) = N(flow(x_{k-1}) + shift, Q(dt))`` even when the node publishes predictions
between measurements. A ``predict`` that finds the noise of an earlier interval still pending draws it
first, so predict(dt1), predict(dt2), update(y) samples the same process as predict(dt1),
update(NaN), predict(dt2), update(y): ``x2 = flow2(flow1(x0) + w1) + w2``, not
``flow2(flow1(x0)) + w``, which differ for a nonlinear model. Until the next update, :attr:`covariance`
includes the pending ``Q``.
"""
from __future__ import annotations

import math

import numpy as np

from gpf_nav import resampling as resamplers
from gpf_nav.filters.constraint import constrain
from gpf_nav.filters.flattening import Flattening
from gpf_nav.filters.interface import CLOUD, COSTATE, N_PARTICLES, RESAMPLING, TEMPERING, Filter
from gpf_nav.filters.kernel import map_moments, weighted_moments
from gpf_nav.filters.likelihood import Whitening, log_likelihood
from gpf_nav.filters.normal_draws import NormalDraws
from gpf_nav.filters.proposal import PriorProposal, Proposal, Stage
from gpf_nav.filters.tempering_schedule import Tempering
from gpf_nav.kernels import cloud, log_weights
from gpf_nav.linalg import cholesky_or_none, positive_definite, psd_sqrt
from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.sensors.sensor import Sensor


STATE_LIMIT = 1e150
"""Particles with a component sum beyond this magnitude are treated as non-finite."""
_REMEMBER_EVERY = 10
"""Updates between two snapshots of the last good estimate (a weighted covariance costs O(N n^2))."""


class ParticleFilter(Filter):
    """SMC loop with a pluggable proposal (the prior transition by default).

    Args:
        model: the state-space model.
        n_particles: number of particles N.
        resampling: ``systematic`` (default), ``stratified``, ``residual`` or ``multinomial``.
        ess_threshold: tau in (0, 1]; resample when ESS < tau N.
        seed: seed of the filter's random generator.
        collapse_steps: re-initialise (see :meth:`Filter._recover`) after this many consecutive
            updates with an ESS below 1.5 particles; 0 (default) never does.
        tempering_ess: likelihood tempering (progressive correction): a draw whose ESS/N would fall
            below this is refused, and the update is split into stages, each weighting by a fraction of
            the log-likelihood, ``p(y | x)^f``, with a resampling and a new proposal from the cloud
            between them (:mod:`gpf_nav.filters.tempering_schedule`); 0 (default) updates in one stage.
        observability_constraint: an update keeps the prediction's conditional along the directions
            about which the data carried less information than this fraction of the prior's
            (:mod:`gpf_nav.filters.constraint`, :mod:`gpf_nav.integrity.observability`); 0 (default) does not.
        proposal: the proposal (:mod:`gpf_nav.filters.proposal`); None: the prior transition.

    Attributes:
        proposal: the proposal.
        tempering_stages: stages of the last update (1 when it was not split).
        tempered_updates: updates split into more than one stage so far.
    """

    def __init__(self, model: StateSpaceModel, n_particles: int = N_PARTICLES, resampling: str = "systematic",
                 ess_threshold: float = 0.5, seed: int | np.random.Generator | None = None,
                 collapse_steps: int = 0, tempering_ess: float = 0.0,
                 observability_constraint: float = 0.0, proposal: Proposal | None = None):
        super().__init__(model, seed)
        self.proposal = PriorProposal() if proposal is None else proposal
        if not 0.0 <= float(observability_constraint) < 1.0:
            raise ValueError(f"observability_constraint must lie in [0, 1), got {observability_constraint}")
        self.observability_constraint = float(observability_constraint)
        if not 0.0 <= float(tempering_ess) < 1.0:
            raise ValueError(f"tempering_ess must lie in [0, 1), got {tempering_ess}")
        self.tempering_ess = float(tempering_ess)
        self.tempering_stages = 1
        self.tempered_updates = 0
        if int(collapse_steps) < 0:
            raise ValueError(f"collapse_steps must be non-negative, got {collapse_steps}")
        self.collapse_steps = int(collapse_steps)
        self._collapsed_for = 0
        self._updates = 0
        if int(n_particles) < 1:
            raise ValueError(f"n_particles must be positive, got {n_particles}")
        if not 0.0 < float(ess_threshold) <= 1.0:
            raise ValueError(f"ess_threshold must lie in (0, 1], got {ess_threshold}")
        self.n_particles = int(n_particles)
        self.ess_threshold = float(ess_threshold)
        self.resampling = resampling
        self._resample = resamplers.get(resampling)
        self.normal_draws = NormalDraws(self.rng)
        n = model.state_dim
        self._x = np.zeros((n, self.n_particles))
        # the uniform log-weights and weights, copied at every resampling (a new array each time: weights
        # handed out stay as they were)
        self._uniform = (np.full(self.n_particles, -np.log(self.n_particles)),
                         np.full(self.n_particles, 1.0 / self.n_particles))
        self._logw, self._weights = self._uniform[0].copy(), self._uniform[1].copy()
        self._moments = None
        self._pending_dt = 0.0
        self._pending_t = 0.0
        self._input = None
        self._sensor = self._own_sensor
        self._whiteners = Whitening(np.asarray(model.measurement_noise(), dtype=float))
        self._time_varying_noise = model.time_varying_noise
        self._noise_cache: tuple[tuple[float, float] | None, np.ndarray | None, np.ndarray | None] = \
            (None, None, None)
        self.ess = 1.0
        self.resampled = False
        self.resample_count = 0
        self._costate = np.zeros((self.n_particles, model.measurement_dim))
        self._costate_rows = np.zeros(model.measurement_dim, bool)

    # --- state ---------------------------------------------------------------------------------------
    def initialize(self, mean, cov, t0=0.0):
        mean, cov = self._check_prior(mean, cov, t0)
        z = self.normal_draws(mean.size, self.n_particles)
        self._x = np.ascontiguousarray(mean[:, None] + psd_sqrt(cov) @ z)
        self._set_uniform_weights()
        self._pending_dt = 0.0
        self._collapsed_for = 0
        self._remember(mean, cov)
        self.initialized = True
        self.proposal.reset()

    @property
    def capabilities(self) -> frozenset[str]:
        """A particle cloud with weights and resampling, a co-state and tempering."""
        return frozenset({CLOUD, RESAMPLING, COSTATE, TEMPERING})

    @property
    def particles(self) -> np.ndarray:
        """Particles ``(N, n)`` (a read-only view; the deterministic part while noise is pending)."""
        view = self._x.T
        view.flags.writeable = False
        return view

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights ``(N,)``."""
        return self._weights

    @property
    def mean(self):
        return self._cloud_mean().copy()

    @property
    def covariance(self):
        """Weighted covariance ``(n, n)`` of the cloud (plus the pending ``Q``), positive definite: a
        degenerate cloud gets the floor of :func:`~gpf_nav.linalg.positive_definite`."""
        cov = self._cloud_moments()[1]
        if self._pending_dt > 0.0:
            cov = cov + self.model.process_noise(self._pending_dt, self._pending_t)
        return positive_definite(cov)

    def set_moments(self, mean: np.ndarray, cov: np.ndarray) -> None:
        """Move the cloud by an affine map so that its weighted mean and covariance are ``mean`` ``(n,)``
        and ``cov`` ``(n, n)``, keeping its shape (the hand-over of an interacting multiple model). Noise
        still pending from a ``predict`` is added on top; nothing changes when either covariance is
        singular."""
        self._require_initialized()
        matched = map_moments(self._x, *self._cloud_moments(), np.asarray(mean, dtype=float),
                              np.asarray(cov, dtype=float))
        if matched is not None:
            self._x = matched

    @property
    def normalized_ess(self) -> float:
        """ESS / N in (0, 1] after the last update (before any resampling)."""
        return self.ess

    @property
    def costate(self) -> np.ndarray:
        """Per-particle geometric co-state ``(N, m)`` of the last update,
        ``(H_w H_w^T + eps I)^-1 W r / dt`` with ``H_w = W H``: for the Euclidean metric its unit is a
        squared state unit per second (m^2/s on the lunar model), for the process-noise metric 1/s.
        Zero for components not measured (or not computed): see :attr:`costate_measured`."""
        return self._costate

    @property
    def costate_measured(self) -> np.ndarray:
        """Components ``(m,)`` bool that the last co-state was computed for (the others are 0)."""
        return self._costate_rows

    @property
    def costate_mean(self) -> np.ndarray:
        """Weighted mean co-state ``(m,)``."""
        return np.einsum("n,nk->k", self._weights, self._costate)

    @property
    def costate_norm_mean(self) -> float:
        """Weighted mean of the per-particle co-state norms."""
        norms = np.sqrt(np.einsum("ij,ij->i", self._costate, self._costate))
        return float(np.einsum("n,n->", self._weights, norms))

    @property
    def costate_norm_max(self) -> float:
        """Largest per-particle co-state norm."""
        return float(np.sqrt(np.einsum("ij,ij->i", self._costate, self._costate).max()))

    # --- the loop ------------------------------------------------------------------------------------
    def predict(self, dt, u=None):
        self._require_initialized()
        dt = self._check_dt(dt)
        self._input = u
        if dt == 0.0:
            return
        if self._pending_dt > 0.0:
            factor = self._noise_factors(self._pending_dt)[0]
            # a new array, so views handed out as `particles` keep their state
            self._x = self._x + factor @ self.normal_draws(*self._x.shape)
        self._observe_predict(dt, u)
        self._x = np.ascontiguousarray(self.model.transition(self._x.T, dt, self.time, u).T)
        self._pending_dt, self._pending_t = dt, self.time
        self.time += dt
        self._discard_non_finite()

    def update(self, y, sensor=None):
        """Move and weight the cloud by ``y`` of ``sensor`` (:meth:`_assimilate`).

        A proposal may run the whole update in coordinates of its own (:meth:`Proposal.flatten
        <gpf_nav.filters.proposal.Proposal.flatten>`): the cloud is mapped back after it. With
        ``observability_constraint`` the updated cloud then keeps the prediction along the directions the
        data have not determined (:mod:`gpf_nav.filters.constraint`)."""
        self._require_initialized()
        sensor = self._use(sensor)
        y, rows = self._check_measurement(y, sensor)
        flat = prior = basis = None
        if rows.any():
            self._observe_update(y, sensor, rows, self._cloud_mean())
            flat = self.proposal.flatten(self, rows)
            if self.observability_constraint:
                basis = self._observability.basis(self.observability_constraint)
                prior = self._predicted_moments() if basis.shape[1] else None
        recoveries = self.recoveries
        try:
            evidence, rows = self._assimilate(y, rows, flat)
            if evidence is not None and prior is not None:
                jacobian = None if flat is None else flat.jacobian[flat.rows]
                constrained = constrain(self._x, basis, prior, self._cloud_moments(), jacobian)
                if constrained is not None:
                    self._x = constrained
        finally:
            if flat is not None and self.recoveries == recoveries:  # (a recovered cloud is not flattened)
                x = flat.unflatten(self._x)
                if np.isfinite(x).all():
                    self._x = np.ascontiguousarray(x)
        if evidence is None:  # the filter re-initialised itself
            return
        self.tempered_updates += self.tempering_stages > 1
        self.last_log_likelihood = evidence
        self.proposal.observed(sensor.name, y, rows)
        self._check_collapse()
        self._updates += 1
        if self._updates % _REMEMBER_EVERY == 0:
            self._remember(*self._estimate())

    def _assimilate(self, y: np.ndarray, rows: np.ndarray, flat: Flattening | None
                    ) -> tuple[float | None, np.ndarray]:
        """Algorithm 1 for the predicted cloud ``x^-`` (the drift, :meth:`predict`) and the measurement
        ``y`` ``(m,)`` of ``rows`` ``(m,)``, in order: the proposal's move (the Jacobian ``H``, the
        projection onto the measurement-consistent subspace, the co-state ``lambda``, the process noise),
        the log-weights, their normalisation (log-sum-exp), the ESS, and the resampling below ``tau N``.
        ``flat``: the update's flattened coordinates, or None. Returns ``(log-evidence, the rows used)``,
        the evidence None when the filter had to re-initialise.

        With ``tempering_ess`` the likelihood comes in stages (:mod:`gpf_nav.filters.tempering_schedule`):
        a draw that would leave too few effective particles is refused and drawn again with less of it. The
        innovation gate and the co-state are those of the first draw (the whole likelihood, from the
        predicted cloud); the evidence is the sum of the stages'."""
        schedule = Tempering(self.tempering_ess)
        evidence, self.tempering_stages = 0.0, 0
        while True:
            first = schedule.draws == 0
            # the proposal: Jacobian, projection, co-state and process noise
            stage = Stage(self._x, y, rows, self._pending_dt, schedule.fraction, first, flat)
            move = self.proposal.draw(self, stage)
            if first:
                self._keep_costate(move.costate, move.costate_rows)
            rows = move.rows
            # the weights: log w += f log p(y | x) + log p(x | x^-) - log q(x | x^-, y)
            increment = move.log_correction
            if rows.any():
                increment = increment + self._log_likelihood(move.particles, y, rows, schedule.fraction, flat)
            if schedule.refuses(self._logw, increment, rows):
                continue  # the cloud stays as it was
            self._x = move.particles
            self._pending_dt = 0.0
            self.tempering_stages += 1
            if not self._discard_non_finite():
                return None, rows
            # normalised by their log-sum-exp, the stage's log-evidence
            self.resampled = False
            total = self._normalise(self._logw + increment)
            if total is None:
                self._recover("every particle weight is zero or NaN")
                return None, rows
            self.last_log_likelihood = total  # (the previous log-weights are normalised)
            # the effective sample size
            self.ess = resamplers.effective_sample_size(self._weights) / self.n_particles
            resampling = self.ess < self.ess_threshold
            # the weighted cloud gets the exact moments of the proposals it was drawn from (cloud proposal)
            moments = None if move.mixture is None else move.mixture.moments(self._weights)
            if moments is not None and not resampling:
                self._x = moments.match(self._x)
            # resampling below tau N
            if resampling:
                weighted, ancestors = self._x, self._resample(self._weights, self.rng)
                self._x = np.take(weighted, ancestors, axis=1)  # (a C-contiguous copy, faster than [:, ancestors])
                if self._costate_rows.any():  # (else the co-state is zero)
                    self._costate = self._costate[ancestors]
                if moments is not None:
                    self._x = moments.match_resampled(self._x, weighted, self._weights, ancestors)
                self._set_uniform_weights()
                self.resampled = True
                self.resample_count += 1
            evidence += self.last_log_likelihood
            if schedule.accepted(rows):
                return evidence, rows

    def _predicted_moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(n,)`` and covariance ``(n, n)`` of the predicted cloud, pending process noise included."""
        mean, cov = self._cloud_moments()
        if self._pending_dt > 0.0:
            cov = cov + self.model.process_noise(self._pending_dt, self._pending_t)
        return mean, cov

    def _cloud_mean(self) -> np.ndarray:
        """Weighted mean ``(n,)`` of the cloud, in the filter's own state (:attr:`mean` may report the
        user's part of it only): the kept one, or a pass over the cloud that does not form the covariance
        (a filter that never reads the covariance does not pay for it), the same number either way."""
        kept = self._moments
        if kept is not None and kept[0] is self._x and kept[1] is self._weights:
            return kept[2]
        return cloud.weighted_mean(self._x, self._weights)  # the kept one's arithmetic

    def _cloud_moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean ``(n,)`` and covariance ``(n, n)`` of the cloud, pending noise not included (read
        only), kept until the particles or the weights change: both arrays are replaced, never written
        in place (but by :meth:`_discard_non_finite`, which forgets the moments)."""
        kept = self._moments
        if kept is None or kept[0] is not self._x or kept[1] is not self._weights:
            mean, cov = weighted_moments(self._x, self._weights)
            mean.flags.writeable = cov.flags.writeable = False
            kept = self._moments = (self._x, self._weights, mean, cov)
        return kept[2], kept[3]

    def _state_token(self) -> tuple:
        """What the estimate is a function of: the particles, the weights and the pending interval. The
        arrays are replaced, never written in place, so the same objects mean the same estimate."""
        return self._x, self._weights, self._pending_dt, self._pending_t

    def _use(self, sensor: Sensor | None) -> Sensor:
        """Make ``sensor`` (None: the model's own) the one this update measures with, and read its noise
        ``R``: the one place an update reads it (the whitening factors are cached until ``R`` changes)."""
        sensor = self._sensor = self._sensor_for(sensor)
        self._whiteners.use(sensor.noise(self.time))
        return sensor

    def _estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mean, covariance)`` of the estimate, as :meth:`_remember` keeps it (one call where a
        subclass derives both from the same work)."""
        return self.mean, self.covariance

    def _discard_non_finite(self) -> bool:
        """Give non-finite particles zero weight (and a finite placeholder state); recover when none
        is left. A particle beyond ``STATE_LIMIT`` counts as non-finite: its covariance would overflow.
        Returns False when the filter had to re-initialise."""
        # a column sum is NaN or beyond the limit iff a component is (about); counted in one compiled pass
        # (the check runs twice a step), the rare bad cloud then mended by numpy
        if not cloud.count_outside(self._x, STATE_LIMIT):
            return True
        bad = ~(np.abs(self._x.sum(axis=0)) < STATE_LIMIT)
        if bad.all():
            self._recover("every particle became non-finite")
            return False
        x = self._x.copy()  # (a new array: the state is never written in place, :meth:`_state_token`)
        x[:, bad] = x[:, np.flatnonzero(~bad)[0]][:, None]
        self._x = x
        self._moments = None
        logw = self._logw.copy()
        logw[bad] = -np.inf
        if self._normalise(logw) is None:
            self._recover("every particle with weight became non-finite")
            return False
        return True

    def _normalise(self, logw: np.ndarray) -> float | None:
        """Set the weights from unnormalised log-weights ``(N,)`` (NaN counts as zero weight) and
        return their log-sum-exp; None, changing nothing, when every weight is zero or NaN
        (:func:`gpf_nav.kernels.log_weights.normalise`: new arrays, so weights handed out stay as they were)."""
        normalised, weights = np.empty(logw.size), np.empty(logw.size)
        total = log_weights.normalise(np.ascontiguousarray(logw, dtype=float), normalised, weights)
        if math.isnan(total):
            return None
        self._logw, self._weights = normalised, weights
        return total

    def _check_collapse(self) -> None:
        if not self.collapse_steps:
            return
        self._collapsed_for = self._collapsed_for + 1 if self.ess * self.n_particles < 1.5 else 0
        if self._collapsed_for >= self.collapse_steps:
            self._recover(f"ESS below 1.5 particles for {self.collapse_steps} updates")

    def _noise_factors(self, dt: float) -> tuple[np.ndarray, np.ndarray | None]:
        """``(L, L^-1)`` with ``L L^T = Q`` over the pending interval ``[t, t + dt]`` (``t`` its start);
        ``L^-1`` is None when ``Q`` is not positive definite.

        Cached for the last ``dt`` (measurements usually arrive at a fixed rate), and the last ``t`` when
        the model's ``process_noise`` takes ``t``."""
        key = (dt, self._pending_t if self._time_varying_noise else 0.0)
        if self._noise_cache[0] != key:
            q = self.model.process_noise(dt, self._pending_t)
            chol = cholesky_or_none(q)
            if chol is None:
                self._noise_cache = (key, psd_sqrt(q), None)
            else:
                self._noise_cache = (key, chol, np.linalg.inv(chol))
        return self._noise_cache[1], self._noise_cache[2]

    def _keep_costate(self, costate: np.ndarray | None, rows: np.ndarray) -> None:
        """Keep the co-state ``costate`` ``(N, k)`` of the measured ``rows`` ``(m,)``, zero for the other
        components; None clears it (no new array when it is already clear). The co-state is kept for the
        model's own measurement only (the integrity monitor tests it); another sensor clears it."""
        m = self.model.measurement_dim
        if costate is None or self._sensor is not self._own_sensor:
            if self._costate_rows.any():
                self._costate = np.zeros((self.n_particles, m))
                self._costate_rows = np.zeros(m, bool)
            return
        if not rows.all():
            costate, measured = np.zeros((self.n_particles, m)), costate
            costate[:, rows] = measured
        self._costate, self._costate_rows = costate, rows

    def _whitening(self, rows: np.ndarray, fraction: float = 1.0) -> tuple[np.ndarray, float]:
        """``(W, log of the Gaussian normalising constant)`` of the measured ``rows`` ``(m,)`` for the
        likelihood ``p(y | x)^fraction`` of the sensor in use
        (:class:`~gpf_nav.filters.likelihood.Whitening`)."""
        return self._whiteners.of(rows, fraction)

    def _log_likelihood(self, x: np.ndarray, y: np.ndarray, rows: np.ndarray, fraction: float,
                        flat: Flattening | None) -> np.ndarray:
        """Gaussian ``f log p(y_rows | x)`` ``(N,)`` of the particles ``x`` ``(n, N)``, ``f`` the ``fraction``;
        in flattened coordinates ``flat``, of the measurement linearised at the cloud's mean (the
        particle's own measurement once mapped back)."""
        if flat is None:
            e = self._sensor.measurement_residual(y, x.T, self.time).T  # (m, N)
        else:
            e = flat.residual(y, x)
        return log_likelihood(e, rows, self._whitening(rows, fraction))

    def _set_uniform_weights(self) -> None:
        self._logw, self._weights = self._uniform[0].copy(), self._uniform[1].copy()


class BootstrapPF(ParticleFilter):
    """Bootstrap particle filter (the paper's SPF): the prior transition is the proposal.

    Args:
        compute_costate: also compute, as a diagnostic only, the co-state the geometric projection
            would apply to the predicted particles (innovation reference); it costs a projection.
        regularization: relative Tikhonov ``eps`` of that diagnostic projection.
        observability_constraint: see :class:`ParticleFilter` (0, the default, is the paper's SPF; the
            node's ``spf`` sets it: resampling alone narrows a direction no measurement sees).
        Other arguments as :class:`ParticleFilter`.
    """

    def __init__(self, model: StateSpaceModel, n_particles: int = N_PARTICLES, resampling: str = "systematic",
                 ess_threshold: float = 0.5, seed: int | np.random.Generator | None = None,
                 compute_costate: bool = False, regularization: float = 1e-6, collapse_steps: int = 0,
                 observability_constraint: float = 0.0):
        self.compute_costate = bool(compute_costate)
        self.regularization = float(regularization)
        super().__init__(model, n_particles, resampling, ess_threshold, seed, collapse_steps,
                         observability_constraint=observability_constraint,
                         proposal=PriorProposal(self.regularization if self.compute_costate else None))

    @property
    def capabilities(self) -> frozenset[str]:
        """:class:`ParticleFilter`'s, without the co-state unless ``compute_costate``."""
        return super().capabilities - (set() if self.compute_costate else {COSTATE})


__all__ = ["ParticleFilter", "BootstrapPF"]
