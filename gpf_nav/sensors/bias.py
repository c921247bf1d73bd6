"""Sensor-bias states: a model with the biases of some sensors appended to its state.

:class:`SensorBiasModel` runs any filter on ``x_aug = [x (n), b (n_b)]``: ``b`` holds one state per biased
component of each sensor that declares a :class:`~gpf_nav.sensors.sensor.Bias` (random constant, or
first-order Gauss-Markov), with the prior ``N(0, std^2)``, the transition ``b e^(-dt/tau)`` and the noise
``std^2 (1 - e^(-2 dt / tau))`` (zero for a constant). A biased sensor measures ``h(x) + b`` on the
augmented state (:meth:`SensorBiasModel.lift`); the model's own measurement carries the bias of its
:class:`~gpf_nav.sensors.model.ModelSensor` when that one is among the sensors. Biases are found by the
sensor's name, so a sensor rebuilt with a new noise (a message's covariance) keeps its bias states.
"""
from __future__ import annotations


import numpy as np

from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.sensors.sensor import Padded, Sensor
from gpf_nav.sensors.model import ModelSensor


class BiasedSensor(Padded):
    """``sensor`` on the augmented state: ``h(x[:, :n]) + x[:, columns]`` on its ``components``."""

    def __init__(self, sensor: Sensor, n: int, total: int, columns: np.ndarray, components: np.ndarray):
        super().__init__(sensor, n, total)
        self._columns, self._components = columns, components
        self.measured_state_index = self.measured_state_index + tuple(int(c) for c in columns)

    def _add(self, h: np.ndarray, x: np.ndarray) -> np.ndarray:
        h = np.array(h, dtype=float)
        h[:, self._components] += x[:, self._columns]
        return h

    def measure(self, x, t=0.0):
        return self._add(super().measure(x, t), x)

    def measure_and_jacobian(self, x, t=0.0):
        h, H = super().measure_and_jacobian(x, t)
        return self._add(h, x), H

    # the biased measurement, then its residual (the sensor's own one-pass residual knows no bias)
    measurement_residual = Sensor.measurement_residual

    def _pad(self, H: np.ndarray) -> np.ndarray:
        out = super()._pad(H)
        out[:, self._components, self._columns] = 1.0
        return out


