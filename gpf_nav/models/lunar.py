"""Lunar-descent model of the paper's Section 7, in SI units (m, m/s, rad, s).

State ``x = [r, v]`` (``(N, 6)``) in a Moon-centred inertial frame. Nominal drift: two-body gravity
``dv/dt = -mu r / |r|^3 + u`` with ``u`` an optional IMU specific force already rotated to the world
frame, plus, when the model is given one, a gravity field's perturbation ``a_p(r, t)``
(:mod:`gpf_nav.models.gravity`: J2, the zonal terms, a degree-4 field). ``mu_scale`` multiplies ``mu``:
the filters use 1, the truth ``1 + epsilon`` (9 % by default), the paper's structural mismatch. Measurements are range, azimuth and elevation of the vehicle seen from a
station (default: the Moon's centre), azimuth ``atan2(dy, dx)`` and elevation ``atan2(dz, |(dx, dy)|)``.
Process noise is white acceleration of spectral density ``accel_noise_density**2`` (m^2/s^3).
"""
from __future__ import annotations

import math

import numpy as np

from gpf_nav.kernels import bearing, orbit
from gpf_nav.models.gravity import GravityField
from gpf_nav.models.state_space import StateSpaceModel

MU_MOON = 4.9028e12
"""Lunar gravitational parameter, m^3/s^2 (the paper's 4902.8 km^3/s^2)."""
MOON_RADIUS = 1.7374e6
"""Mean lunar radius, m."""

MAX_SUBSTEPS = 200
"""Cap on the integration sub-steps of one :meth:`LunarDescentModel.transition` call."""
_MIN_RANGE_SQ = 1.0  # m^2: floor of |r|^2 that keeps gravity finite at the Moon's centre
_MIN_RANGE = 1.0  # m: floor of the range that keeps H finite with the vehicle at the station
_MIN_HORIZONTAL = 1e-3  # m: floor for the azimuth derivative at elevation +-pi/2


