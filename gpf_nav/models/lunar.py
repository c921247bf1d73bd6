"""Lunar-descent model of the paper's Section 7, in SI units (m, m/s, rad, s).

State ``x = [r, v]`` (``(N, 6)``) in a Moon-centred inertial frame. Nominal drift: two-body gravity
``dv/dt = -mu r / |r|^3 + u`` with ``u`` an optional IMU specific force already rotated to the world
frame. ``mu_scale`` multiplies ``mu``: the filters use 1, the truth ``1 + epsilon`` (9 % by default), the
paper's structural mismatch. Measurements are range, azimuth and elevation of the vehicle seen from a
station (default: the Moon's centre), azimuth ``atan2(dy, dx)`` and elevation ``atan2(dz, |(dx, dy)|)``.
Process noise is white acceleration of spectral density ``accel_noise_density**2`` (m^2/s^3).
"""
from __future__ import annotations

import math

import numpy as np

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
                 accel_noise_density: float = 1e-3, max_step: float = 10.0):
        if range_noise_std <= 0 or angle_noise_std <= 0 or accel_noise_density < 0 or max_step <= 0:
            raise ValueError("noise standard deviations and max_step must be positive")
        self.gm = float(mu) * float(mu_scale)
        self.station = np.asarray(station, dtype=float).reshape(3)
        self.range_noise_std = float(range_noise_std)
        self.angle_noise_std = float(angle_noise_std)
        self.accel_noise_density = float(accel_noise_density)
        self.max_step = float(max_step)
        self._R = np.diag([self.range_noise_std ** 2, self.angle_noise_std ** 2, self.angle_noise_std ** 2])

    # --- dynamics -----------------------------------------------------------------------------------
    # Internally the model works on transposed blocks ``(3, N)``: rows are contiguous when the filter
    # stores particles as ``(n, N)`` and passes the ``(N, n)`` transpose.
    def _acceleration(self, r: np.ndarray, u) -> np.ndarray:
        """Gravity plus specific force ``(3, N)`` at positions ``(3, N)``."""
        r2 = np.einsum("ij,ij->j", r, r)
        np.maximum(r2, _MIN_RANGE_SQ, out=r2)
        k = -self.gm / (r2 * np.sqrt(r2))
        a = r * k
        if u is not None:
            a += u.T if u.ndim == 2 else u[:, None]
        return a

    def _substeps(self, dt: float) -> int:
        """Sub-steps of at most ``max_step``, capped at ``MAX_SUBSTEPS`` (a huge ``dt`` gets coarser
        steps rather than an unbounded loop)."""
        return min(MAX_SUBSTEPS, max(1, math.ceil(abs(dt) / self.max_step)))

    def drift(self, x, t=0.0, u=None):
        xt = x.T
        return np.concatenate([xt[3:], self._acceleration(xt[:3], _as_input(u))]).T

    def transition(self, x, dt, t=0.0, u=None):
        """Kick-drift-kick leapfrog (second order, symplectic) in :meth:`_substeps` sub-steps."""
        u = _as_input(u)
        steps = self._substeps(dt)
        h = dt / steps
        xt = x.T
        r, v = xt[:3].copy(), xt[3:].copy()
        a = self._acceleration(r, u)
        for _ in range(steps):
            v += (0.5 * h) * a
            r += h * v
            a = self._acceleration(r, u)
            v += (0.5 * h) * a
        return np.concatenate([r, v]).T

    def gravity_gradient(self, r: np.ndarray) -> np.ndarray:
        """``d(gravity)/dr`` ``(N, 3, 3)`` at positions ``(N, 3)``."""
        r2 = np.maximum(np.einsum("ij,ij->i", r, r), _MIN_RANGE_SQ)
        k = -self.gm * r2 ** -1.5
        outer = r[:, :, None] * r[:, None, :] / r2[:, None, None]
        return k[:, None, None] * (np.eye(3) - 3.0 * outer)

    def transition_jacobian(self, x, dt, t=0.0, u=None):
        """Second-order Taylor ``I + A h + (A h)^2 / 2`` chained over the sub-steps of :meth:`transition`."""
        steps = self._substeps(dt)
        h = dt / steps
        n = x.shape[0]
        phi = np.broadcast_to(np.eye(6), (n, 6, 6)).copy()
        state = np.asarray(x, dtype=float)
        for _ in range(steps):
            a = np.zeros((n, 6, 6))
            a[:, :3, 3:] = np.eye(3)
            a[:, 3:, :3] = self.gravity_gradient(state[:, :3])
            ah = a * h
            step = np.eye(6) + ah + ah @ ah * 0.5
            phi = step @ phi
            if steps > 1:
                state = self.transition(state, h, t, u)
        return phi

    def compensation_frame(self, x):
        """Radial, along-track and cross-track axes ``(N, 3, 3)`` (columns) of the osculating orbit at
        ``x`` ``(N, 6)``: the frame of orbit determination's empirical accelerations, in which gravity-field
        errors (radial), drag and thrust (along-track) keep their direction. Where the orbit plane is
        undefined (``r`` parallel to ``v``) the cross-track axis is any one normal to ``r``; at the
        Moon's centre, or for a non-finite ``x``, the frame is the world's. Built particle-last (rows of
        ``N``) and returned as the ``(N, 3, 3)`` view; one state is computed in Python floats (the frame of a
        particle filter's estimate, :mod:`gpf_nav.models.compensation`)."""
        if x.shape[0] == 1:
            frame = _point_frame(x[0])
            if frame is not None:
                return frame
        xt = x.T
        r, v = xt[:3], xt[3:6]
        frame = np.empty((3, 3, x.shape[0]))  # (component, axis, particle)
        radial, along, normal = frame[:, 0], frame[:, 1], frame[:, 2]
        np.divide(r, np.maximum(np.sqrt(np.einsum("in,in->n", r, r)), _MIN_RANGE), out=radial)
        _cross(radial, v, out=normal)
        size = np.sqrt(np.einsum("in,in->n", normal, normal))
        speed2 = np.einsum("in,in->n", v, v)
        # every orbit plane defined when the smallest size passes the largest speed's threshold; the sizes
        # are then positive and the states finite (a non-finite one fails the test): a frame of finite axes
        if size.min() > 1e-12 * max(math.sqrt(speed2.max()), 1.0):
            normal /= size
            # normal x radial = (v - (radial . v) radial) / size: the velocity less its radial part
            np.multiply(radial, np.einsum("in,in->n", radial, v), out=along)
            np.subtract(v, along, out=along)
            along /= size
        else:
            _degenerate_frames(frame, size, speed2)
        return frame.transpose(2, 0, 1)

    def process_noise(self, dt):
        q = self.accel_noise_density ** 2
        dt = abs(float(dt))
        i3 = np.eye(3)
        return q * np.block([[dt ** 3 / 3.0 * i3, dt ** 2 / 2.0 * i3], [dt ** 2 / 2.0 * i3, dt * i3]])

    # --- measurements -------------------------------------------------------------------------------
    def _line_of_sight(self, x):
        """Line of sight ``d`` ``(3, N)`` from the station, its horizontal length and its range ``(N,)``."""
        d = x.T[:3] - self.station[:, None]
        h2 = d[0] * d[0] + d[1] * d[1]
        rho2 = h2 + d[2] * d[2]
        return d, np.sqrt(h2), np.sqrt(rho2)

    def _measure(self, d, horizontal, rho):
        return np.stack([rho, np.arctan2(d[1], d[0]), np.arctan2(d[2], horizontal)]).T

    def measure(self, x):
        return self._measure(*self._line_of_sight(x))

    def measurement_jacobian(self, x):
        if x.shape[0] == 1:  # one point (the GPF linearises at its cloud's mean)
            return self._point_jacobian(x[0])
        return self._jacobian(*self._line_of_sight(x))

    def measure_and_jacobian(self, x):
        los = self._line_of_sight(x)
        return self._measure(*los), self._jacobian(*los)

    def _jacobian(self, d, horizontal, rho):
        hor = np.maximum(horizontal, _MIN_HORIZONTAL)
        inv_rho = 1.0 / np.maximum(rho, _MIN_RANGE)
        inv_rho2 = inv_rho * inv_rho
        jac = np.zeros((3, 6, d.shape[1]))
        np.multiply(d, inv_rho, out=jac[0, :3])
        inv_h2 = 1.0 / (hor * hor)
        np.multiply(d[1], inv_h2, out=jac[1, 0])
        np.negative(jac[1, 0], out=jac[1, 0])
        np.multiply(d[0], inv_h2, out=jac[1, 1])
        k = d[2] * inv_rho2
        k /= -hor
        np.multiply(k, d[0], out=jac[2, 0])
        np.multiply(k, d[1], out=jac[2, 1])
        np.multiply(hor, inv_rho2, out=jac[2, 2])
        return jac.transpose(2, 0, 1)

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
    return None if not np.any(u) else u


