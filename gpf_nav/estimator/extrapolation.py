"""Extrapolation: the estimate published between measurements, the filter's mean and covariance carried
forward by the model's flow and its Jacobian, ``x' = f(x)``, ``P' = F P F^T + Q(dt)`` (an extended Kalman
prediction), from the filter's time to the node's. The filter itself is never moved: a measurement that
arrives after a prediction past its stamp (but newer than the last one) is still used. Over the gaps
between measurements the flow is nearly linear, so one Gaussian prediction serves every filter at the
cost of one state, where predicting a copy of a particle filter costs its whole cloud at every
``publish_rate`` tick. The prediction is kept from one tick to the next while the filter has not changed,
and carried only over the time since."""
from __future__ import annotations

import numpy as np

from gpf_nav.estimator.engine_config import EngineConfig
from gpf_nav.estimator.imu_hold import ImuHold
from gpf_nav.filters.interface import Filter


class Extrapolation:
    """The last extrapolated estimate (mean ``(n,)``, covariance ``(n, n)``), its stamp and model time, and
    the filter version it started from."""

    def __init__(self, config: EngineConfig):
        self.config = config
        self.drop()

    def drop(self) -> None:
        """Forget the extrapolation (the filter was restored or rebuilt, or a prediction failed)."""
        self._mean: np.ndarray | None = None
        self._cov: np.ndarray | None = None
        self._version = -1
        self._ns: int | None = None
        self._time = 0.0

    def estimate(self, flt: Filter, t_ns: int | None, version: int, now_ns: int, imu: ImuHold,
                 force: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
        """Predicted ``(mean (n,), cov (n, n))`` at ``now_ns`` of ``flt`` (at ``t_ns``, None: not
        initialised; ``version``: its state's), ``flt`` untouched, with the inputs ``imu`` holds.

        None when not initialised, ``now_ns`` is not after ``t_ns``, the horizon exceeds
        ``max_extrapolation`` (unless ``force``) or the prediction is not finite.
        """
        if t_ns is None or now_ns <= t_ns:
            return None
        if not force and (now_ns - t_ns) * 1e-9 > self.config.max_extrapolation:
            return None
        if self._mean is None or self._version != version or now_ns < self._ns:
            self._mean = np.array(flt.mean, dtype=float)
            self._cov = np.array(flt.covariance, dtype=float)
            self._version, self._ns, self._time = version, t_ns, float(flt.time)
        try:
            dt = (now_ns - self._ns) * 1e-9
            if dt > 0.0:
                self._predict(flt.model, dt, imu.input_at(now_ns))
                self._ns = now_ns
        except Exception:  # noqa: BLE001 - a failed prediction is just not published
            self.drop()
            return None
        if not (np.all(np.isfinite(self._mean)) and np.all(np.isfinite(self._cov))):
            self.drop()
            return None
        return self._mean.copy(), self._cov.copy()

    def _predict(self, model, dt: float, u: np.ndarray | None) -> None:
        """Carry the mean and covariance over ``dt`` s with the input ``u``."""
        x = self._mean[None]
        F = model.transition_jacobian(x, dt, self._time, u)[0]
        self._mean = np.asarray(model.transition(x, dt, self._time, u), dtype=float)[0]
        P = F @ self._cov @ F.T + model.process_noise(dt, self._time)
        self._cov = 0.5 * (P + P.T)
        self._time += dt
