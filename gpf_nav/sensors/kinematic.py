"""Sensors of the vehicle's own kinematics: position and velocity fixes, altitude above a sphere.

All SI (m, m/s), world frame. The state holds the position and the velocity at ``position_index`` and
``velocity_index`` (the lunar model's ``(0, 1, 2)`` and ``(3, 4, 5)`` by default); the Jacobians have as
many columns as the state they are given, so a sensor works on any state that holds those components.
"""
from __future__ import annotations

import copy
from functools import lru_cache

import numpy as np

from gpf_nav.models.lunar import MOON_RADIUS
from gpf_nav.sensors.sensor import Bias, Sensor


def noise_covariance(noise, dim: int) -> np.ndarray:
    """``R`` ``(dim, dim)`` from a standard deviation (scalar or ``(dim,)``) or a covariance
    ``(dim, dim)``; ValueError unless it is finite, symmetric and positive definite."""
    a = np.asarray(noise, dtype=float)
    if a.ndim <= 1:
        std = np.broadcast_to(a, (dim,))
        R = np.diag(std ** 2)
        ok = bool(np.all(np.isfinite(std)) and np.all(std > 0.0))
    else:
        R = np.array(a)
        ok = (R.shape == (dim, dim) and bool(np.all(np.isfinite(R))) and np.allclose(R, R.T)
              and np.linalg.eigvalsh(0.5 * (R + R.T)).min() > 0.0)
        R = 0.5 * (R + R.T)
    if not ok:
        raise ValueError(f"sensor noise must be positive standard deviations or a ({dim}, {dim}) symmetric "
                         f"positive definite covariance, got {a.tolist()}")
    R.flags.writeable = False
    return R


@lru_cache(maxsize=64)
def _selection(index: tuple[int, ...], n: int) -> np.ndarray:
    """``(k, n)`` matrix selecting the state components ``index`` (read-only)."""
    H = np.zeros((len(index), n))
    H[np.arange(len(index)), list(index)] = 1.0
    H.flags.writeable = False
    return H


class StateComponentSensor(Sensor):
    """Measures state components directly, ``h(x) = x[:, index]``: a linear sensor.

    Args:
        index: the measured state components.
        noise: standard deviation(s) or covariance ``(k, k)``, in the components' units.
        name: the sensor's name.
        bias: optional bias states.
    """

    orthogonal_jacobian_rows = True

    def __init__(self, index, noise, name: str, bias: Bias | None = None):
        self.index = tuple(int(i) for i in index)
        self.dim = len(self.index)
        self.angular = np.zeros(self.dim, bool)
        self.measured_state_index = self.index
        self.name = name
        self.bias = bias
        self._R = noise_covariance(noise, self.dim)

    def with_noise(self, noise) -> StateComponentSensor:
        """A copy of this sensor with another noise (e.g. the covariance a message carries): standard
        deviation(s) or a ``(k, k)`` covariance."""
        out = copy.copy(self)
        out._R = noise_covariance(noise, self.dim)
        return out

    def measure(self, x, t=0.0):
        return x[:, self.index]

    def jacobian(self, x, t=0.0):
        return np.broadcast_to(_selection(self.index, x.shape[1]), (x.shape[0], self.dim, x.shape[1]))

    def jacobian_along(self, x, t):
        return self.jacobian(x)  # (the same selection at every state and time)

    def noise(self, t=0.0):
        return self._R


class PositionSensor(StateComponentSensor):
    """A position fix (e.g. terrain-relative navigation): the three position components, m, world frame.

    Args:
        noise: standard deviation(s), m, or the ``(3, 3)`` covariance, m^2.
        name: default ``"position"``.
        bias: optional bias states.
        index: the position components of the state.
    """

    def __init__(self, noise, name: str = "position", bias: Bias | None = None, index=(0, 1, 2)):
        super().__init__(index, noise, name, bias)


class VelocitySensor(StateComponentSensor):
    """A velocity fix (e.g. a Doppler velocimeter): the three velocity components, m/s, world axes.

    Args:
        noise: standard deviation(s), m/s, or the ``(3, 3)`` covariance, m^2/s^2.
        name: default ``"velocity"``.
        bias: optional bias states.
        index: the velocity components of the state.
    """

    def __init__(self, noise, name: str = "velocity", bias: Bias | None = None, index=(3, 4, 5)):
        super().__init__(index, noise, name, bias)


class AltitudeSensor(Sensor):
    """Altitude above a reference sphere (a radar or laser altimeter): ``h(x) = |r| - reference_radius``, m.

    Args:
        noise_std: standard deviation, m.
        reference_radius: radius of the sphere, m (default the Moon's mean radius, 1737.4 km).
        name: default ``"altitude"``.
        bias: optional bias state.
        position_index: the position components of the state.
    """

    angular = np.zeros(1, bool)
    dim = 1
    orthogonal_jacobian_rows = True

    def __init__(self, noise_std: float, reference_radius: float = MOON_RADIUS, name: str = "altitude",
                 bias: Bias | None = None, position_index=(0, 1, 2)):
        if not (np.isfinite(reference_radius) and reference_radius >= 0.0):
            raise ValueError(f"reference_radius must be finite and non-negative, got {reference_radius}")
        self.noise_std = float(noise_std)
        self.reference_radius = float(reference_radius)
        self.name = name
        self.bias = bias
        self.position_index = tuple(int(i) for i in position_index)
        self.measured_state_index = self.position_index
        self._R = noise_covariance(self.noise_std, 1)

    def _radius(self, x):
        r = x[:, self.position_index]
        return r, np.sqrt(np.einsum("ij,ij->i", r, r))

    def measure(self, x, t=0.0):
        return (self._radius(x)[1] - self.reference_radius)[:, None]

    def jacobian(self, x, t=0.0):
        return self.measure_and_jacobian(x, t)[1]

    def measure_and_jacobian(self, x, t=0.0):
        r, radius = self._radius(x)
        H = np.zeros((x.shape[0], 1, x.shape[1]))
        H[:, 0, self.position_index] = r / np.maximum(radius, 1.0)[:, None]  # 1 m floor: finite at the centre
        return (radius - self.reference_radius)[:, None], H

    def noise(self, t=0.0):
        return self._R
