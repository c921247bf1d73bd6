"""A model with more white acceleration in its process noise: ``dv = (f_v + w) dt``, ``E[w w^T] = q I dt``.

:class:`WhiteAccelerationNoise` is its base model in every respect but ``Q(dt)``, to which it adds the
covariance a white acceleration of spectral density ``q`` (m^2/s^3) accumulates over ``dt`` on each
position/velocity pair: ``q dt^3 / 3`` on the position, ``q dt^2 / 2`` between position and velocity,
``q dt`` on the velocity (on every state, ``q dt``, for a model that declares no positions and
velocities). It is how the multiple-model GPF's nominal member admits forces too small and too varied
for any compensated member to be worth its states (:mod:`gpf_nav.filters.multiple_model`): unlike an
estimated acceleration it carries no learnt force across a gap in the data, it only widens the
covariance by what such a force could do. A compensation of this model
(:mod:`gpf_nav.models.compensation`) carries its acceleration in the state's own axes and through the base's
plain transition: the base's local frame and fused transition are not forwarded.
"""
from __future__ import annotations

import math

import numpy as np

from gpf_nav.models.state_space import StateSpaceModel


class WhiteAccelerationNoise(StateSpaceModel):
    """``base`` with a white acceleration of spectral density ``intensity`` added (module docstring).

    Args:
        base: the model (any :class:`StateSpaceModel`).
        intensity: spectral density ``q`` of the added white acceleration, state units^2 per s^3
            (m^2/s^3), >= 0.
    """

    def __init__(self, base: StateSpaceModel, intensity: float):
        if not (math.isfinite(intensity) and intensity >= 0.0):
            raise ValueError(f"intensity must be finite and >= 0, got {intensity}")
        self.base = base
        self.intensity = float(intensity)
        self.state_dim = base.state_dim
        self.measurement_dim = base.measurement_dim
        self.angular = getattr(base, "angular", None)  # a missing mask is reported by the validation
        self.position_index = tuple(base.position_index)
        self.velocity_index = tuple(base.velocity_index)
        self.measured_state_index = base.measured_state_index
        self.orthogonal_jacobian_rows = base.orthogonal_jacobian_rows
        self._velocities = np.asarray(self.velocity_index or range(self.state_dim), dtype=int)
        pairs = 0 < len(self.velocity_index) == len(self.position_index)
        self._positions = np.asarray(self.position_index, dtype=int) if pairs else None
        self._time_varying_noise = base.time_varying_noise
        self._noise_cache: tuple[tuple[float, float] | None, np.ndarray | None] = (None, None)

    # --- the process noise: the base's plus the white acceleration's ------------------------------------
    @property
    def time_varying_noise(self) -> bool:
        return self._time_varying_noise

    def process_noise(self, dt, t=0.0):
        """The base ``Q`` over ``[t, t + dt]`` plus the white acceleration's; cached for the last ``dt`` (and
        the last ``t`` when the base model's noise varies with time)."""
        dt = float(dt)
        key = (dt, float(t) if self._time_varying_noise else 0.0)
        if self._noise_cache[0] != key:
            Q = np.array(self.base.process_noise(dt, t), dtype=float)
            span = abs(dt)
            v = self._velocities
            Q[v, v] += self.intensity * span
            if self._positions is not None:
                p = self._positions
                Q[p, p] += self.intensity * span ** 3 / 3.0
                Q[p, v] += self.intensity * span ** 2 / 2.0
                Q[v, p] += self.intensity * span ** 2 / 2.0
            Q.flags.writeable = False
            self._noise_cache = (key, Q)
        return self._noise_cache[1]

    # --- everything else is the base model's ------------------------------------------------------------
    @property
    def base_state_dim(self) -> int:
        return self.base.base_state_dim

    def drift(self, x, t=0.0, u=None):
        return self.base.drift(x, t, u)

    def transition(self, x, dt, t=0.0, u=None):
        return self.base.transition(x, dt, t, u)

    def transition_jacobian(self, x, dt, t=0.0, u=None):
        return self.base.transition_jacobian(x, dt, t, u)

    def transition_chain(self, x, dt, t, u):
        return self.base.transition_chain(x, dt, t, u)

    def transition_jacobian_along(self, x, dt, t, u):
        return self.base.transition_jacobian_along(x, dt, t, u)

    def measure(self, x, t=0.0):
        return self.base.measure(x, t)

    def measurement_jacobian(self, x, t=0.0):
        return self.base.measurement_jacobian(x, t)

    def measure_and_jacobian(self, x, t=0.0):
        return self.base.measure_and_jacobian(x, t)

    def measurement_jacobian_along(self, x, t):
        return self.base.measurement_jacobian_along(x, t)

    def measurement_noise(self):
        return self.base.measurement_noise()

    def residual(self, y, y_pred):
        return self.base.residual(y, y_pred)

    def measurement_residual(self, y, x, t=0.0, reverse=False):
        return self.base.measurement_residual(y, x, t, reverse)

    def measurement_mean(self, y, weights):
        return self.base.measurement_mean(y, weights)
