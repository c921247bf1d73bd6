"""The interface every filter shares: ``initialize``, ``predict``, ``update``, ``mean``, ``covariance``.

Measurements are vectors ``y`` of shape ``(m,)``; a non-finite component (NaN) means "not measured" and
the update uses only the measured rows. That is how partial observability reaches a filter.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from gpf_nav.models.base import StateSpaceModel


class Filter(ABC):
    """Base class of all filters: holds the model, the filter time and a seeded random generator.

    Args:
        model: the state-space model the filter runs on.
        seed: seed (or ``numpy.random.Generator``) of the filter's own random stream.
    """

    def __init__(self, model: StateSpaceModel, seed: int | np.random.Generator | None = None):
        self.model = model
        self.rng = np.random.default_rng(seed)
        self.time = 0.0
        self.initialized = False
        self.recoveries = 0
        self.last_recovery_reason: str | None = None
        self.recovery_inflation = 10.0
        self._last_good: tuple[np.ndarray, np.ndarray] | None = None

    @abstractmethod
    def initialize(self, mean: np.ndarray, cov: np.ndarray) -> None:
        """Start from the Gaussian prior ``N(mean (n,), cov (n, n))``."""

    @abstractmethod
    def predict(self, dt: float, u: np.ndarray | None = None) -> None:
        """Propagate the estimate over ``dt`` seconds with the known input ``u`` held constant."""

    @abstractmethod
    def update(self, y: np.ndarray) -> None:
        """Condition on measurement ``y`` ``(m,)``; NaN components are not measured."""

    @property
    @abstractmethod
    def mean(self) -> np.ndarray:
        """Posterior mean ``(n,)``."""

    @property
    @abstractmethod
    def covariance(self) -> np.ndarray:
        """Posterior covariance ``(n, n)``."""

    def _require_initialized(self) -> None:
        if not self.initialized:
            raise RuntimeError(f"{type(self).__name__}: call initialize() before predict() or update()")

    # --- recovery ----------------------------------------------------------------------------------------
    def _remember(self, mean: np.ndarray, cov: np.ndarray) -> None:
        """Keep ``(mean, cov)`` as the last good estimate, if it is finite."""
        if np.all(np.isfinite(mean)) and np.all(np.isfinite(cov)):
            self._last_good = (np.array(mean, dtype=float), np.array(cov, dtype=float))

    def _guard(self) -> None:
        """After a step of a Gaussian or ensemble filter: remember a healthy estimate, or recover
        from one that is non-finite or has a negative variance."""
        mean, cov = self.mean, self.covariance
        if np.all(np.isfinite(mean)) and np.all(np.isfinite(cov)) and np.all(np.diag(cov) >= 0.0):
            self._last_good = (np.array(mean), np.array(cov))
        else:
            self._recover("estimate became non-finite or its covariance indefinite")

    def _recover(self, reason: str) -> None:
        """Re-initialise from the last good estimate with its covariance times ``recovery_inflation``.

        Counted in :attr:`recoveries`; :attr:`last_recovery_reason` says why. Filter time is kept.
        """
        self.recoveries += 1
        self.last_recovery_reason = reason
        mean, cov = self._last_good
        time = self.time
        self.initialize(mean, self.recovery_inflation * cov)
        self.time = time

    # --- helpers shared by the filters ---------------------------------------------------------------
    def _check_prior(self, mean, cov) -> tuple[np.ndarray, np.ndarray]:
        n = self.model.state_dim
        mean = np.asarray(mean, dtype=float).reshape(-1)
        cov = np.asarray(cov, dtype=float)
        if mean.shape != (n,) or cov.shape != (n, n):
            raise ValueError(f"prior must be mean ({n},) and covariance ({n}, {n}); "
                             f"got {mean.shape} and {cov.shape}")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            raise ValueError("prior mean and covariance must be finite")
        return mean, 0.5 * (cov + cov.T)

    def _check_measurement(self, y) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(y (m,), measured rows (m,) bool)``; raise ValueError on a malformed shape."""
        y = np.asarray(y, dtype=float)
        if y.shape != (self.model.measurement_dim,):
            raise ValueError(f"measurement must have shape ({self.model.measurement_dim},), got {y.shape}")
        return y, np.isfinite(y)

    def _measured_rows(self, y) -> tuple[np.ndarray, np.ndarray] | None:
        """Start a Gaussian-type update: ``(y, mask)``, or None (and a zero ``last_log_likelihood``)
        when nothing is measured."""
        self._require_initialized()
        y, mask = self._check_measurement(y)
        if not mask.any():
            self.last_log_likelihood = 0.0
            return None
        return y, mask

    @staticmethod
    def _check_dt(dt) -> float:
        dt = float(dt)
        if not np.isfinite(dt) or dt < 0:
            raise ValueError(f"dt must be finite and non-negative, got {dt}")
        return dt
