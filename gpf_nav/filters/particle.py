"""The sequential Monte Carlo loop shared by the bootstrap PF and the GPF.

A particle filter here differs from another only in its *proposal*: the shift it applies to the
predicted particles before the process noise is added, and the log-weight correction that shift needs.
The loop (deterministic drift in ``predict``, proposal + noise + weighting in ``update``, ESS check and
resampling) is written once, in :class:`ParticleFilter`.

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
from gpf_nav.filters.interface import CLOUD, COSTATE, RESAMPLING, TEMPERING, Filter
from gpf_nav.filters.kernel import map_moments, weighted_moments
from gpf_nav.kernels import cloud
from gpf_nav.filters.projection import project
from gpf_nav.linalg import cholesky_or_none, positive_definite, psd_sqrt
from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.sensors.sensor import Sensor


STATE_LIMIT = 1e150
"""Particles with a component sum beyond this magnitude are treated as non-finite."""
_REMEMBER_EVERY = 10
"""Updates between two snapshots of the last good estimate (a weighted covariance costs O(N n^2))."""
TEMPERING_FACTOR = 4.0
"""Tempering: a refused draw retries with this many times less of the likelihood; after an accepted
stage the next takes up to this many times more."""
TEMPERING_DRAWS = 32
"""Tempering: most draws of one update (the last is accepted whatever its ESS)."""


class ParticleFilter(Filter):
    """SMC loop with a pluggable proposal (the bootstrap proposal by default).

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
            between them (:meth:`update`); 0 (default) updates in one stage.
        observability_constraint: an update keeps the prediction's conditional along the directions
            about which the data carried less information than this fraction of the prior's
            (:meth:`_constrain`, :mod:`gpf_nav.integrity.observability`); 0 (default) does not.

    Attributes:
        tempering_stages: stages of the last update (1 when it was not split).
        tempered_updates: updates split into more than one stage so far.
    """

    def __init__(self, model: StateSpaceModel, n_particles: int = 500, resampling: str = "systematic",
                 ess_threshold: float = 0.5, seed: int | np.random.Generator | None = None,
                 collapse_steps: int = 0, tempering_ess: float = 0.0,
                 observability_constraint: float = 0.0):
        super().__init__(model, seed)
        if not 0.0 <= float(observability_constraint) < 1.0:
            raise ValueError(f"observability_constraint must lie in [0, 1), got {observability_constraint}")
        self.observability_constraint = float(observability_constraint)
        if not 0.0 <= float(tempering_ess) < 1.0:
            raise ValueError(f"tempering_ess must lie in [0, 1), got {tempering_ess}")
        self.tempering_ess = float(tempering_ess)
        self.tempering_stages = 1
        self.tempered_updates = 0
        self._fraction = 1.0
        self._first_draw = True
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
        n = model.state_dim
        self._x = np.zeros((n, self.n_particles))
        self._logw = np.full(self.n_particles, -np.log(self.n_particles))
        self._weights = np.full(self.n_particles, 1.0 / self.n_particles)
        self._moments = None
        self._pending_dt = 0.0
        self._pending_t = 0.0
        self._sensor = self._own_sensor
        self._R = np.asarray(model.measurement_noise(), dtype=float)
        self._whiteners: dict[bytes, tuple[np.ndarray, float]] = {}
        self._time_varying_noise = model.time_varying_noise
        self._noise_cache: tuple[tuple[float, float] | None, np.ndarray | None, np.ndarray | None] = \
            (None, None, None)
        self.ess = 1.0
        self.resampled = False
        self.resample_count = 0
        self.log_likelihood = 0.0
        self._costate = np.zeros((self.n_particles, model.measurement_dim))
        self._costate_rows = np.zeros(model.measurement_dim, bool)

    # --- state ---------------------------------------------------------------------------------------
    def initialize(self, mean, cov, t0=0.0):
        mean, cov = self._check_prior(mean, cov, t0)
        z = self.rng.standard_normal((mean.size, self.n_particles))
        self._x = np.ascontiguousarray(mean[:, None] + psd_sqrt(cov) @ z)
        self._set_uniform_weights()
        self._pending_dt = 0.0
        self._collapsed_for = 0
        self._remember(mean, cov)
        self.initialized = True

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
        if dt == 0.0:
            return
        if self._pending_dt > 0.0:
            factor = self._noise_factors(self._pending_dt)[0]
            # a new array, so views handed out as `particles` keep their state
            self._x = self._x + factor @ self.rng.standard_normal(self._x.shape)
        self._observe_predict(dt, u)
        self._x = np.ascontiguousarray(self.model.transition(self._x.T, dt, self.time, u).T)
        self._pending_dt, self._pending_t = dt, self.time
        self.time += dt
        self._discard_non_finite()

    def update(self, y, sensor=None):
        """Weight (and move, for a proposal that does) the cloud by ``y`` of ``sensor``.

        With ``tempering_ess`` > 0 the likelihood is brought in by stages: a draw weighted by
        ``p(y | x)^f`` whose ESS/N would fall below ``tempering_ess`` is refused and drawn again with
        ``f / TEMPERING_FACTOR``; an accepted stage is weighted (and resampled below ``tau N``), and the
        next, drawn from the new cloud with no process noise, takes up to ``TEMPERING_FACTOR`` times
        more, until the fractions sum to 1. The innovation gate and the co-state are those of the first
        draw (the whole likelihood, from the predicted cloud); :attr:`log_likelihood` is the sum of the
        stages' evidences."""
        self._require_initialized()
        sensor = self._use(sensor)
        y, rows = self._check_measurement(y, sensor)
        prior, basis = None, None
        if rows.any():
            self._observe_update(y, sensor, rows, self._cloud_mean())
            self._begin_update(rows)
            if self.observability_constraint:
                basis = self._observability.basis(self.observability_constraint)
                prior = self._predicted_moments() if basis.shape[1] else None
        try:
            evidence, rows = self._tempered_stages(y, rows)
            if evidence is not None and prior is not None:
                self._constrain(basis, *prior)
        finally:
            self._fraction = 1.0
            self._end_update()
        if evidence is None:  # the filter re-initialised itself
            return
        self.tempered_updates += self.tempering_stages > 1
        self.log_likelihood = evidence
        self._after_update(y, rows)
        self._check_collapse()
        self._updates += 1
        if self._updates % _REMEMBER_EVERY == 0:
            self._remember(*self._estimate())

    def _tempered_stages(self, y: np.ndarray, rows: np.ndarray) -> tuple[float | None, np.ndarray]:
        """The stages of :meth:`update`: ``(sum of the stages' log-evidences, the rows used)``, with
        ``None`` for the evidence when the filter had to re-initialise."""
        remaining, fraction, evidence = 1.0, 1.0, 0.0
        self._first_draw, draws, self.tempering_stages = True, 0, 0
        while True:
            self._fraction = fraction
            x, log_correction, rows = self._sample(self._x, y, rows, self._pending_dt)
            self._first_draw = False
            draws += 1
            increment = log_correction
            if rows.any():
                increment = increment + self._log_likelihood(x, y, rows)
            if (self.tempering_ess and draws < TEMPERING_DRAWS and rows.any()
                    and _ess(self._logw + increment) < self.tempering_ess):
                fraction /= TEMPERING_FACTOR  # refused: the cloud stays as it was
                continue
            self._x = x
            self._pending_dt = 0.0
            self.tempering_stages += 1
            if not self._discard_non_finite():
                return None, rows
            if not self._reweight(increment):
                self._recover("every particle weight is zero or NaN")
                return None, rows
            evidence += self.log_likelihood
            remaining -= fraction
            if remaining <= 0.0 or not rows.any():
                return evidence, rows
            fraction = min(remaining, TEMPERING_FACTOR * fraction)
            if remaining - fraction < 1e-12:  # (rounding: the last stage takes what is left)
                fraction = remaining

    def _begin_update(self, rows: np.ndarray) -> None:
        """Hook run once an update has measured ``rows``, before the constraint's prior moments are read
        and the first draw (the GPF moves the cloud to its flattened coordinates here)."""

    def _end_update(self) -> None:
        """Hook run after the stages and the constraint, also when they failed (the GPF maps the cloud
        back from its flattened coordinates)."""

    def _constraint_jacobian(self) -> np.ndarray | None:
        """Jacobian ``(k, n)`` of the measured rows whose row space :meth:`_constrain` leaves to the update
        (None: the tracker's directions as they are)."""
        return None

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

    def _constrain(self, basis: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> None:
        """Observability-constrained update: keep the prediction ``N(mean (n,), cov (n, n))`` along the
        undetermined directions ``basis`` ``(n, d)`` (:mod:`gpf_nav.integrity.observability`).

        With ``s = V^T x`` the determined coordinates (``V`` spans the complement of the undetermined
        subspace ``U``), a likelihood that depends on ``s`` alone leaves the prediction's conditional
        ``p(x | s)`` unchanged: the posterior is ``p(s | y) p(x | s)``. Its moments are the update's for
        ``s`` and the prediction's regression for the rest,
        ``m = m^- + B (V^T m^+ - V^T m^-)``, ``P = P^- - B V^T P^- + B (V^T P^+ V) B^T``,
        ``B = P^- V (V^T P^- V)^-1``, and the cloud is moved to them by an affine map. The particle
        update is exact only in the limit; along an undetermined direction of a curved problem its
        approximations (a Gaussian kernel, one linearisation for the whole cloud) manufacture information
        there is none of, which this removes. Computed in units of the prediction's standard deviations.
        When :meth:`_constraint_jacobian` gives the update's measurement Jacobian (the GPF's flattened
        update), each undetermined direction loses its part that this measurement moves: the tracker's
        directions come from a reference that may be tens of kilometres from the cloud, and a direction
        tilted towards the measured one would give the measured coordinate the prediction's spread."""
        n = cov.shape[0]
        scale = np.sqrt(np.maximum(cov.diagonal(), 1e-300))
        P_prior = cov / np.outer(scale, scale)
        m_prior = mean / scale
        posterior = self._cloud_moments()
        m_post, P_post = posterior[0] / scale, posterior[1] / np.outer(scale, scale)
        J = self._constraint_jacobian()
        if J is not None and basis.shape[1]:
            # a direction the measurement moves is not undetermined in this update: keep its part that the
            # measurement does not see (in the scaled coordinates the map works in)
            scaled = basis / scale[:, None]
            scaled = scaled / np.linalg.norm(scaled, axis=0)
            Hs = J * scale
            try:
                scaled = scaled - np.linalg.solve(Hs @ Hs.T, Hs).T @ (Hs @ scaled)
            except np.linalg.LinAlgError:
                return
            keep = np.linalg.norm(scaled, axis=0) > 0.5
            basis = scaled[:, keep] * scale[:, None]
            if not basis.shape[1]:
                return
        if basis.shape[1] >= n:
            m, P = m_prior, P_prior
        else:
            q, _ = np.linalg.qr(np.column_stack([basis / scale[:, None], np.eye(n)]))
            V = q[:, basis.shape[1]:]  # (n, n - d) the determined coordinates
            PV = P_prior @ V
            try:
                B = np.linalg.solve(V.T @ PV, PV.T).T
            except np.linalg.LinAlgError:
                return
            m = m_prior + B @ (V.T @ (m_post - m_prior))
            P = P_prior - B @ PV.T + B @ (V.T @ P_post @ V) @ B.T
        P = 0.5 * (P + P.T) * np.outer(scale, scale)
        if np.isfinite(P).all() and np.isfinite(m).all():
            moved = map_moments(self._x, *posterior, m * scale, P, symmetric=True)
            if moved is not None:
                self._x = moved

    def _use(self, sensor: Sensor | None) -> Sensor:
        """Make ``sensor`` (None: the model's own) the one this update measures with, and read its noise
        ``R``: the one place an update reads it (the whitening factors are cached until ``R`` changes)."""
        sensor = self._sensor = self._sensor_for(sensor)
        R = sensor.noise(self.time)
        if R is not self._R and not np.array_equal(R, self._R):
            self._whiteners = {}
        self._R = R
        return sensor

    def _estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mean, covariance)`` of the estimate, as :meth:`_remember` keeps it (one call where a
        subclass derives both from the same work)."""
        return self.mean, self.covariance

    def _discard_non_finite(self) -> bool:
        """Give non-finite particles zero weight (and a finite placeholder state); recover when none
        is left. A particle beyond ``STATE_LIMIT`` counts as non-finite: its covariance would overflow.
        Returns False when the filter had to re-initialise."""
        column_sums = np.abs(self._x.sum(axis=0))  # NaN or beyond the limit iff a component is (about)
        if (column_sums < STATE_LIMIT).all():
            return True
        bad = ~(column_sums < STATE_LIMIT)
        if bad.all():
            self._recover("every particle became non-finite")
            return False
        self._x[:, bad] = self._x[:, np.flatnonzero(~bad)[0]][:, None]
        self._moments = None
        logw = self._logw.copy()
        logw[bad] = -np.inf
        if self._normalise(logw) is None:
            self._recover("every particle with weight became non-finite")
            return False
        return True

    def _normalise(self, logw: np.ndarray) -> float | None:
        """Set the weights from unnormalised log-weights ``(N,)`` (NaN counts as zero weight) and
        return their log-sum-exp; None, changing nothing, when every weight is zero or NaN."""
        logw[np.isnan(logw)] = -np.inf
        peak = logw.max()
        if not -np.inf < peak < np.inf:
            return None
        total = peak + np.log(np.exp(logw - peak).sum())
        self._logw = logw - total
        self._weights = np.exp(self._logw)
        return float(total)

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

    def _sample(self, x_pred: np.ndarray, y: np.ndarray, rows: np.ndarray, dt: float
                ) -> tuple[np.ndarray, np.ndarray | float, np.ndarray]:
        """Draw the new particles ``(n, N)`` from the proposal and return them with the log-weight
        correction ``log p(x | x_prev) - log q(x | x_prev, y)`` (``(N,)`` or 0.0) and the measured rows
        the update uses (``rows`` less any the proposal refused as outliers).

        ``x_pred`` ``(n, N)`` is the deterministic flow over the pending ``dt``. This default draws the
        process noise ``L z`` and adds the shift of :meth:`_propose`; the result is a new array, so
        views handed out as :attr:`particles` keep the predicted state.
        """
        factor = inverse_factor = z = None
        if dt > 0.0:
            factor, inverse_factor = self._noise_factors(dt)
            z = self.rng.standard_normal((self.model.state_dim, self.n_particles))
        shift, log_correction = self._propose(x_pred, y, rows, dt, inverse_factor, z)
        if z is None:
            x = x_pred.copy()
        else:
            x = factor @ z
            x += x_pred
        if shift is not None:
            x += shift
        return x, log_correction, rows

    def _propose(self, x_pred, y, rows, dt, inverse_factor, z):
        """Proposal hook: ``(shift (n, N) or None, log-weight correction (N,) or 0.0)``.

        ``x_pred`` are the predicted particles ``(n, N)``, ``inverse_factor`` the inverse Cholesky
        factor ``L^-1`` of ``Q(dt)`` (None when ``Q`` is not positive definite) and ``z`` ``(n, N)`` the
        standard normal draws of the process noise ``L z`` (None when ``dt == 0``).
        The bootstrap proposal moves nothing.
        """
        return None, 0.0

    def _set_costate(self, a: np.ndarray | None, rows: np.ndarray, dt: float) -> None:
        """Keep the co-state ``a / dt`` of the measured ``rows`` (``a`` ``(N, k)``), zero for the other
        components; ``a = None`` clears it (no new array when it is already clear). The co-state is kept
        for the model's own measurement only (the integrity monitor tests it); another sensor clears it.
        Only the first draw of an update sets it (a tempered update's later stages do not)."""
        if not self._first_draw:  # a later tempering draw: the first draw's co-state stands
            return
        m = self.model.measurement_dim
        if a is None or self._sensor is not self._own_sensor:
            if self._costate_rows.any():
                self._costate = np.zeros((self.n_particles, m))
                self._costate_rows = np.zeros(m, bool)
            return
        if rows.all():
            costate = a if dt == 1.0 else a / dt  # (a is the caller's new array)
        else:
            costate = np.zeros((self.n_particles, m))
            costate[:, rows] = a / dt
        self._costate, self._costate_rows = costate, rows

    def _after_update(self, y, rows) -> None:
        """Hook run after weighting and resampling (the GPF keeps its measurement history here)."""

    def _innovation(self, states: np.ndarray, y: np.ndarray, rows: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Jacobian ``(N, k, n)`` and innovation ``y - h(x)`` ``(N, k)`` of the measured rows."""
        h, H = self._sensor.measure_and_jacobian(states, self.time)
        return select_rows(H, rows), select_columns(self._sensor.residual(y, h), rows)

    # --- weighting -----------------------------------------------------------------------------------
    def _whitener(self, rows: np.ndarray) -> np.ndarray:
        """``W`` with ``W R_rows W^T = I`` for the measured rows: ``(k, k)``, or its diagonal ``(k,)``
        when ``R_rows`` is diagonal (what :func:`project` and the likelihood take)."""
        return self._whitening(rows)[0]

    def _whitening(self, rows: np.ndarray) -> tuple[np.ndarray, float]:
        """``(W, log of the Gaussian normalising constant)`` of the measured rows for the likelihood of
        this tempering stage, ``p(y | x)^f``: ``sqrt(f) W`` and ``f`` times the constant (the whitening
        of the noise ``R / f``, normalised as the power of the density)."""
        w, constant = self._whitening_of(rows)
        f = self._fraction
        if f == 1.0:
            return w, constant
        return math.sqrt(f) * w, f * constant

    def _whitening_of(self, rows: np.ndarray) -> tuple[np.ndarray, float]:
        """``(W, log of the Gaussian normalising constant)`` of the measured rows, cached per mask."""
        key = rows.tobytes()
        if key not in self._whiteners:
            r = self._R[np.ix_(rows, rows)]
            w = np.linalg.inv(np.linalg.cholesky(r))
            constant = np.log(np.diag(w)).sum() - 0.5 * rows.sum() * np.log(2.0 * np.pi)
            if np.count_nonzero(w) == np.count_nonzero(np.diag(w)):
                w = np.diag(w).copy()
            self._whiteners[key] = (w, float(constant))
        return self._whiteners[key]

    def _log_likelihood(self, x: np.ndarray, y: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Gaussian ``log p(y_rows | x)`` ``(N,)`` for particles ``x`` ``(n, N)``."""
        e = self._sensor.residual(y, self._sensor.measure(x.T, self.time)).T  # (m, N)
        w, constant = self._whitening(rows)
        e = e if rows.all() else e[rows]
        ew = e * w[:, None] if w.ndim == 1 else w @ e  # (k, N)
        return constant - 0.5 * np.einsum("kn,kn->n", ew, ew)

    def _reweight(self, increment) -> bool:
        """Add the log-weight increment ``(N,)``, normalise, resample below ``tau N``.

        Returns False (and changes nothing) when every new weight is zero or NaN."""
        self.resampled = False
        total = self._normalise(self._logw + increment)
        if total is None:
            return False
        self.log_likelihood = total  # previous log-weights are normalised
        self.ess = resamplers.effective_sample_size(self._weights) / self.n_particles
        resampling = self.ess < self.ess_threshold
        self._after_weighting(resampling)
        if resampling:
            ancestors = self._resample(self._weights, self.rng)
            self._x = np.ascontiguousarray(self._x[:, ancestors])
            self._on_resample(ancestors)
            self._set_uniform_weights()
            self.resampled = True
            self.resample_count += 1
        return True

    def _after_weighting(self, resampling: bool) -> None:
        """Hook run once the new weights are set, before any resampling (``resampling`` says whether
        the cloud is about to be resampled)."""

    def _on_resample(self, ancestors: np.ndarray) -> None:
        """Per-particle quantities follow their ancestors."""
        self._costate = self._costate[ancestors]

    def _set_uniform_weights(self) -> None:
        self._logw = np.full(self.n_particles, -np.log(self.n_particles))
        self._weights = np.full(self.n_particles, 1.0 / self.n_particles)


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

    def __init__(self, model: StateSpaceModel, n_particles: int = 500, resampling: str = "systematic",
                 ess_threshold: float = 0.5, seed: int | np.random.Generator | None = None,
                 compute_costate: bool = False, regularization: float = 1e-6, collapse_steps: int = 0,
                 observability_constraint: float = 0.0):
        super().__init__(model, n_particles, resampling, ess_threshold, seed, collapse_steps,
                         observability_constraint=observability_constraint)
        self.compute_costate = bool(compute_costate)
        self.regularization = float(regularization)

    @property
    def capabilities(self) -> frozenset[str]:
        """:class:`ParticleFilter`'s, without the co-state unless ``compute_costate``."""
        return super().capabilities - (set() if self.compute_costate else {COSTATE})

    def _propose(self, x_pred, y, rows, dt, inverse_factor, z):
        a = None
        if self.compute_costate and dt > 0.0 and rows.any():
            H, r = self._innovation(x_pred.T, y, rows)
            a = project(H, r, self._whitener(rows), self.regularization,
                        columns=self._sensor.measured_state_index,
                        orthogonal_rows=self._sensor.orthogonal_jacobian_rows)[1]
        self._set_costate(a, rows, dt)
        return None, 0.0


def _ess(logw: np.ndarray) -> float:
    """ESS / N of the unnormalised log-weights ``(N,)`` (NaN counts as zero weight; 0 when all are)."""
    logw = np.where(np.isnan(logw), -np.inf, logw)
    peak = logw.max()
    if not -np.inf < peak < np.inf:
        return 0.0
    w = np.exp(logw - peak)
    return resamplers.effective_sample_size(w / w.sum()) / logw.size


def select_rows(H: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``H[:, rows, :]`` of a Jacobian ``(N, m, n)`` without a copy when every row is kept; the
    selection runs on the particle-last layout the models build, so it copies contiguous rows."""
    if rows.all():
        return H
    return H.transpose(1, 2, 0)[rows].transpose(2, 0, 1)


def select_columns(r: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``r[:, rows]`` of ``(N, m)`` without a copy when every component is kept."""
    return r if rows.all() else r.T[rows].T


def gaussian_shift_correction(shift: np.ndarray, inverse_factor: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``log p(x|x_prev) - log q(x|x_prev, y)`` for ``q`` the prior transition shifted by ``shift``.

    With ``x = flow + shift + L z`` and ``Q = L L^T``: ``-(L^-1 shift) . z - |L^-1 shift|^2 / 2``.
    ``shift`` and ``z`` are ``(n, N)``, ``inverse_factor`` is ``L^-1`` ``(n, n)``; returns ``(N,)``.
    """
    s = inverse_factor @ shift
    return -np.einsum("ij,ij->j", s, z) - 0.5 * np.einsum("ij,ij->j", s, s)


__all__ = ["ParticleFilter", "BootstrapPF", "gaussian_shift_correction"]
