"""Any filter of the package with sensor-bias states estimated beside the user's state.

:class:`SensorBiasFilter` builds the filter on :class:`~gpf_nav.sensors.bias.SensorBiasModel` (the user's
model with one augmented state per biased sensor component) and keeps the user's interface:
:meth:`initialize` takes the user's prior ``(n,)`` (the biases start from ``N(0, std^2)``), :attr:`mean`
and :attr:`covariance` are the user's state, :meth:`sensor_bias` gives a sensor's estimated bias and its
sigma. ``update(y, sensor)`` maps the user's sensor onto the augmented state (its bias states, found by
its name, or zero columns); ``update(y)`` is the model's own measurement with its bias, if declared.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from gpf_nav.filters.composite import Composite
from gpf_nav.filters.interface import SENSOR_BIAS, Filter
from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.sensors.sensor import Sensor
from gpf_nav.sensors.bias import SensorBiasModel


class SensorBiasFilter(Composite):
    """A filter on the user's model augmented with the bias states of ``sensors``.

    A :class:`~gpf_nav.filters.composite.Composite` of one member, :attr:`filter`: every capability but
    :data:`~gpf_nav.filters.interface.SENSOR_BIAS` is the member's (its attributes on the augmented state,
    e.g. particles ``(N, n + n_b)``); the sensor biases are its own.

    Args:
        build: builds the filter on a model, e.g. ``lambda m: GeometricProjectionPF(m, 500, seed=0)``.
        model: the user's state-space model.
        sensors: the sensors whose declared :class:`~gpf_nav.sensors.sensor.Bias` is estimated (the
            model's own measurement as ``ModelSensor(model, name, bias=...)``).

    Attributes:
        filter: the filter on the augmented model.
        bias_model: the augmented model.
    """

    own_capabilities = frozenset({SENSOR_BIAS})

    def __init__(self, build: Callable[[StateSpaceModel], Filter], model: StateSpaceModel,
                 sensors: list[Sensor]):
        super().__init__(model)
        self.bias_model = SensorBiasModel(model, sensors)
        self.filter = build(self.bias_model)

    @property
    def members(self) -> tuple[Filter]:
        """:attr:`filter`."""
        return (self.filter,)

    @property
    def last_log_likelihood(self) -> float:
        """:attr:`filter`'s."""
        return self.filter.last_log_likelihood

    def delegate(self, capability: str) -> Filter:
        """:attr:`filter` answers every capability but the sensor biases."""
        return self.filter

    def initialize(self, mean, cov, t0: float = 0.0) -> None:
        """Start from the user's prior ``N(mean (n,), cov (n, n))``, biases from ``N(0, std^2)``; an
        augmented prior ``(n + n_b,)`` is taken as it is."""
        mean = np.asarray(mean, dtype=float).reshape(-1)
        if mean.shape == (self.model.state_dim,):
            mean, cov = self.bias_model.augment_prior(mean, np.asarray(cov, dtype=float))
        self.filter.initialize(mean, cov, t0)

    def predict(self, dt: float, u: np.ndarray | None = None) -> None:
        self.filter.predict(dt, u)

    def update(self, y: np.ndarray, sensor: Sensor | None = None) -> None:
        """Condition on ``y`` of ``sensor`` (None: the model's own measurement, with its bias)."""
        self.filter.update(y, self.bias_model.lift(sensor))

    def predicted_estimate(self, sensor: Sensor) -> tuple[Sensor, np.ndarray, np.ndarray]:
        """``sensor`` on the augmented state with the augmented mean ``(n + n_b,)`` and covariance: what an
        innovation test of ``sensor`` needs, its estimated bias subtracted and its bias sigma counted."""
        return self.bias_model.lift(sensor), self.augmented_mean, self.augmented_covariance

    def predicted_estimates(self, sensor: Sensor) -> list[tuple[Sensor, np.ndarray, np.ndarray]]:
        """:attr:`filter`'s, of ``sensor`` on the augmented state (:meth:`predicted_estimate`)."""
        return self.filter.predicted_estimates(self.bias_model.lift(sensor))

    @property
    def augmented_mean(self) -> np.ndarray:
        """Mean ``(n + n_b,)`` of the user's state and the biases."""
        return np.asarray(self.filter.mean)

    @property
    def augmented_covariance(self) -> np.ndarray:
        """Its covariance ``(n + n_b, n + n_b)``."""
        return np.asarray(self.filter.covariance)

    @property
    def mean(self) -> np.ndarray:
        """Estimate of the user's state ``(n,)``."""
        return self.augmented_mean[:self.model.state_dim]

    @property
    def covariance(self) -> np.ndarray:
        """Its covariance ``(n, n)``."""
        n = self.model.state_dim
        return self.augmented_covariance[:n, :n]

    @property
    def sensor_names(self) -> tuple[str, ...]:
        """Names of the sensors whose bias is estimated."""
        return tuple(self.bias_model.blocks)

    def sensor_bias(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """``(estimated bias (m,), its std (m,))`` of sensor ``name``, in the measurement's units; zero
        for components without a bias state. KeyError if ``name`` has no bias states."""
        return self.bias_model.bias_estimate(name, self.augmented_mean, self.augmented_covariance)
