"""Extended and unscented Kalman filters: Gaussian filters that run on any :class:`StateSpaceModel`.

Also holds the two pieces every Kalman-type filter of the package shares: the model-noise cache and the
innovation solve (gain and Gaussian log-likelihood).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dposv, dpotrf

from gpf_nav.filters.interface import Filter
from gpf_nav.filters.gating import OUTLIER_GATE_LIMIT, InnovationGated
from gpf_nav.linalg import positive_definite, psd_sqrt
from gpf_nav.models.state_space import StateSpaceModel

_LOG_2PI = math.log(2.0 * math.pi)


def innovation_solve(S: np.ndarray, B: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Solve with the innovation covariance and score the innovation.

    Args:
        S: innovation covariance ``(k, k)``, symmetric positive definite; only its lower triangle is read.
        B: right-hand sides ``(k, p)`` (``H P`` or ``Pxy^T``, giving the transposed gain).
        r: innovation ``(k,)``.

    Returns:
        ``(S^-1 B (k, p), S^-1 r (k,), log N(r; 0, S))``.

    Raises:
        numpy.linalg.LinAlgError: if ``S`` is not positive definite.
    """
    if S.shape[0] == 1:  # one measured row: a division
        s = float(S[0, 0])
        if not s > 0.0:
            raise np.linalg.LinAlgError(f"innovation variance is not positive ({s})")
        s_r = r / s
        return B / s, s_r, -0.5 * (float(r[0]) * float(s_r[0]) + math.log(s) + _LOG_2PI)
    # LAPACK dposv: Cholesky factor and solve in one call (numpy's cholesky + solve cost ~7x more here).
    L, sol, info = dposv(S, np.concatenate((B, r[:, None]), axis=1), lower=1, overwrite_b=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"innovation covariance is not positive definite (dposv info={info})")
    s_r = sol[:, -1]
    log_det = 2.0 * sum(map(math.log, L.diagonal().tolist()))
    log_lik = -0.5 * (float(r @ s_r) + log_det + r.shape[0] * _LOG_2PI)
    return sol[:, :-1], s_r, log_lik


class ModelNoise:
    """A model's ``Q(dt)`` and the measured-rows block of a sensor's ``R``, with square roots, computed
    once and cached.

    The block of ``R`` is recomputed when the set of measured rows changes or ``R`` does (another
    object with other values). ``Q`` is recomputed when ``dt`` changes, and when ``t`` changes if the
    model's ``process_noise`` takes ``t``.
    """

    def __init__(self, model: StateSpaceModel):
        self._model = model
        self._time_varying = model.time_varying_noise
        self._key: tuple[float, float] | None = None
        self._q = self._q_sqrt = None
        self._mask_key: bytes | None = None
        self._r_full = self._r = self._r_sqrt = None

    def process(self, dt: float, t: float) -> np.ndarray:
        """``Q`` ``(n, n)`` over ``[t, t + dt]``."""
        key = (dt, t if self._time_varying else 0.0)
        if key != self._key:
            self._q, self._q_sqrt, self._key = self._model.process_noise(dt, t), None, key
        return self._q

    def process_sqrt(self, dt: float, t: float) -> np.ndarray:
        """``L`` ``(n, n)`` with ``L L^T = Q`` over ``[t, t + dt]``."""
        q = self.process(dt, t)
        if self._q_sqrt is None:
            self._q_sqrt = psd_sqrt(q)
        return self._q_sqrt

    def measurement(self, mask: np.ndarray, r: np.ndarray) -> np.ndarray:
        """``R[mask][:, mask]`` ``(k, k)`` of a sensor's ``R`` ``(m, m)`` for the measured rows ``mask``
        ``(m,)`` bool."""
        key = mask.tobytes()
        if key != self._mask_key or (r is not self._r_full and not np.array_equal(r, self._r_full)):
            self._r_full = r
            self._r = r if mask.all() else r[np.ix_(mask, mask)]
            self._r_sqrt, self._mask_key = None, key
        return self._r

    def measurement_sqrt(self, mask: np.ndarray, r: np.ndarray) -> np.ndarray:
        """``L`` ``(k, k)`` with ``L L^T = R[mask][:, mask]``."""
        r = self.measurement(mask, r)
        if self._r_sqrt is None:
            self._r_sqrt = psd_sqrt(r)
        return self._r_sqrt


