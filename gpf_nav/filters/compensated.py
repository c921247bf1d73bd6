"""Filters that estimate an unmodelled acceleration beside the user's state (dynamic model compensation).

:class:`ModelErrorCompensated` is a mixin: the filter runs on ``ModelErrorCompensation(model)`` (see
:mod:`gpf_nav.models.compensation`) while :meth:`initialize`, :attr:`mean` and :attr:`covariance` keep
the user's state ``(n,)``; the estimated extra acceleration and the whole augmented (compensated)
posterior are properties of their own. :attr:`mean` and :attr:`covariance` are the model average of the
compensated posterior and of its nominal hypothesis, "no unmodelled acceleration"
(:mod:`gpf_nav.filters.model_averaging`), unless ``nominal_prior`` is 0. The GPF's default
configuration uses it, and :class:`CompensatedEKF` gives an EKF with the same compensation and the same
average (the fair baseline of the experiments).
"""
from __future__ import annotations

import numpy as np

from gpf_nav.filters.gating import OUTLIER_GATE_LIMIT
from gpf_nav.filters.interface import COMPENSATION, MODEL_PROBABILITIES
from gpf_nav.filters.kalman import ExtendedKF
from gpf_nav.filters.model_averaging import NOMINAL_PRIOR, mixture_moments, model_average
from gpf_nav.linalg import positive_definite
from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.models.compensation import ModelErrorCompensation
from gpf_nav.models.checks import validate_model

UNMODELLED_ACCELERATION_STD = 0.1
"""Default stationary standard deviation of the unmodelled acceleration (state units / s^2; m/s^2)."""
UNMODELLED_ACCELERATION_TIME = 1.0e6
"""Default correlation time of the unmodelled acceleration, s."""