def _point_frame(x: np.ndarray) -> np.ndarray | None:
    """:meth:`LunarDescentModel.compensation_frame` ``(1, 3, 3)`` of one state ``x`` ``(6,)`` in Python floats
    (the same operations; at one point numpy's calls cost more than the arithmetic), or None where the
    orbit plane is undefined or the state is not finite (the array path handles those)."""
    r0, r1, r2, v0, v1, v2 = x[:6].tolist()
    size_r = max(math.sqrt(r0 * r0 + r1 * r1 + r2 * r2), _MIN_RANGE)
    a0, a1, a2 = r0 / size_r, r1 / size_r, r2 / size_r  # radial
    n0, n1, n2 = a1 * v2 - a2 * v1, a2 * v0 - a0 * v2, a0 * v1 - a1 * v0
    size = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if not size > 1e-12 * max(math.sqrt(v0 * v0 + v1 * v1 + v2 * v2), 1.0):  # (NaN fails too)
        return None
    n0, n1, n2 = n0 / size, n1 / size, n2 / size
    along = a0 * v0 + a1 * v1 + a2 * v2
    t0, t1, t2 = (v0 - along * a0) / size, (v1 - along * a1) / size, (v2 - along * a2) / size
    return np.array([[[a0, t0, n0], [a1, t1, n1], [a2, t2, n2]]])


