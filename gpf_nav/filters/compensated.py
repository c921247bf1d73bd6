"""Filters that estimate an unmodelled acceleration beside the user's state (dynamic model compensation).

:class:`ModelErrorCompensated` is a mixin: the filter runs on ``ModelErrorCompensation(model)`` (see
:mod:`gpf_nav.models.compensation`) while :meth:`initialize`, :attr:`mean` and :attr:`covariance` keep
the user's state ``(n,)``; the estimated extra acceleration and the whole augmented estimate are
properties of their own. The GPF's default configuration uses it, and :class:`CompensatedEKF` gives an
EKF with the same compensation (the fair baseline of the experiments).
"""
from __future__ import annotations

import numpy as np

from gpf_nav.filters.kalman import ExtendedKF
from gpf_nav.models.base import StateSpaceModel
from gpf_nav.models.compensation import ModelErrorCompensation
from gpf_nav.models.validation import validate_model

UNMODELLED_ACCELERATION_STD = 0.1
"""Default stationary standard deviation of the unmodelled acceleration (state units / s^2; m/s^2)."""
UNMODELLED_ACCELERATION_TIME = 1.0e6
"""Default correlation time of the unmodelled acceleration, s."""


class ModelErrorCompensated:
    """Mixin for a :class:`~gpf_nav.filters.base.Filter` subclass (put it first in the bases)."""

    nominal_model: StateSpaceModel

    def _compensate(self, model: StateSpaceModel, acceleration_std: float,
                    time_constant: float) -> StateSpaceModel:
        """The model the filter runs on: ``model`` augmented, or ``model`` itself when
        ``acceleration_std`` is 0."""
        self.nominal_model = model
        if float(acceleration_std) == 0.0:
            return model
        return ModelErrorCompensation(model, time_constant, acceleration_std)

    @property
    def compensated(self) -> bool:
        """True when the filter estimates an unmodelled acceleration."""
        return self.model is not self.nominal_model

    def initialize(self, mean, cov, t0=0.0):
        """Start from the user's prior ``N(mean (n,), cov (n, n))`` at filter time ``t0``, the unmodelled
        acceleration from ``N(0, sigma^2 I)``; an augmented prior ``(n + p,)`` is taken as it is. The
        first time, the user's own model is validated on the user's prior, so errors name it."""
        mean = np.asarray(mean, dtype=float).reshape(-1)
        if self.compensated and mean.shape == (self.nominal_model.state_dim,):
            if not self._model_checked:
                validate_model(self.nominal_model, mean, np.asarray(cov, dtype=float), t0)
            mean, cov = self.model.augment_prior(mean, np.asarray(cov, dtype=float))
        super().initialize(mean, cov, t0)

    @property
    def mean(self) -> np.ndarray:
        return super().mean[:self.nominal_model.state_dim]

    @property
    def covariance(self) -> np.ndarray:
        n = self.nominal_model.state_dim
        return super().covariance[:n, :n]

    @property
    def augmented_mean(self) -> np.ndarray:
        """Mean ``(n + p,)`` of the whole state (the user's state, then the unmodelled acceleration)."""
        return super().mean

    @property
    def augmented_covariance(self) -> np.ndarray:
        """Covariance ``(n + p, n + p)`` of the whole state."""
        return super().covariance

    @property
    def unmodelled_acceleration(self) -> np.ndarray:
        """Estimated unmodelled acceleration ``(p,)`` (empty without compensation)."""
        return self.augmented_mean[self.nominal_model.state_dim:]

    @property
    def unmodelled_acceleration_covariance(self) -> np.ndarray:
        """Its covariance ``(p, p)``."""
        n = self.nominal_model.state_dim
        return self.augmented_covariance[n:, n:]


class CompensatedEKF(ModelErrorCompensated, ExtendedKF):
    """EKF on the model augmented with the unmodelled acceleration (the GPF's compensation).

    Args:
        model: the state-space model.
        unmodelled_acceleration_std: stationary std of the unmodelled acceleration (0: plain EKF).
        unmodelled_acceleration_time: its correlation time, s.
        seed: seed of the filter's random stream.
    """

    def __init__(self, model: StateSpaceModel, unmodelled_acceleration_std: float = UNMODELLED_ACCELERATION_STD,
                 unmodelled_acceleration_time: float = UNMODELLED_ACCELERATION_TIME,
                 seed: int | np.random.Generator | None = None):
        super().__init__(self._compensate(model, unmodelled_acceleration_std, unmodelled_acceleration_time),
                         seed)
