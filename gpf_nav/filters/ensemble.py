"""Stochastic ensemble Kalman filter (perturbed observations) on any :class:`StateSpaceModel`."""
from __future__ import annotations

import numpy as np

from gpf_nav.filters.interface import CLOUD, N_PARTICLES, Filter
from gpf_nav.filters.kalman import ModelNoise, innovation_solve, readonly_view
from gpf_nav.filters.normal_draws import NormalDraws
from gpf_nav.linalg import positive_definite, psd_sqrt
from gpf_nav.models.state_space import StateSpaceModel


class EnsembleKF(Filter):
    """Stochastic EnKF: members ``X`` ``(N, n)`` moved by a gain built from ensemble anomalies.

    Predict: one batched ``model.transition`` of all members plus ``N(0, Q(dt))`` samples. Update on
    the measured rows: predicted-measurement anomalies are ``model.residual(h(X), h_mean)`` with
    ``h_mean = model.measurement_mean`` (angles wrapped about their circular mean), the gain solves
    ``Pyy K^T = Pxy^T`` and each member is moved by its own perturbed innovation
    ``residual(y, h(x_i)) + e_i``, ``e_i ~ N(0, R)`` drawn from ``self.rng``
    (:class:`~gpf_nav.filters.normal_draws.NormalDraws`).

    Args:
        model: the state-space model.
        n_particles: ensemble size ``N >= 2``.
        seed: seed (or generator) of the filter's random stream; same seed, same output.

    :attr:`last_log_likelihood` is ``log N(r; 0, Pyy)`` of the ensemble-mean innovation ``r`` over the
    measured rows at the last update.
    """

    def __init__(self, model: StateSpaceModel, n_particles: int = N_PARTICLES,
                 seed: int | np.random.Generator | None = None):
        if int(n_particles) < 2:
            raise ValueError(f"n_particles must be at least 2, got {n_particles}")
        super().__init__(model, seed)
        self.n_particles = int(n_particles)
        self._X = np.zeros((self.n_particles, model.state_dim))
        self._weights = np.full(self.n_particles, 1.0 / self.n_particles)
        self._noise = ModelNoise(model)
        self.normal_draws = NormalDraws(self.rng)

    def initialize(self, mean: np.ndarray, cov: np.ndarray, t0: float = 0.0) -> None:
        """Draw the ``N`` members from ``N(mean (n,), cov (n, n))``."""
        mean, cov = self._check_prior(mean, cov, t0)
        z = self.normal_draws(*self._X.shape)
        self._X = mean + z @ psd_sqrt(cov).T
        self.last_log_likelihood = 0.0
        self._remember(mean, cov)
        self.initialized = True

    def predict(self, dt: float, u: np.ndarray | None = None) -> None:
        """Move every member through ``model.transition`` and add process noise; ``dt == 0`` is a no-op."""
        self._require_initialized()
        dt = self._check_dt(dt)
        if dt == 0.0:
            return
        self._observe_predict(dt, u)
        X = self.model.transition(self._X, dt, self.time, u)
        self._X = X + self.normal_draws(*X.shape) @ self._noise.process_sqrt(dt, self.time).T
        self.time += dt
        self._guard(False, self.mean, self.covariance)

    def update(self, y: np.ndarray, sensor=None) -> None:
        """Condition on ``y`` ``(m,)`` of ``sensor`` (None: the model's); NaN rows are not measured, an
        all-NaN ``y`` is a no-op."""
        sensor = self._sensor_for(sensor)
        measured = self._measured_rows(y, sensor)
        if measured is None:
            return
        y, mask, k = measured
        self._observe_update(y, sensor, mask, self.mean)
        X = self._X
        HX = sensor.measure(X, self.time)
        h_mean = sensor.measurement_mean(HX, self._weights)
        # One residual call gives the anomalies Ay (N, m) of the predicted measurements and, in its last
        # row, the ensemble-mean innovation r (m,).
        deviations = sensor.residual(np.vstack((HX, y)), h_mean)
        Ay, r = deviations[:-1], deviations[-1]
        innovations = sensor.residual(y, HX)  # (N, m)
        if k < mask.shape[0]:
            Ay, innovations, r = Ay[:, mask], innovations[:, mask], r[mask]
        Ax = X - np.einsum("n,ni->i", self._weights, X)
        scale = 1.0 / (self.n_particles - 1)
        R = sensor.noise(self.time)
        Pyy = (Ay.T @ Ay) * scale + self._noise.measurement(mask, R)
        Pxy_t = (Ay.T @ Ax) * scale  # (k, n)
        try:
            Kt, _, self.last_log_likelihood = innovation_solve(Pyy, Pxy_t, r)
        except np.linalg.LinAlgError:
            self._recover("innovation covariance not positive definite")
            return
        innovations += self.normal_draws(*innovations.shape) @ self._noise.measurement_sqrt(mask, R).T
        self._X = X + innovations @ Kt
        self._guard(True, self.mean, self.covariance)

    @property
    def capabilities(self) -> frozenset[str]:
        """An ensemble of equally weighted members."""
        return frozenset({CLOUD})

    @property
    def particles(self) -> np.ndarray:
        """Ensemble members ``(N, n)``, read-only view."""
        return readonly_view(self._X)

    @property
    def mean(self) -> np.ndarray:
        """Ensemble mean ``(n,)``."""
        return readonly_view(np.einsum("n,ni->i", self._weights, self._X))

    @property
    def covariance(self) -> np.ndarray:
        """Unbiased ensemble covariance ``(n, n)``, positive definite (a degenerate ensemble gets the floor
        of :func:`~gpf_nav.linalg.positive_definite`)."""
        A = self._X - np.einsum("n,ni->i", self._weights, self._X)
        P = (A.T @ A) / (self.n_particles - 1)
        return readonly_view(positive_definite(P))
