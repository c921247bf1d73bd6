"""The estimator's Moon frames and named stations from its parameters. No ROS here.

* :class:`MoonFrames`: world_frame (inertial), moon_fixed_frame (:class:`gpf_nav.models.frames.MoonRotation`
  at ``moon_epoch``) and site_frame (:class:`gpf_nav.models.frames.Site` at ``site_latitude``,
  ``site_longitude``, ``site_height``): a position fix in any of them is turned into world_frame, and the
  transforms ``world -> moon_fixed -> site`` at any time are what the node publishes on TF.
* :func:`station_sensors`: the stations of the parameter tables, a
  :class:`gpf_nav.sensors.station.StationSensor` per name. ROS parameters cannot be nested mappings, so a
  table is two parallel lists: ``station_names`` with ``station_lat_lon_height`` (three numbers per
  name), ``inertial_station_names`` with ``inertial_station_positions``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gpf_nav.models.frames import MoonRotation, Site
from gpf_nav.sensors.station import StationSensor


@dataclass(frozen=True)
class MoonFrames:
    """The frames a position may be given in, by name, and the transforms between them."""

    world: str
    moon_fixed: str
    site_frame: str
    moon: MoonRotation
    site: Site

    @classmethod
    def from_parameters(cls, p: dict) -> MoonFrames:
        return cls(p["world_frame"], p["moon_fixed_frame"], p["site_frame"], MoonRotation(p["moon_epoch"]),
                   Site(p["site_latitude"], p["site_longitude"], p["site_height"]))

    @property
    def names(self) -> tuple[str, str, str]:
        return self.world, self.moon_fixed, self.site_frame

    def position_to_world(self, frame: str, position: np.ndarray, covariance: np.ndarray,
                          t: float) -> tuple[np.ndarray, np.ndarray]:
        """A position ``(3,)`` and its covariance ``(3, 3)`` given in ``frame`` (one of :attr:`names`) at
        ``t`` s, in world_frame: ``origin + R p``, ``R C R^T``."""
        origin, R = self.pose(frame, t)
        return origin + R @ position, R @ covariance @ R.T

    def pose(self, frame: str, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(origin (3,), R (3, 3))`` of ``frame`` in world_frame at ``t``: ``r_world = origin + R r_frame``."""
        if frame == self.world:
            return np.zeros(3), np.eye(3)
        if frame == self.moon_fixed:
            return np.zeros(3), self.moon.fixed_to_inertial_matrix(t)
        if frame == self.site_frame:
            return self.site.inertial_pose(self.moon, t)
        raise ValueError(f"unknown frame {frame!r}")

    def transforms(self, t: float) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
        """``(parent, child, translation (3,), R (3, 3))`` of ``world -> moon_fixed`` (a turn about z) and
        ``moon_fixed -> site`` (constant) at ``t``: a child's coordinates ``c`` are ``translation + R c`` in
        its parent's, as a TF transform says."""
        return [(self.world, self.moon_fixed, np.zeros(3), self.moon.fixed_to_inertial_matrix(t)),
                (self.moon_fixed, self.site_frame, self.site.position, self.site.axes.T)]


def station_errors(p: dict) -> list[str]:
    """Errors of the station tables: lengths, names repeated or taken by another frame."""
    errors = []
    names = []
    for names_key, values_key in (("station_names", "station_lat_lon_height"),
                                  ("inertial_station_names", "inertial_station_positions")):
        given, values = p[names_key] or [], p[values_key] or []
        if len(values) != 3 * len(given):
            errors.append(f"parameter '{values_key}' has {len(values)} numbers; '{names_key}' names "
                          f"{len(given)} station(s), 3 numbers each")
        names += given
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        errors.append(f"station name(s) {', '.join(repeated)} given more than once")
    taken = sorted(set(names) & {p["measurement_frame"], p["world_frame"], p["moon_fixed_frame"], p["site_frame"]})
    if taken:
        errors.append(f"station name(s) {', '.join(taken)} also name measurement_frame or a frame")
    latitudes = (p["station_lat_lon_height"] or [])[::3]
    if any(abs(lat) > np.pi / 2 for lat in latitudes):
        errors.append("parameter 'station_lat_lon_height': a latitude must lie in [-pi/2, pi/2] rad")
    return errors


def station_sensors(p: dict, model) -> dict[str, StationSensor]:
    """``{name: sensor}`` of the stations of the parameter tables (module docstring), with the model's
    range and angle noise and position components; the parameters checked by :func:`station_errors`."""
    moon = MoonRotation(p["moon_epoch"])
    noise = dict(range_noise_std=p["range_noise_std"], angle_noise_std=p["angle_noise_std"],
                 position_index=tuple(model.position_index))
    sensors = {}
    for name, (lat, lon, height) in zip(p["station_names"] or [],
                                        np.reshape(p["station_lat_lon_height"] or [], (-1, 3)).tolist()):
        sensors[name] = StationSensor.surface(lat, lon, height, moon, name=name, **noise)
    for name, position in zip(p["inertial_station_names"] or [],
                              np.reshape(p["inertial_station_positions"] or [], (-1, 3))):
        sensors[name] = StationSensor.inertial(position, name=name, **noise)
    return sensors
