"""Extrapolation: the estimate published between measurements, predicted on a copy of the filter (the
shadow), so that it never moves the filter's own time: a measurement that arrives after a prediction
past its stamp (but newer than the last one) is still used. The shadow is kept from one prediction to the
next while the filter has not changed, and predicts only the time since."""
from __future__ import annotations

import copy

import numpy as np

from gpf_nav.estimator.engine_config import EngineConfig
from gpf_nav.estimator.imu_hold import ImuHold
from gpf_nav.filters.interface import Filter


class Extrapolation:
    """The shadow: a copy of the filter, at its own time, and the filter version it was copied from."""

    def __init__(self, config: EngineConfig):
        self.config = config
        self.drop()

    def drop(self) -> None:
        """Forget the shadow (the filter was restored or rebuilt, or the shadow failed)."""
        self._shadow: Filter | None = None
        self._version = -1
        self._ns: int | None = None

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
        if self._shadow is None or self._version != version or now_ns < self._ns:
            self._shadow = copy.deepcopy(flt)
            self._version = version
            self._ns = t_ns
        try:
            dt = (now_ns - self._ns) * 1e-9
            if dt > 0.0:
                self._shadow.predict(dt, imu.input_at(now_ns))
                self._ns = now_ns
            mean = np.array(self._shadow.mean, dtype=float)
            cov = np.array(self._shadow.covariance, dtype=float)
        except Exception:  # noqa: BLE001 - a failed prediction is just not published
            self.drop()
            return None
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            self.drop()
            return None
        return mean, cov