class LunarDescentModel(StateSpaceModel):
    """Two-body lunar gravity with range/azimuth/elevation measurements.

    Args:
        mu: gravitational parameter, m^3/s^2.
        mu_scale: multiplier of ``mu`` (``1 + epsilon`` for the mismatched truth).
        station: observer position ``(3,)`` in metres, world frame.
        range_noise_std: range noise standard deviation, m.
        angle_noise_std: azimuth and elevation noise standard deviation, rad.
        accel_noise_density: process-noise acceleration density, m/s^(3/2).
        max_step: longest integration sub-step of :meth:`transition`, s.
        gravity: the field's perturbation beyond the point mass (None: the point mass). Its flow is
            integrated with numpy (:meth:`_field_leapfrog`); the Jacobians keep the point mass's gravity
            gradient, which the field changes by a relative ``J2 (R / r)^2``, about 2e-4.
    """

    state_dim = 6
    measurement_dim = 3
    angular = np.array([False, True, True])
    position_index = (0, 1, 2)
    velocity_index = (3, 4, 5)
    measured_state_index = (0, 1, 2)
    orthogonal_jacobian_rows = True

    def __init__(self, mu: float = MU_MOON, mu_scale: float = 1.0, station=(0.0, 0.0, 0.0),
                 range_noise_std: float = 30.0, angle_noise_std: float = math.radians(0.03),
                 accel_noise_density: float = 1e-3, max_step: float = 10.0,
                 gravity: GravityField | None = None):
        if range_noise_std <= 0 or angle_noise_std <= 0 or accel_noise_density < 0 or max_step <= 0:
            raise ValueError("noise standard deviations and max_step must be positive")
        self.gm = float(mu) * float(mu_scale)
        self.station = np.asarray(station, dtype=float).reshape(3)
        self.range_noise_std = float(range_noise_std)
        self.angle_noise_std = float(angle_noise_std)
        self.accel_noise_density = float(accel_noise_density)
        self.max_step = float(max_step)
        self.gravity = gravity
        self._R = np.diag([self.range_noise_std ** 2, self.angle_noise_std ** 2, self.angle_noise_std ** 2])

    # --- dynamics -----------------------------------------------------------------------------------
    # Internally the model works on transposed blocks ``(3, N)``: rows are contiguous when the filter
    # stores particles as ``(n, N)`` and passes the ``(N, n)`` transpose.
    def _acceleration(self, r: np.ndarray, u, t: float = 0.0) -> np.ndarray:
        """Gravity plus specific force ``(3, N)`` at positions ``(3, N)`` at time ``t``."""
        r2 = np.einsum("ij,ij->j", r, r)
        np.maximum(r2, _MIN_RANGE_SQ, out=r2)
        k = -self.gm / (r2 * np.sqrt(r2))
        a = r * k
        if self.gravity is not None:
            a += self.gravity.acceleration(r, t)
        if u is not None:
            a += u.T if u.ndim == 2 else u[:, None]
        return a

    def _substeps(self, dt: float) -> int:
        """Sub-steps of at most ``max_step``, capped at ``MAX_SUBSTEPS`` (a huge ``dt`` gets coarser
        steps rather than an unbounded loop)."""
        return min(MAX_SUBSTEPS, max(1, math.ceil(abs(dt) / self.max_step)))

    def drift(self, x, t=0.0, u=None):
        xt = x.T
        return np.concatenate([xt[3:], self._acceleration(xt[:3], _as_input(u), t)]).T

    def transition(self, x, dt, t=0.0, u=None):
        """Kick-drift-kick leapfrog (second order, symplectic) in :meth:`_substeps` sub-steps
        (:func:`gpf_nav.kernels.orbit.leapfrog`; with a gravity field, :meth:`_field_leapfrog`)."""
        if self.gravity is not None:
            return self._field_leapfrog(x, dt, t, u)
        steps = self._substeps(dt)
        return orbit.leapfrog(_particle_last(x), self.gm, dt / steps, steps, _input_columns(u)).T

    def _field_leapfrog(self, x: np.ndarray, dt: float, t: float, u) -> np.ndarray:
        """The leapfrog of :meth:`transition` with the gravity field's perturbation, ``(N, 6) -> (N, 6)``,
        the field taken at each sub-step's time (a tesseral field turns with the Moon)."""
        steps = self._substeps(dt)
        h = dt / steps
        u = _as_input(u)
        xt = np.array(np.asarray(x, dtype=float).T)
        r, v = xt[:3], xt[3:]
        a = self._acceleration(r, u, t)
        for k in range(steps):
            v += 0.5 * h * a
            r += h * v
            a = self._acceleration(r, u, t + (k + 1) * h)
            v += 0.5 * h * a
        return xt.T

    def pushed_transition(self, x, dt, t, u, a, velocity_gain, position_gain, driven, integrated, out):
        """The compensated transition's flow and push in one pass (:func:`gpf_nav.kernels.orbit.pushed_leapfrog`;
        the numbers of :meth:`transition` and :meth:`compensation_frame` in turn). With a gravity field the
        compensation makes the two calls (False)."""
        if self.gravity is not None:
            return False
        steps = self._substeps(dt)
        orbit.pushed_leapfrog(np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(a, dtype=float),
                              self.gm, dt / steps, steps, _input_columns(u), driven, integrated, velocity_gain,
                              position_gain, out)
        return True

    def transition_jacobian(self, x, dt, t=0.0, u=None):
        """Second-order Taylor ``I + A h + (A h)^2 / 2`` chained over the sub-steps of :meth:`transition`
        (:func:`gpf_nav.kernels.orbit.leapfrog_jacobian`)."""
        steps = self._substeps(dt)
        return orbit.leapfrog_jacobian(_particle_last(x), self.gm, dt / steps, steps, _input_columns(u))

    def transition_chain(self, x, dt, t, u):
        """:meth:`transition` ``K`` times in turn in one kernel call (:func:`gpf_nav.kernels.orbit.leapfrog_chain`;
        the point mass's flow does not depend on ``t``; with a gravity field, the calls in turn)."""
        if self.gravity is not None:
            return super().transition_chain(x, dt, t, u)
        steps, h = self._chain_steps(dt)
        return orbit.leapfrog_chain(np.asarray(x, dtype=float), self.gm, h, steps, _input_matrix(u)).T

    def pushed_transition_chain(self, x, a, dt, t, u, velocity_gain, position_gain, decay, driven, integrated):
        """The compensated transition ``K`` times in turn in one kernel call
        (:func:`gpf_nav.kernels.orbit.pushed_leapfrog_chain`); with a gravity field, None (the compensation
        makes the calls)."""
        if self.gravity is not None:
            return None
        steps, h = self._chain_steps(dt)
        return orbit.pushed_leapfrog_chain(np.asarray(x, dtype=float), np.asarray(a, dtype=float), self.gm, h,
                                           steps, _input_matrix(u), driven, integrated,
                                           np.asarray(velocity_gain, dtype=float),
                                           np.asarray(position_gain, dtype=float), np.asarray(decay, dtype=float)).T

    def _chain_steps(self, dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The sub-steps ``(K,)`` of each of the steps ``dt`` ``(K,)`` and their length ``(K,)``, s."""
        distinct, index = np.unique(dt, return_inverse=True)
        steps = np.array([self._substeps(step) for step in distinct.tolist()], dtype=np.int64)[index.ravel()]
        return steps, dt / steps

    def transition_jacobian_along(self, x, dt, t, u):
        """:meth:`transition_jacobian` at each state of ``x`` ``(K, 6)`` in one kernel call per distinct step
        ``dt`` (the sub-steps follow it), each with its own input (the flow does not depend on ``t``)."""
        out = np.empty((len(dt), 6, 6))
        inputs = _input_matrix(u)
        for step in np.unique(dt).tolist():
            index = np.flatnonzero(dt == step)
            steps = self._substeps(step)
            out[index] = orbit.leapfrog_jacobian(_particle_last(x[index]), self.gm, step / steps, steps,
                                                 np.ascontiguousarray(inputs[:, index]))
        return out

    def compensation_frame(self, x):
        """Radial, along-track and cross-track axes ``(N, 3, 3)`` (columns) of the osculating orbit at
        ``x`` ``(N, 6)``: the frame of orbit determination's empirical accelerations, in which gravity-field
        errors (radial), drag and thrust (along-track) keep their direction. Where the orbit plane is
        undefined (``r`` parallel to ``v``) the cross-track axis is any one normal to ``r``; at the
        Moon's centre, or for a non-finite ``x``, the frame is the world's
        (:func:`gpf_nav.kernels.orbit.frames`). Built particle-last and returned as the ``(N, 3, 3)`` view
        (:mod:`gpf_nav.models.compensation` takes the particle-last array back)."""
        return orbit.frames(_particle_last(x)).transpose(2, 0, 1)

    def compensation_push_derivative(self, x, a, relative_step):
        """The central differences of the compensation's Jacobian in one kernel
        (:func:`gpf_nav.kernels.orbit.push_derivative`)."""
        return orbit.push_derivative(np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(a, dtype=float),
                                     float(relative_step))

    def process_noise(self, dt):
        """White-acceleration ``Q(dt)``, read-only, kept for the last ``dt`` (the GPF reads it at every
        update)."""
        dt = abs(float(dt))
        key = (dt, self.accel_noise_density)
        cached = getattr(self, "_noise", None)
        if cached is None or cached[0] != key:
            q = self.accel_noise_density ** 2
            i3 = np.eye(3)
            Q = q * np.block([[dt ** 3 / 3.0 * i3, dt ** 2 / 2.0 * i3], [dt ** 2 / 2.0 * i3, dt * i3]])
            Q.flags.writeable = False
            cached = self._noise = (key, Q)
        return cached[1]

    # --- measurements -------------------------------------------------------------------------------
    def _line_of_sight(self, x):
        """Line of sight ``d`` ``(3, N)`` from the station, its horizontal length and its range ``(N,)``."""
        geometry = orbit.line_of_sight(np.ascontiguousarray(x.T[:3], dtype=float), self.station)
        return geometry[:3], geometry[3], geometry[4]

    def _measure(self, d, horizontal, rho):
        out = np.empty((3, rho.size))  # (filled row by row: np.stack costs more than the arithmetic at N = 500)
        out[0] = rho
        np.arctan2(d[1], d[0], out=out[1])
        np.arctan2(d[2], horizontal, out=out[2])
        return out.T

    def measure(self, x):
        return self._measure(*self._line_of_sight(x))

    def measurement_residual(self, y, x, t=0.0, reverse=False):
        """:meth:`measure`, its residual and the angles' wrapping in one kernel
        (:func:`gpf_nav.kernels.bearing.range_bearing_residual`; ``h`` does not depend on ``t``); a subclass
        with a measurement or residual of its own gets the two calls."""
        if type(self).measure is not LunarDescentModel.measure or type(self).residual is not LunarDescentModel.residual:
            return super().measurement_residual(y, x, t, reverse)
        r = np.ascontiguousarray(x.T[:3], dtype=float)
        return bearing.range_bearing_residual(r, self.station, np.asarray(y, dtype=float).reshape(3), reverse).T

    def measurement_jacobian(self, x):
        if x.shape[0] == 1:  # one point (the GPF linearises at its cloud's mean)
            return self._point_jacobian(x[0])
        return self._jacobian(*self._line_of_sight(x))

    def measurement_jacobian_along(self, x, t):
        """:meth:`measurement_jacobian` at every state of ``x`` ``(K, 6)`` in one call (``h`` does not depend
        on ``t``)."""
        return self.measurement_jacobian(x)

    def measure_and_jacobian(self, x):
        if x.shape[0] == 1:  # one point (the observability tracker's reference): the point Jacobian
            return self.measure(x), self._point_jacobian(x[0])
        los = self._line_of_sight(x)
        return self._measure(*los), self._jacobian(*los)

    def _jacobian(self, d, horizontal, rho):
        """``H`` ``(N, 3, 6)`` from the line of sight (:func:`gpf_nav.kernels.bearing.range_bearing_jacobian`,
        a view of its particle-last ``(3, 6, N)`` array)."""
        return bearing.range_bearing_jacobian(d, horizontal, rho, _MIN_HORIZONTAL, _MIN_RANGE).transpose(2, 0, 1)

    def _point_jacobian(self, x: np.ndarray) -> np.ndarray:
        """:meth:`_jacobian` ``(1, 3, 6)`` at one state ``x`` ``(6,)``, in Python floats: at one point the
        work is the cost of numpy's calls, not of the arithmetic (the same operations, the same result)."""
        d0, d1, d2 = (x[:3] - self.station).tolist()
        horizontal = math.sqrt(d0 * d0 + d1 * d1)
        rho = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        hor = max(horizontal, _MIN_HORIZONTAL)
        inv_rho = 1.0 / max(rho, _MIN_RANGE)
        inv_rho2 = inv_rho * inv_rho
        inv_h2 = 1.0 / (hor * hor)
        k = d2 * inv_rho2 / -hor
        return np.array([[[d0 * inv_rho, d1 * inv_rho, d2 * inv_rho, 0.0, 0.0, 0.0],
                          [-(d1 * inv_h2), d0 * inv_h2, 0.0, 0.0, 0.0, 0.0],
                          [k * d0, k * d1, hor * inv_rho2, 0.0, 0.0, 0.0]]])

    def measurement_noise(self):
        return self._R


def _as_input(u):
    """Specific force as ``(3,)`` or ``(N, 3)`` float array, or None."""
    if u is None:
        return None
    u = np.asarray(u, dtype=float)
    return u if u.any() else None  # (the method: np.any's dispatch costs more than the test at every call)


def _input_matrix(u: list) -> np.ndarray:
    """``(3, K)``: the inputs ``u`` (``K`` specific forces ``(3,)`` or None) side by side, a zero column for
    None (what no input gives the kernels)."""
    inputs = np.zeros((3, len(u)))
    for k, force in enumerate(u):
        if force is not None:
            inputs[:, k] = force
    return inputs


def _particle_last(x: np.ndarray) -> np.ndarray:
    """States ``(N, 6)`` as the C-contiguous ``(6, N)`` array the kernels take (no copy for a filter's
    particles, stored that way)."""
    return np.ascontiguousarray(np.asarray(x, dtype=float).T)


_NO_INPUT = np.zeros((3, 1))


def _input_columns(u) -> np.ndarray:
    """The specific force as the kernels take it: ``(3, 1)`` for one input (zeros for none), ``(3, N)``
    for one per particle."""
    u = _as_input(u)
    if u is None:
        return _NO_INPUT
    return np.ascontiguousarray(u.T) if u.ndim == 2 else u.reshape(3, 1)