def symmetrised(P: np.ndarray) -> np.ndarray:
    """``(P + P^T) / 2`` ``(n, n)``."""
    S = P + P.T
    S *= 0.5
    return S


def readonly_view(a: np.ndarray) -> np.ndarray:
    """A non-writeable view of ``a``."""
    view = a.view()
    view.flags.writeable = False
    return view


class _GaussianFilter(Filter):
    """State ``N(x (n,), P (n, n))`` shared by the EKF and the UKF; :attr:`last_log_likelihood` is the
    Gaussian ``log N(r; 0, S)`` of the last update's innovation over the measured rows."""

    def __init__(self, model: StateSpaceModel, seed: int | np.random.Generator | None = None):
        super().__init__(model, seed)
        n = model.state_dim
        self._x = np.zeros(n)
        self._P = np.zeros((n, n))
        self._noise = ModelNoise(model)

    def initialize(self, mean: np.ndarray, cov: np.ndarray, t0: float = 0.0) -> None:
        self._x, self._P = self._check_prior(mean, cov, t0)
        self.last_log_likelihood = 0.0
        self._remember(self._x, self._P)
        self.initialized = True

    @property
    def mean(self) -> np.ndarray:
        return readonly_view(self._x)

    @property
    def covariance(self) -> np.ndarray:
        """Covariance ``(n, n)``, positive definite (:func:`~gpf_nav.linalg.positive_definite`)."""
        return readonly_view(positive_definite(self._P))

    def _state_token(self) -> tuple:
        """What the estimate is a function of: ``x`` and ``P``, replaced at every step, never written in
        place, so the same objects mean the same estimate."""
        return self._x, self._P


class ExtendedKF(InnovationGated, _GaussianFilter):
    """Extended Kalman filter: transition and measurement linearised about the current mean.

    The update uses the measured rows only, wraps angular residuals through ``model.residual`` and
    writes the covariance in Joseph form, symmetrised. The small products are ``ndarray.dot`` (less call
    overhead than ``@`` on ``n x n`` matrices: the EKF's step is a few dozen such calls).

    Args:
        model: the state-space model.
        seed: seed of the filter's random stream (the EKF itself draws nothing).
        outlier_gate: a measured component whose innovation is beyond this many standard deviations of
            ``S = H P H^T + R`` is not used (counted in :attr:`gated`), the GPF's gate
            (:mod:`gpf_nav.filters.gating`); 0 (default) disables it.
        outlier_gate_limit: consecutive refusals of a component after which it is used anyway.
    """

    def __init__(self, model: StateSpaceModel, seed: int | np.random.Generator | None = None,
                 outlier_gate: float = 0.0, outlier_gate_limit: int = OUTLIER_GATE_LIMIT):
        super().__init__(model, seed)
        self._eye = np.eye(model.state_dim)
        self._init_gate(outlier_gate, outlier_gate_limit)

    def predict(self, dt: float, u: np.ndarray | None = None) -> None:
        """``x <- f(x)``, ``P <- F P F^T + Q(dt)``; ``dt == 0`` leaves the estimate unchanged."""
        self._require_initialized()
        dt = self._check_dt(dt)
        if dt == 0.0:
            return
        x = self._x[None]
        self._observe_predict(dt, u)
        F = self.model.transition_jacobian(x, dt, self.time, u)[0]
        self._x = self.model.transition(x, dt, self.time, u)[0]
        P = F.dot(self._P).dot(F.T)
        P += self._noise.process(dt, self.time)
        self._P = symmetrised(P)
        self.time += dt
        self._guard(False, self._x, self._P)

    def update(self, y: np.ndarray, sensor=None) -> None:
        """Condition on ``y`` ``(m,)`` of ``sensor`` (None: the model's); NaN rows are not measured, an
        all-NaN ``y`` is a no-op."""
        sensor = self._sensor_for(sensor)
        measured = self._measured_rows(y, sensor)
        if measured is None:
            return
        y, mask, k = measured
        self._observe_update(y, sensor, mask, self._x)
        x = self._x[None]
        hx, H = sensor.measure_and_jacobian(x, self.time)
        r, H = sensor.residual(y, hx[0]), H[0]
        if k < mask.shape[0]:
            r, H = r[mask], H[mask]
        noise = sensor.noise(self.time)
        R = self._noise.measurement(mask, noise)
        P = self._P
        HP = H.dot(P)
        S = HP.dot(H.T)
        S += R
        used = self._gate(r, S, mask, sensor.name)
        if used is not mask:  # outliers left out
            if not used.any():
                self.last_log_likelihood = 0.0
                return
            keep = used[mask]
            r, H, HP, S, R = r[keep], H[keep], HP[keep], S[np.ix_(keep, keep)], self._noise.measurement(used, noise)
        try:
            Kt, _, self.last_log_likelihood = innovation_solve(S, HP, r)
        except np.linalg.LinAlgError:
            self._recover("innovation covariance not positive definite")
            return
        K = Kt.T
        self._x = self._x + K.dot(r)
        A = self._eye - K.dot(H)
        P = A.dot(P).dot(A.T)
        P += K.dot(R).dot(Kt)
        self._P = symmetrised(P)
        self._guard(True, self._x, self._P)


