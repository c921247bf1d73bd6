"""Range, azimuth and elevation of the vehicle from a station: on the rotating Moon or fixed in inertial space.

A station measures the line of sight ``d = r - s(t)`` from its position ``s(t)`` in its own axes
``(north, east, up)``: range ``|d|``, azimuth ``atan2(d_east, d_north)`` and elevation
``atan2(d_up, |(d_north, d_east)|)``.

* A surface station (:meth:`StationSensor.surface`) stands at a latitude, longitude and height on the
  Moon and turns with it (:mod:`gpf_nav.models.frames`): its axes are its local north, east and up, so it
  reports what a ground antenna reports, azimuth from north towards east (clockwise seen from above,
  in [-pi, pi]) and elevation above its horizon. Both depend on ``t``.
* An inertial station (:meth:`StationSensor.inertial`) stands still in the world frame with the world's
  axes, ``north`` = x, ``east`` = y, ``up`` = z: azimuth ``atan2(dy, dx)`` and elevation above the xy
  plane, the lunar model's own measurement (:class:`gpf_nav.models.lunar.LunarDescentModel`).

A range-only message feeds the same sensor with the angles NaN (not measured).
"""
from __future__ import annotations

import numpy as np

from gpf_nav.models.frames import MoonRotation, Site
from gpf_nav.sensors.kinematic import noise_covariance
from gpf_nav.sensors.sensor import Sensor

_MIN_RANGE = 1.0  # m: floor of the range that keeps H finite with the vehicle at the station
_MIN_HORIZONTAL = 1e-3  # m: floor for the azimuth derivative at elevation +-pi/2
_WORLD_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


class StationSensor(Sensor):
    """Range (m), azimuth and elevation (rad) from a station (module docstring).

    Use :meth:`surface` or :meth:`inertial`.

    Args:
        position: ``(3,)`` the station, m: Moon-fixed with ``moon``, inertial without.
        axes: ``(3, 3)`` rows north, east, up, in the same frame as ``position``.
        moon: the Moon's rotation that carries the station, or None (fixed in inertial space).
        range_noise_std: m.
        angle_noise_std: rad.
        name: the sensor's name.
        position_index: the position components of the state.
    """

    dim = 3
    angular = np.array([False, True, True])
    orthogonal_jacobian_rows = True

    def __init__(self, position, axes, moon: MoonRotation | None, range_noise_std: float,
                 angle_noise_std: float, name: str = "station", position_index=(0, 1, 2)):
        self.position = np.asarray(position, dtype=float).reshape(3)
        self.axes = np.asarray(axes, dtype=float).reshape(3, 3)
        if not (np.all(np.isfinite(self.position)) and np.all(np.isfinite(self.axes))):
            raise ValueError(f"station {name!r}: position and axes must be finite")
        self.moon = moon
        self.name = name
        self.bias = None
        self.position_index = tuple(int(i) for i in position_index)
        self.measured_state_index = self.position_index
        self._R = noise_covariance([range_noise_std, angle_noise_std, angle_noise_std], 3)

    @classmethod
    def surface(cls, latitude: float, longitude: float, height: float, moon: MoonRotation,
                range_noise_std: float, angle_noise_std: float, name: str = "station",
                position_index=(0, 1, 2)) -> StationSensor:
        """A station on the Moon at ``latitude``, ``longitude`` (rad, east positive), ``height`` (m above
        the mean radius), measuring topocentric azimuth (from north towards east) and elevation."""
        site = Site(latitude, longitude, height)
        north_east_up = site.axes[[1, 0, 2]]
        return cls(site.position, north_east_up, moon, range_noise_std, angle_noise_std, name, position_index)

    @classmethod
    def inertial(cls, position, range_noise_std: float, angle_noise_std: float, name: str = "station",
                 position_index=(0, 1, 2)) -> StationSensor:
        """A station fixed at ``position`` ``(3,)`` in the world frame, azimuth ``atan2(dy, dx)`` (the lunar
        model's convention)."""
        return cls(position, _WORLD_AXES, None, range_noise_std, angle_noise_std, name, position_index)

    def visible(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """``(N,)`` bool: the vehicle is above the station's horizon (elevation > 0) at ``t``."""
        return self._local(x, t)[0][:, 2] > 0.0

    def _pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The station ``(3,)`` and its axes ``(3, 3)`` (rows north, east, up) in the inertial frame at ``t``."""
        if self.moon is None:
            return self.position, self.axes
        M = self.moon.fixed_to_inertial_matrix(t)
        return M @ self.position, self.axes @ M.T

    def _local(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The line of sight ``(N, 3)`` in the station's axes and those axes ``(3, 3)`` (inertial)."""
        s, axes = self._pose(t)
        return (x[:, list(self.position_index)] - s) @ axes.T, axes

    def measure(self, x, t=0.0):
        d = self._local(x, t)[0]
        horizontal = np.hypot(d[:, 0], d[:, 1])
        return np.stack([np.sqrt(horizontal ** 2 + d[:, 2] ** 2), np.arctan2(d[:, 1], d[:, 0]),
                         np.arctan2(d[:, 2], horizontal)], axis=1)

    def jacobian(self, x, t=0.0):
        return self.measure_and_jacobian(x, t)[1]

    def measure_and_jacobian(self, x, t=0.0):
        d, axes = self._local(x, t)
        n, e, u = d[:, 0], d[:, 1], d[:, 2]
        horizontal = np.hypot(n, e)
        rho = np.sqrt(horizontal ** 2 + u ** 2)
        h = np.stack([rho, np.arctan2(e, n), np.arctan2(u, horizontal)], axis=1)
        # derivatives with respect to the local line of sight (the lunar model's, in these axes), then
        # chained through the axes: d(local) / d(r) = axes
        hor = np.maximum(horizontal, _MIN_HORIZONTAL)
        inv_rho = 1.0 / np.maximum(rho, _MIN_RANGE)
        inv_h2 = 1.0 / (hor * hor)
        k = -u * inv_rho * inv_rho / hor
        local = np.zeros((x.shape[0], 3, 3))
        local[:, 0] = d * inv_rho[:, None]
        local[:, 1, 0], local[:, 1, 1] = -e * inv_h2, n * inv_h2
        local[:, 2, 0], local[:, 2, 1], local[:, 2, 2] = k * n, k * e, hor * inv_rho * inv_rho
        H = np.zeros((x.shape[0], 3, x.shape[1]))
        H[:, :, list(self.position_index)] = local @ axes
        return h, H

    def noise(self, t=0.0):
        return self._R
