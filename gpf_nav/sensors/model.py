"""The model's own measurement as a sensor: the default sensor of every filter."""
from __future__ import annotations

import numpy as np

from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.sensors.sensor import Bias, Sensor


class ModelSensor(Sensor):
    """A :class:`StateSpaceModel`'s measurement (``measure``, ``measurement_jacobian``,
    ``measurement_noise``, ``angular``, ``residual``) as a :class:`Sensor`, every call delegated, so a
    filter updating with it computes exactly what it computed from the model (bit for bit).

    On the lunar model it is the range / azimuth / elevation sensor of a station.

    Args:
        model: the state-space model.
        name: the sensor's name (``"rae"`` for the lunar model's).
        bias: optional bias states of its components.
    """

    def __init__(self, model: StateSpaceModel, name: str = "model", bias: Bias | None = None):
        self.model = model
        self.name = name
        self.bias = bias

    # read from the model when asked: a filter builds its model's sensor before it validates the model
    @property
    def dim(self) -> int:
        return int(self.model.measurement_dim)

    @property
    def angular(self) -> np.ndarray:
        return np.asarray(self.model.angular, dtype=bool)

    @property
    def measured_state_index(self) -> tuple[int, ...] | None:
        return self.model.measured_state_index

    @property
    def orthogonal_jacobian_rows(self) -> bool:
        return self.model.orthogonal_jacobian_rows

    def measure(self, x, t=0.0):
        return self.model.measure(x, t)

    def jacobian(self, x, t=0.0):
        return self.model.measurement_jacobian(x, t)

    def measure_and_jacobian(self, x, t=0.0):
        return self.model.measure_and_jacobian(x, t)

    def jacobian_along(self, x, t):
        return self.model.measurement_jacobian_along(x, t)

    def noise(self, t=0.0):
        return self.model.measurement_noise()

    def residual(self, y, h):
        return self.model.residual(y, h)

    def measurement_residual(self, y, x, t=0.0, reverse=False):
        return self.model.measurement_residual(y, x, t, reverse)

    def measurement_mean(self, y, weights):
        return self.model.measurement_mean(y, weights)
