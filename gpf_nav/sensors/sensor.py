"""The sensor interface: a measurement function, its Jacobian, its noise, its angular mask, optional bias.

A :class:`Sensor` measures the user's state ``x`` ``(N, n)`` (position, velocity, ...), batched over
particles: ``measure(x, t) -> (N, m)``, ``jacobian(x, t) -> (N, m, n)``, ``noise(t) -> R (m, m)``
(symmetric positive definite), ``residual(y, h)`` (``y - h`` with the angular components wrapped to
(-pi, pi]). Every filter of :mod:`gpf_nav.filters` updates with any sensor, ``filter.update(y, sensor)``;
without one it uses the model's own measurement (:class:`~gpf_nav.sensors.model.ModelSensor`). A NaN
component of ``y`` is not measured.

A sensor may declare a :class:`Bias`: an additive bias per component, a random constant or a first-order
Gauss-Markov process, that a filter estimates as augmented states (:mod:`gpf_nav.sensors.bias`,
:mod:`gpf_nav.filters.biased`).

Sensors return ``noise`` arrays they never write afterwards (filters cache factors of ``R`` and compare
a new ``R`` with the last one); a sensor whose noise changes returns a new array.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from gpf_nav.models.state_space import measurement_mean, wrapped_residual


@dataclass(frozen=True)
class Bias:
    """An additive bias ``b`` per measurement component, estimated as augmented states.

    ``std[i] = 0`` leaves component ``i`` unbiased (no state). ``time[i] = inf`` makes ``b_i`` a random
    constant with prior ``N(0, std_i^2)``; a finite ``time`` a first-order Gauss-Markov process of
    stationary std ``std_i`` and correlation time ``time_i`` s, ``b(t + dt) = e^(-dt/tau) b(t) + w``,
    ``var(w) = std^2 (1 - e^(-2 dt / tau))``.

    Attributes:
        std: ``(m,)`` stationary (prior) standard deviations, in the measurement's units.
        time: ``(m,)`` correlation times, s (``inf``: random constant).
    """

    std: tuple[float, ...]
    time: tuple[float, ...]

    def __post_init__(self):
        std = tuple(float(s) for s in np.atleast_1d(self.std))
        time = tuple(float(s) for s in np.broadcast_to(np.atleast_1d(self.time), (len(std),)))
        if not all(math.isfinite(s) and s >= 0.0 for s in std):
            raise ValueError(f"bias std must be finite and non-negative, got {std}")
        if not all(t > 0.0 for t in time):
            raise ValueError(f"bias correlation times must be positive (inf: a constant), got {time}")
        object.__setattr__(self, "std", std)
        object.__setattr__(self, "time", time)

    @property
    def components(self) -> np.ndarray:
        """Indices of the biased components (``std > 0``)."""
        return np.flatnonzero(np.asarray(self.std) > 0.0)


def random_constant_bias(std) -> Bias:
    """A constant bias of prior std ``std`` (scalar or ``(m,)``; 0 for an unbiased component)."""
    return Bias(tuple(np.atleast_1d(np.asarray(std, dtype=float))), (math.inf,))


def gauss_markov_bias(std, time) -> Bias:
    """A first-order Gauss-Markov bias of stationary std ``std`` and correlation time ``time`` s."""
    return Bias(tuple(np.atleast_1d(np.asarray(std, dtype=float))), tuple(np.atleast_1d(time)))


class Sensor(ABC):
    """A measurement model as an object of its own (module docstring).

    Attributes:
        name: the sensor's name (``"rae"``, ``"position"``...): estimated biases are looked up by it.
        dim: ``m``, the measurement dimension.
        angular: ``(m,)`` bool, the components that are angles (residuals wrapped).
        bias: the bias states this sensor declares, or None.
        measured_state_index: the state components ``h`` depends on (other columns of the Jacobian are
            zero), or None for all; lets the GPF's projection skip structural zeros.
        orthogonal_jacobian_rows: the rows of the Jacobian are mutually orthogonal everywhere.
    """

    name: str = "sensor"
    dim: int
    angular: np.ndarray
    bias: Bias | None = None
    measured_state_index: tuple[int, ...] | None = None
    orthogonal_jacobian_rows: bool = False

    @abstractmethod
    def measure(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Noise-free measurement ``h(x, t)``: ``(N, n) -> (N, m)``."""

    @abstractmethod
    def jacobian(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Its Jacobian ``(N, n) -> (N, m, n)``."""

    def jacobian_along(self, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Jacobians ``(K, m, n)`` at the ``K`` states ``x`` ``(K, n)``, each at its own time ``t[k]`` (the
        observability tracker's rebuild). The default calls :meth:`jacobian` once per state; a sensor
        overrides it to do them in one call, with the same numbers."""
        out = np.empty((len(t), self.dim, x.shape[1]))
        for k, time in enumerate(t):
            out[k] = self.jacobian(x[k:k + 1], float(time))[0]
        return out

    @abstractmethod
    def noise(self, t: float = 0.0) -> np.ndarray:
        """Noise covariance ``R`` ``(m, m)`` at ``t`` (never written after it is returned)."""

    def measure_and_jacobian(self, x: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """``(h (N, m), H (N, m, n))`` together; override to share work between the two."""
        return self.measure(x, t), self.jacobian(x, t)

    def residual(self, y: np.ndarray, h: np.ndarray) -> np.ndarray:
        """``y - h`` with the angular components wrapped to (-pi, pi]; shapes broadcast."""
        return wrapped_residual(y, h, self.angular)

    def measurement_residual(self, y: np.ndarray, x: np.ndarray, t: float = 0.0, reverse: bool = False
                             ) -> np.ndarray:
        """The residual ``(N, m)`` of the measurement ``y`` ``(m,)`` at the states ``x`` ``(N, n)``:
        :meth:`residual` of ``y`` and :meth:`measure`, or, ``reverse``, of :meth:`measure` and ``y`` (``h(x) -
        y``). A sensor overrides it to do both in one pass, with the same numbers."""
        h = self.measure(x, t)
        return self.residual(h, y) if reverse else self.residual(y, h)

    def measurement_mean(self, y: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Weighted mean ``(m,)`` of measurements ``(K, m)`` with weights ``(K,)``; angles circular."""
        return measurement_mean(y, weights, self.angular)


def innovation_distance(sensor: Sensor, y: np.ndarray, mean: np.ndarray, cov: np.ndarray,
                        t: float = 0.0) -> tuple[float, int]:
    """``(d^2, k)``: the squared Mahalanobis distance of the ``k`` measured (finite) components of ``y``
    ``(m,)`` from the prediction of an estimate ``N(mean (n,), cov (n, n))``, linearised at the mean,
    ``d^2 = r^T (H P H^T + R)^-1 r`` with ``r`` the residual; chi-square with ``k`` degrees of freedom
    when the estimate and the sensor are right (a whole-measurement gate). ``(inf, k)`` when the
    innovation covariance is not positive definite; ``(0.0, 0)`` when nothing is measured."""
    y = np.asarray(y, dtype=float)
    rows = np.isfinite(y)
    k = int(rows.sum())
    if not k:
        return 0.0, 0
    x = np.asarray(mean, dtype=float)[None]
    h, H = sensor.measure_and_jacobian(x, t)
    r = sensor.residual(y, h[0])[rows]
    H = H[0][rows]
    S = H @ np.asarray(cov, dtype=float) @ H.T + np.asarray(sensor.noise(t))[np.ix_(rows, rows)]
    try:
        L = np.linalg.cholesky(0.5 * (S + S.T))
    except np.linalg.LinAlgError:
        return math.inf, k
    w = np.linalg.solve(L, r)
    return float(w @ w), k


class Padded(Sensor):
    """``sensor`` seen from a state with extra components after the user's ``n`` (model-error
    compensation): it measures ``x[:, :n]`` and its Jacobian gets zero columns up to ``total``."""

    def __init__(self, sensor: Sensor, n: int, total: int):
        self.sensor, self._n, self._total = sensor, int(n), int(total)
        self.name, self.dim, self.angular = sensor.name, sensor.dim, sensor.angular
        self.bias = None
        index = sensor.measured_state_index
        self.measured_state_index = tuple(range(n)) if index is None else tuple(index)
        self.orthogonal_jacobian_rows = sensor.orthogonal_jacobian_rows

    def measure(self, x, t=0.0):
        return self.sensor.measure(x[:, :self._n], t)

    def jacobian(self, x, t=0.0):
        return self._pad(self.sensor.jacobian(x[:, :self._n], t))

    def measure_and_jacobian(self, x, t=0.0):
        h, H = self.sensor.measure_and_jacobian(x[:, :self._n], t)
        return h, self._pad(H)

    def jacobian_along(self, x, t):
        return self._pad(self.sensor.jacobian_along(x[:, :self._n], t))

    def _pad(self, H: np.ndarray) -> np.ndarray:
        out = np.zeros((H.shape[0], H.shape[1], self._total))
        out[:, :, :self._n] = H
        return out

    def noise(self, t=0.0):
        return self.sensor.noise(t)

    def residual(self, y, h):
        return self.sensor.residual(y, h)

    def measurement_residual(self, y, x, t=0.0, reverse=False):
        """The sensor's own (its one-pass kernel where it has one, as an unpadded filter's update uses)."""
        return self.sensor.measurement_residual(y, x[:, :self._n], t, reverse)

    def measurement_mean(self, y, weights):
        return self.sensor.measurement_mean(y, weights)
