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

:func:`scenario_stations` gives the sensors and data of a scenario's own ``surface_stations`` (the
campaigns' surface conditions): the Moon-fixed frame's epoch is the scenario's start, the time a filter
initialised there counts from.
"""
from __future__ import annotations

import numpy as np

from gpf_nav.models.frames import MoonRotation
from gpf_nav.models.state_space import wrap_angle
from gpf_nav.sensors.station import StationSensor
from gpf_nav.sim.scenario import Scenario, ScenarioConfig

_STATION_ENTROPY = 0x57A7_1038
"""Mixed with the scenario seed: the stations' streams differ from the scenario's and the suite's."""


def surface_measurements(scenario: Scenario, stations: dict[str, tuple[float, float, float]],
                         moon_epoch: float, start_stamp: float, seed: int) -> dict[str, np.ndarray]:
    """``{name: (K, 3)}`` range (m), azimuth and elevation (rad) of each station at ``scenario.times``
    (module docstring); NaN rows where the vehicle is below the station's horizon."""
    config = scenario.config
    std = np.array([config.range_noise_std, config.angle_noise_std, config.angle_noise_std]) \
        * config.measurement_noise_scale
    stamps = start_stamp + (scenario.times - scenario.start_time)
    truth = scenario.truth[1:]
    out = {}
    for i, (name, sensor) in enumerate(station_sensors(config, stations, moon_epoch).items()):
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


def station_sensors(config: ScenarioConfig, stations: dict[str, tuple[float, float, float]],
                    moon_epoch: float) -> dict[str, StationSensor]:
    """``{name: sensor}`` of each station of ``stations`` (name -> latitude, longitude, height) on the Moon
    turning from ``moon_epoch``, with the scenario's noise (times ``measurement_noise_scale``)."""
    moon = MoonRotation(moon_epoch)
    scale = config.measurement_noise_scale
    return {name: StationSensor.surface(lat, lon, height, moon, config.range_noise_std * scale,
                                        config.angle_noise_std * scale, name=name)
            for name, (lat, lon, height) in stations.items()}


def scenario_stations(scenario: Scenario, seed: int) -> list[tuple[StationSensor, np.ndarray]]:
    """``[(sensor, measurements (K, 3))]`` of each of ``scenario.config.surface_stations`` (named
    ``beacon_1``, ``beacon_2``... in turn), the Moon turning from the scenario's start; ``seed`` is the
    scenario's. Empty when the scenario has none."""
    config = scenario.config
    values = config.surface_stations
    table = {f"beacon_{i // 3 + 1}": tuple(values[i:i + 3]) for i in range(0, len(values), 3)}
    sensors = station_sensors(config, table, 0.0)
    data = surface_measurements(scenario, table, 0.0, 0.0, seed)
    return [(sensors[name], data[name]) for name in table]
