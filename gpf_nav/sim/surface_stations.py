"""Surface stations of the simulator: range, azimuth and elevation from beacons on the rotating Moon.

:func:`surface_measurements` draws, for a :class:`~gpf_nav.sim.scenario.Scenario`, what each station of a
table (name, latitude, longitude, height, as the estimator's ``station_names`` and
``station_lat_lon_height``) measures at the scenario's measurement times with
:class:`gpf_nav.sensors.station.StationSensor`: topocentric azimuth and elevation, the station turning
with the Moon (:class:`gpf_nav.models.frames.MoonRotation` at ``moon_epoch``, on the scale of the
stamps: ``start_stamp`` is the stamp of the scenario's start). The noise is the scenario's (its range and
angle standard deviations times ``measurement_noise_scale``), drawn from a stream of each station's own
(seeded by the scenario seed and the station's place in the table), so the scenario's data do not change
with the stations. Below a station's horizon (elevation <= 0) there is no measurement (a NaN row).
"""
from __future__ import annotations

import numpy as np

from gpf_nav.models.frames import MoonRotation
from gpf_nav.models.state_space import wrap_angle
from gpf_nav.sensors.station import StationSensor
from gpf_nav.sim.scenario import Scenario

_STATION_ENTROPY = 0x57A7_1038
"""Mixed with the scenario seed: the stations' streams differ from the scenario's and the suite's."""


def surface_measurements(scenario: Scenario, stations: dict[str, tuple[float, float, float]],
                         moon_epoch: float, start_stamp: float, seed: int) -> dict[str, np.ndarray]:
    """``{name: (K, 3)}`` range (m), azimuth and elevation (rad) of each station at ``scenario.times``
    (module docstring); NaN rows where the vehicle is below the station's horizon."""
    config = scenario.config
    moon = MoonRotation(moon_epoch)
    std = np.array([config.range_noise_std, config.angle_noise_std, config.angle_noise_std]) \
        * config.measurement_noise_scale
    stamps = start_stamp + (scenario.times - scenario.start_time)
    truth = scenario.truth[1:]
    out = {}
    for i, (name, (lat, lon, height)) in enumerate(stations.items()):
        sensor = StationSensor.surface(lat, lon, height, moon, std[0], std[1], name=name)
        noise = np.random.default_rng(np.random.SeedSequence([int(seed), _STATION_ENTROPY, i])).standard_normal(
            (len(stamps), 3)) * std
        y = np.full((len(stamps), 3), np.nan)
        for k, t in enumerate(stamps.tolist()):
            x = truth[k:k + 1]
            if sensor.visible(x, t)[0]:
                y[k] = sensor.measure(x, t)[0] + noise[k]
        y[:, 1] = wrap_angle(y[:, 1])
        out[name] = y
    return out