def _degenerate_frames(frame: np.ndarray, size: np.ndarray, speed2: np.ndarray) -> None:
    """Finish :meth:`LunarDescentModel.compensation_frame` ``(3, 3, N)`` (radial axes and unnormalised
    normals ``(3, N)`` of norms ``size`` in place) where some orbit plane is undefined (``r`` parallel to
    ``v``, of squared norms ``speed2`` ``(N,)``): there any axis normal to ``r``, the cross product with the
    least-aligned base axis; where no frame results (``r = 0``, a non-finite state), the world's."""
    radial, along, normal = frame[:, 0], frame[:, 1], frame[:, 2]
    flat = ~(size > 1e-12 * np.maximum(np.sqrt(speed2), 1.0))
    base = np.eye(3)[:, np.argmin(np.abs(radial[:, flat]), axis=0)]
    normal[:, flat] = _cross(radial[:, flat], base)
    size[flat] = np.sqrt(np.einsum("in,in->n", normal[:, flat], normal[:, flat]))
    with np.errstate(invalid="ignore", divide="ignore"):  # r = 0: no frame, replaced below
        normal /= size
    _cross(normal, radial, out=along)
    bad = ~np.isfinite(frame).all(axis=(0, 1))
    if bad.any():
        frame[:, :, bad] = np.eye(3)[:, :, None]


def _cross(a: np.ndarray, b: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Cross products ``(3, N)`` of the columns of ``a`` and ``b`` ``(3, N)``, written into ``out`` when
    given."""
    if out is None:
        out = np.empty(a.shape)
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # the three components
        np.multiply(a[j], b[k], out=out[i])
        out[i] -= a[k] * b[j]
    return out