class UnscentedKF(_GaussianFilter):
    """Unscented Kalman filter with the standard scaled ``2n + 1`` sigma points.

    Sigma points ``x``, ``x +- gamma L_j`` with ``L L^T = P`` (Cholesky, or :func:`psd_sqrt`'s clipped
    eigen-square-root when ``P`` is singular), ``gamma^2 = n + lambda = alpha^2 (n + kappa)``; weights
    ``wm_0 = lambda / (n + lambda)``, ``wc_0 = wm_0 + 1 - alpha^2 + beta``, ``w_i = 1 / (2 (n + lambda))``.
    Points are redrawn from the predicted ``N(x, P)`` before each update, so on a linear-Gaussian model
    the filter is the exact Kalman filter.

    The unscented sums are evaluated in an algebraically identical form built on the deviations
    ``d_i = y_i - y_0`` from the central point: mean ``y_0 + delta`` with ``delta = sum_i wm_i d_i`` and
    covariance ``sum_{i>0} w_i d_i d_i^T + (beta - alpha^2) delta delta^T``. With a small ``alpha`` the
    central weights are of order ``-1/alpha^2`` and the textbook sums cancel catastrophically; this form
    never multiplies by them. The measurement mean is ``z_0 + model.measurement_mean(residual(z, z_0))``:
    a circular mean for angular components (rotation-equivariant, hence the same as the circular mean of
    the ``z_i``); the innovation covariance is taken about it (see :meth:`_spread`).

    Args:
        model: the state-space model.
        alpha: spread of the sigma points, ``alpha > 0``.
        beta: weight of the central point's covariance term (2 is optimal for Gaussian priors).
        kappa: secondary scaling, ``n + kappa > 0``.
        seed: seed of the filter's random stream (the UKF itself draws nothing).
    """

    def __init__(self, model: StateSpaceModel, alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0,
                 seed: int | np.random.Generator | None = None):
        super().__init__(model, seed)
        n = model.state_dim
        if not alpha > 0 or not n + kappa > 0:
            raise ValueError(f"need alpha > 0 and n + kappa > 0; got alpha={alpha}, kappa={kappa}, n={n}")
        spread = alpha ** 2 * (n + kappa)  # n + lambda
        self._gamma = math.sqrt(spread)
        self._w = 0.5 / spread
        self._wm = np.full(2 * n + 1, self._w)
        self._wm[0] = 1.0 - n / spread  # lambda / (n + lambda)
        self._c0 = beta - alpha ** 2  # wc_0 - wm_0 - 1: weight of delta delta^T in the covariance
        self._zero_row = np.zeros((1, n))

    def _sigma_offsets(self) -> np.ndarray:
        """Offsets ``(2n+1, n)`` of the sigma points from the mean: ``0``, ``+gamma L_j``, ``-gamma L_j``."""
        U, info = dpotrf(self._P)  # upper factor, P = U^T U: the rows of U are the columns L_j
        if info != 0:
            U = psd_sqrt(self._P).T
        U = self._gamma * U
        return np.concatenate((self._zero_row, U, -U))

    def _spread(self, d: np.ndarray, delta: np.ndarray, mu: np.ndarray | None = None) -> np.ndarray:
        """``sum_i wc_i (d_i - delta)(d_i - delta)^T`` ``(p, p)`` about the mean ``delta`` ``(p,)``.

        ``d`` ``(2n+1, p)`` are deviations from the central point (``d_0 = 0``). ``mu`` is their linear mean
        ``sum_i wm_i d_i`` when ``delta`` differs from it (a circular mean), which adds
        ``delta e^T + e delta^T`` with ``e = delta - mu``; omitted, ``delta`` is taken to be that mean.
        """
        col = delta[:, None]
        S = self._w * (d.T @ d) + self._c0 * (col * delta)
        if mu is not None:
            cross = col * (delta - mu)
            S += cross + cross.T
        return S

    def predict(self, dt: float, u: np.ndarray | None = None) -> None:
        """Push the sigma points through ``model.transition``, add ``Q(dt)``; ``dt == 0`` is a no-op."""
        self._require_initialized()
        dt = self._check_dt(dt)
        if dt == 0.0:
            return
        self._observe_predict(dt, u)
        Y = self.model.transition(self._x + self._sigma_offsets(), dt, self.time, u)
        D = Y - Y[0]
        delta = self._w * D.sum(axis=0)
        P = self._spread(D, delta) + self._noise.process(dt, self.time)
        self._x, self._P = Y[0] + delta, 0.5 * (P + P.T)
        self.time += dt
        self._guard(False, self._x, self._P)

    def update(self, y: np.ndarray, sensor=None) -> None:
        """Condition on ``y`` ``(m,)`` of ``sensor`` (None: the model's); NaN rows are not measured, an
        all-NaN ``y`` is a no-op."""
        sensor = self._sensor_for(sensor)
        measured = self._measured_rows(y, sensor)
        if measured is None:
            return
        y, mask, k = measured
        self._observe_update(y, sensor, mask, self._x)
        E = self._sigma_offsets()
        Z = sensor.measure(self._x + E, self.time)
        dZ = sensor.residual(Z, Z[0])
        delta = sensor.measurement_mean(dZ, self._wm)
        mu = self._w * dZ.sum(axis=0)
        r = sensor.residual(y, Z[0] + delta)
        if k < mask.shape[0]:
            dZ, delta, mu, r = dZ[:, mask], delta[mask], mu[mask], r[mask]
        S = self._spread(dZ, delta, mu) + self._noise.measurement(mask, sensor.noise(self.time))
        # Cross-covariance (transposed, (k, n)); the delta term vanishes because sum_i wc_i E_i = 0.
        C = self._w * (dZ.T @ E)
        try:
            Kt, s_r, self.last_log_likelihood = innovation_solve(S, C, r)
        except np.linalg.LinAlgError:
            self._recover("innovation covariance not positive definite")
            return
        self._x = self._x + s_r @ C
        P = self._P - C.T @ Kt
        self._P = 0.5 * (P + P.T)
        self._guard(True, self._x, self._P)