class SensorBiasModel(StateSpaceModel):
    """``base`` with the bias states of ``sensors`` appended (module docstring).

    Args:
        base: the user's model (any :class:`StateSpaceModel`).
        sensors: the sensors whose :attr:`~gpf_nav.sensors.sensor.Sensor.bias` is estimated (others are
            ignored); names must be unique.

    Attributes:
        blocks: ``{name: (columns (k,), components (k,))}``: the augmented-state columns of each biased
            sensor's bias states and the measurement components they bias.
    """

    def __init__(self, base: StateSpaceModel, sensors: list[Sensor]):
        self.base = base
        n = base.state_dim
        self.blocks: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._dims: dict[str, int] = {}
        stds, times = [], []
        self.own_sensor: ModelSensor | None = None
        for sensor in sensors:
            if sensor.bias is None or not sensor.bias.components.size:
                continue
            if sensor.name in self.blocks:
                raise ValueError(f"two biased sensors are named {sensor.name!r}")
            if len(sensor.bias.std) != sensor.dim:
                raise ValueError(f"sensor {sensor.name!r}: bias has {len(sensor.bias.std)} components, "
                                 f"the sensor {sensor.dim}")
            components = sensor.bias.components
            columns = n + len(stds) + np.arange(components.size)
            self.blocks[sensor.name] = (columns, components)
            self._dims[sensor.name] = sensor.dim
            stds.extend(np.asarray(sensor.bias.std)[components])
            times.extend(np.asarray(sensor.bias.time)[components])
            if isinstance(sensor, ModelSensor) and sensor.model is base:
                self.own_sensor = sensor
        self.bias_std = np.asarray(stds, dtype=float)
        self.bias_time = np.asarray(times, dtype=float)
        self._n, self._b = n, len(stds)
        self.state_dim = n + self._b
        self.measurement_dim = base.measurement_dim
        self.angular = getattr(base, "angular", None)  # a missing mask is reported by the validation
        self.position_index = tuple(base.position_index)
        self.velocity_index = tuple(base.velocity_index)
        self._own = (Padded(ModelSensor(base), n, self.state_dim) if self.own_sensor is None
                     else self.lift(self.own_sensor))
        self.measured_state_index = self._own_index()
        self.orthogonal_jacobian_rows = base.orthogonal_jacobian_rows

    def _own_index(self) -> tuple[int, ...] | None:
        if self.own_sensor is None:
            index = self.base.measured_state_index
            return tuple(range(self._n)) if index is None else tuple(index)
        return self._own.measured_state_index

    # --- bias states --------------------------------------------------------------------------------
    def lift(self, sensor: Sensor | None) -> Sensor | None:
        """``sensor`` on the augmented state: with its bias states if it has any here (by name), else
        with zero columns for them. None (the model's own sensor) stays None."""
        if sensor is None:
            return None
        if sensor.name in self.blocks:
            if sensor.dim != self._dims[sensor.name]:
                raise ValueError(f"sensor {sensor.name!r} has {sensor.dim} components, its bias "
                                 f"states {self._dims[sensor.name]}")
            return BiasedSensor(sensor, self._n, self.state_dim, *self.blocks[sensor.name])
        return Padded(sensor, self._n, self.state_dim)

    def augment_prior(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A base prior ``N(mean (n,), cov (n, n))`` extended with the biases ``N(0, diag(std^2))``."""
        out = np.zeros((self.state_dim, self.state_dim))
        out[:self._n, :self._n] = cov
        out[self._n:, self._n:] = np.diag(self.bias_std ** 2)
        return np.concatenate([np.asarray(mean, dtype=float).reshape(-1), np.zeros(self._b)]), out

    def bias_estimate(self, name: str, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(bias mean (m,), its std (m,))`` of sensor ``name`` from an augmented estimate ``mean``
        ``(>= n + n_b,)``, ``cov``; zero for the components it does not bias. KeyError for an unknown
        name."""
        columns, components = self.blocks[name]
        m = self._dims[name]
        b, s = np.zeros(m), np.zeros(m)
        b[components] = mean[columns]
        s[components] = np.sqrt(np.maximum(np.diagonal(cov)[columns], 0.0))
        return b, s

    def _decay(self, dt: float) -> np.ndarray:
        return np.exp(-abs(float(dt)) / self.bias_time)

    # --- StateSpaceModel -----------------------------------------------------------------------------
    @property
    def time_varying_noise(self) -> bool:
        return self.base.time_varying_noise

    @property
    def base_state_dim(self) -> int:
        """The user's model's states (this model's own are appended after them)."""
        return self.base.base_state_dim

    def drift(self, x, t=0.0, u=None):
        return np.concatenate([self.base.drift(x[:, :self._n], t, u), -x[:, self._n:] / self.bias_time], axis=1)

    def transition(self, x, dt, t=0.0, u=None):
        return np.concatenate([self.base.transition(x[:, :self._n], dt, t, u),
                               x[:, self._n:] * self._decay(dt)], axis=1)

    def transition_jacobian(self, x, dt, t=0.0, u=None):
        J = np.zeros((x.shape[0], self.state_dim, self.state_dim))
        J[:, :self._n, :self._n] = self.base.transition_jacobian(x[:, :self._n], dt, t, u)
        J[:, self._n:, self._n:] = np.diag(self._decay(dt))
        return J

    def process_noise(self, dt, t=0.0):
        Q = np.zeros((self.state_dim, self.state_dim))
        Q[:self._n, :self._n] = self.base.process_noise(dt, t)
        Q[self._n:, self._n:] = np.diag(self.bias_std ** 2 * -np.expm1(-2.0 * abs(float(dt)) / self.bias_time))
        return Q

    def compensation_frame(self, x):
        return self.base.compensation_frame(x[:, :self._n])

    def measure(self, x, t=0.0):
        return self._own.measure(x, t)

    def measurement_jacobian(self, x, t=0.0):
        return self._own.jacobian(x, t)

    def measure_and_jacobian(self, x, t=0.0):
        return self._own.measure_and_jacobian(x, t)

    def measurement_noise(self):
        return self.base.measurement_noise()

    def residual(self, y, y_pred):
        return self.base.residual(y, y_pred)

    def measurement_mean(self, y, weights):
        return self.base.measurement_mean(y, weights)


__all__ = ["SensorBiasModel", "BiasedSensor"]