class ModelErrorCompensated:
    """Mixin for a :class:`~gpf_nav.filters.interface.Filter` subclass (put it first in the bases)."""

    nominal_model: StateSpaceModel
    nominal_prior: float

    def _compensate(self, model: StateSpaceModel, acceleration_std: float, time_constant: float,
                    nominal_prior: float) -> StateSpaceModel:
        """The model the filter runs on: ``model`` augmented, or ``model`` itself when
        ``acceleration_std`` is 0. ``nominal_prior`` in [0, 1) is the prior probability of the nominal
        model in the estimate (0: the compensated posterior as it is)."""
        if not 0.0 <= float(nominal_prior) < 1.0:
            raise ValueError(f"nominal_prior must lie in [0, 1), got {nominal_prior}")
        self.nominal_model = model
        self.nominal_prior = float(nominal_prior)
        self._average_cache: tuple[tuple, tuple] | None = None
        if float(acceleration_std) == 0.0:
            return model
        return ModelErrorCompensation(model, time_constant, acceleration_std)

    @property
    def sensor_state_dim(self) -> int:
        """Sensors see the user's state (the unmodelled acceleration is the filter's own)."""
        return self.nominal_model.state_dim

    @property
    def compensated(self) -> bool:
        """True when the filter estimates an unmodelled acceleration."""
        return self.model is not self.nominal_model

    @property
    def capabilities(self) -> frozenset[str]:
        """The filter's, with :data:`~gpf_nav.filters.interface.COMPENSATION` when compensated and
        :data:`~gpf_nav.filters.interface.MODEL_PROBABILITIES` when the estimate is a model average."""
        extra = {COMPENSATION} if self.compensated else set()
        if self.compensated and self.nominal_prior > 0.0:
            extra.add(MODEL_PROBABILITIES)
        return super().capabilities | extra

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

    def _average(self) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(probability of the nominal model, mean (n,), covariance (n, n), acceleration (p,), its
        covariance (p, p))``, model-averaged; kept while the filter's state is the same objects
        (:meth:`_state_token`: a node reads the estimate, the acceleration and the probabilities of the same
        step, a multiple model its members' several times)."""
        token = self._state_token()
        cached = self._average_cache
        if cached is not None and all(a is b or (isinstance(a, float) and a == b) for a, b in zip(cached[0], token)):
            return cached[1]
        n = self.nominal_model.state_dim
        mean, cov = super().mean, super().covariance
        a, A = mean[n:], cov[n:, n:]
        if not self.compensated:
            average = (0.0, mean[:n], cov[:n, :n], a, A)
        else:
            probability, m, P = model_average(mean, cov, n, self.model.acceleration_std, self.nominal_prior)
            if not (np.isfinite(m).all() and np.isfinite(P).all()):  # the average overflowed (a runaway
                probability, m, P = 0.0, mean[:n], cov[:n, :n]      # estimate): the compensated posterior
            if probability > 0.0:  # the nominal model's acceleration is zero
                a, A = mixture_moments((probability, 1.0 - probability),
                                       [(np.zeros_like(a), np.zeros_like(A)), (a, A)])
            average = (probability, m, positive_definite(P), *self.model.world_acceleration(m, a, A))
        self._average_cache = (token, average)
        return average

    def _estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mean (n + p,), covariance)`` of the compensated posterior: a recovery re-initialises the whole
        state from it (:meth:`initialize` takes an augmented prior as it is)."""
        return super().mean, super().covariance

    @property
    def mean(self) -> np.ndarray:
        """Estimate of the user's state ``(n,)``: the model average (module docstring)."""
        return self._average()[1]

    @property
    def covariance(self) -> np.ndarray:
        """Its covariance ``(n, n)``."""
        return self._average()[2]

    @property
    def model_probabilities(self) -> np.ndarray | None:
        """``(2,)`` posterior probabilities of the nominal and the compensated model; None when the
        estimate is not a model average (no compensation, or ``nominal_prior`` 0)."""
        if not (self.compensated and self.nominal_prior > 0.0):
            return None
        nominal = self._average()[0]
        return np.array([nominal, 1.0 - nominal])

    @property
    def augmented_mean(self) -> np.ndarray:
        """Compensated posterior mean ``(n + p,)`` of the whole state (the user's state, then the
        unmodelled acceleration in the model's local frame when it declares one,
        :meth:`~gpf_nav.models.state_space.StateSpaceModel.compensation_frame`)."""
        return super().mean

    @property
    def augmented_covariance(self) -> np.ndarray:
        """Its covariance ``(n + p, n + p)``."""
        return super().covariance

    @property
    def unmodelled_acceleration(self) -> np.ndarray:
        """Estimated unmodelled acceleration ``(p,)`` on the state's own axes (the world's), model-averaged
        (the nominal model's is zero); empty without compensation."""
        return self._average()[3]

    @property
    def unmodelled_acceleration_covariance(self) -> np.ndarray:
        """Its covariance ``(p, p)``."""
        return self._average()[4]


class CompensatedEKF(ModelErrorCompensated, ExtendedKF):
    """EKF on the model augmented with the unmodelled acceleration (the GPF's compensation).

    Args:
        model: the state-space model.
        unmodelled_acceleration_std: stationary std of the unmodelled acceleration (0: plain EKF).
        unmodelled_acceleration_time: its correlation time, s.
        nominal_prior: prior probability of the nominal model in the estimate (0: the compensated
            posterior as it is).
        seed: seed of the filter's random stream.
        outlier_gate: innovation gate in standard deviations, the GPF's (:mod:`gpf_nav.filters.gating`);
            0 (default) disables it.
        outlier_gate_limit: consecutive refusals of a component after which it is used anyway.
    """

    def __init__(self, model: StateSpaceModel, unmodelled_acceleration_std: float = UNMODELLED_ACCELERATION_STD,
                 unmodelled_acceleration_time: float = UNMODELLED_ACCELERATION_TIME,
                 nominal_prior: float = NOMINAL_PRIOR, seed: int | np.random.Generator | None = None,
                 outlier_gate: float = 0.0, outlier_gate_limit: int = OUTLIER_GATE_LIMIT):
        super().__init__(self._compensate(model, unmodelled_acceleration_std, unmodelled_acceleration_time,
                                          nominal_prior), seed, outlier_gate, outlier_gate_limit)
