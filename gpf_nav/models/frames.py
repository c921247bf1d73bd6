"""The rotating Moon's frames: Moon-centred inertial, Moon-fixed, and a site's east-north-up frame.

* Inertial (``moon_inertial``, the state's frame): Moon-centred, z the Moon's pole.
* Moon-fixed (``moon_fixed``): the same origin and z axis, turning about z at ``rate`` rad/s
  (:data:`gpf_nav.models.gravity.MOON_ROTATION_RATE`, IAU); its x axis is the inertial x axis at the time
  ``epoch``, so it has turned by ``rate * (t - epoch)`` at ``t``: the convention of
  :class:`gpf_nav.models.gravity.GravityField`. ``rate`` 0 is the paper's Moon, which does not turn.
* A site (``map`` by REP 105): east, north, up at a spherical latitude, longitude (east positive) and
  height above :data:`gpf_nav.models.lunar.MOON_RADIUS`, fixed on the Moon.

Positions and velocities are ``(3,)`` or ``(N, 3)`` (one per row). A velocity in a turning frame is the
velocity seen there, ``v_fixed = R (v - omega x r)``. No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gpf_nav.models.gravity import MOON_ROTATION_RATE
from gpf_nav.models.lunar import MOON_RADIUS


def _rotation_z(angle: float) -> np.ndarray:
    """``(3, 3)`` rotation by ``angle`` about z: the matrix turning a frame's coordinates into those of the
    frame it is turned by ``angle`` from."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class MoonRotation:
    """The Moon-fixed frame's uniform rotation about the inertial z axis.

    Attributes:
        epoch: the time at which the Moon-fixed x axis is the inertial x axis, s (the scale of ``t``).
        rate: the rotation rate, rad/s (0: a Moon that does not turn).
    """

    epoch: float = 0.0
    rate: float = MOON_ROTATION_RATE

    @property
    def omega(self) -> np.ndarray:
        """The rotation vector ``(3,)``, rad/s, in either frame (it is along their common z axis)."""
        return np.array([0.0, 0.0, self.rate])

    def angle(self, t: float) -> float:
        """The angle the Moon-fixed frame has turned from the inertial one at ``t``, rad."""
        return self.rate * (float(t) - self.epoch)

    def fixed_to_inertial_matrix(self, t: float) -> np.ndarray:
        """``(3, 3)`` ``R`` with ``r_inertial = R r_fixed`` at ``t`` (its columns: the Moon-fixed axes)."""
        return _rotation_z(self.angle(t))

    def to_fixed(self, r, v=None, t: float = 0.0):
        """Inertial position ``r`` (and velocity ``v``) at ``t`` in the Moon-fixed frame: ``r_f`` or
        ``(r_f, v_f)``, ``v_f = R^T (v - omega x r)``."""
        R = self.fixed_to_inertial_matrix(t)
        r = np.asarray(r, dtype=float)
        r_fixed = r @ R
        if v is None:
            return r_fixed
        return r_fixed, (np.asarray(v, dtype=float) - np.cross(self.omega, r)) @ R

    def to_inertial(self, r_fixed, v_fixed=None, t: float = 0.0):
        """Moon-fixed position (and velocity) at ``t`` in the inertial frame: ``r`` or ``(r, v)``,
        ``v = R v_f + omega x r``."""
        R = self.fixed_to_inertial_matrix(t)
        r = np.asarray(r_fixed, dtype=float) @ R.T
        if v_fixed is None:
            return r
        return r, np.asarray(v_fixed, dtype=float) @ R.T + np.cross(self.omega, r)


def surface_position(latitude: float, longitude: float, height: float = 0.0,
                     radius: float = MOON_RADIUS) -> np.ndarray:
    """Moon-fixed position ``(3,)`` of spherical ``latitude``, ``longitude`` (rad, east positive) and
    ``height`` above the sphere of ``radius``, m."""
    c = math.cos(latitude)
    return (radius + height) * np.array([c * math.cos(longitude), c * math.sin(longitude), math.sin(latitude)])


def enu_axes(latitude: float, longitude: float) -> np.ndarray:
    """``(3, 3)`` whose rows are the local east, north and up unit vectors at ``latitude``, ``longitude``
    in Moon-fixed coordinates: ``d_enu = E d_fixed``. Up is the sphere's normal (spherical latitude);
    at a pole, north is along the longitude's meridian and east normal to it."""
    sl, cl = math.sin(latitude), math.cos(latitude)
    so, co = math.sin(longitude), math.cos(longitude)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


@dataclass(frozen=True)
class Site:
    """A frame fixed on the Moon: origin at ``latitude``, ``longitude`` (rad, east positive), ``height``
    (m above :data:`MOON_RADIUS`), axes east, north, up (REP 103's x east, y north, z up).

    Attributes:
        position: ``(3,)`` its origin, Moon-fixed, m.
        axes: ``(3, 3)`` :func:`enu_axes` (rows east, north, up in Moon-fixed coordinates).
    """

    latitude: float
    longitude: float
    height: float = 0.0
    position: np.ndarray = field(init=False, repr=False, compare=False)
    axes: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if not all(math.isfinite(v) for v in (self.latitude, self.longitude, self.height)):
            raise ValueError(f"a site's latitude, longitude and height must be finite, got "
                             f"{(self.latitude, self.longitude, self.height)}")
        if abs(self.latitude) > math.pi / 2:
            raise ValueError(f"a site's latitude must lie in [-pi/2, pi/2] rad, got {self.latitude}")
        object.__setattr__(self, "position", surface_position(self.latitude, self.longitude, self.height))
        object.__setattr__(self, "axes", enu_axes(self.latitude, self.longitude))

    def inertial_pose(self, moon: MoonRotation, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(origin (3,), R (3, 3))`` of the site in the inertial frame at ``t``: ``r = origin + R r_site``
        (the columns of ``R`` are east, north, up in inertial coordinates)."""
        M = moon.fixed_to_inertial_matrix(t)
        return M @ self.position, M @ self.axes.T

    def from_inertial(self, moon: MoonRotation, r, v=None, t: float = 0.0):
        """Inertial position (and velocity) at ``t`` in the site frame: ``r_s`` or ``(r_s, v_s)``, the
        velocity relative to the turning ground."""
        if v is None:
            return (moon.to_fixed(r, t=t) - self.position) @ self.axes.T
        r_fixed, v_fixed = moon.to_fixed(r, v, t)
        return (r_fixed - self.position) @ self.axes.T, v_fixed @ self.axes.T

    def to_inertial(self, moon: MoonRotation, r_site, v_site=None, t: float = 0.0):
        """Site-frame position (and velocity relative to the ground) at ``t`` in the inertial frame."""
        r_fixed = np.asarray(r_site, dtype=float) @ self.axes + self.position
        if v_site is None:
            return moon.to_inertial(r_fixed, t=t)
        return moon.to_inertial(r_fixed, np.asarray(v_site, dtype=float) @ self.axes, t)
