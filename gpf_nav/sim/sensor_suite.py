"""The descent's sensor suite beyond ground tracking: altimeter, terrain-relative navigation, velocimeter.

:func:`generate_suite` draws, for a :class:`~gpf_nav.sim.scenario.Scenario`, the data of three sensors on
the scenario's time grid (SI units, world frame), each with its own rate, noise and availability:

* an altimeter: altitude above the sphere of radius ``reference_radius``, available below
  ``altimeter_max_altitude``;
* terrain-relative navigation (TRN): a position fix every ``trn_period`` s, stamped at the capture of
  its image and delivered ``trn_latency`` s later; with probability ``trn_outlier_probability`` a fix is
  an outlier, off by ``trn_outlier_size`` sigmas in a random direction;
* a velocimeter (Doppler lidar): the velocity, available below ``velocimeter_max_altitude``.

A period of 0 switches a sensor off. The draws come from streams of their own (seeded by the scenario
seed), so the scenario's range/azimuth/elevation, prior and truth do not change with the suite.
:func:`suite_sensors` gives the matching :mod:`gpf_nav.sensors` objects.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from gpf_nav.models.lunar import MOON_RADIUS
from gpf_nav.sim.scenario import Scenario
from gpf_nav.sensors import AltitudeSensor, PositionSensor, Sensor, VelocitySensor

_SUITE_ENTROPY = 0x5E45_0118
"""Mixed with the scenario seed: the suite's streams differ from the scenario's."""


@dataclass(frozen=True)
class SuiteConfig:
    """Rates, noises and availability of the suite (SI units; periods are multiples of the scenario's
    ``dt``, 0 switches a sensor off).

    Attributes:
        altimeter_period: s between two altitudes.
        altimeter_noise_std: m.
        altimeter_max_altitude: the altimeter measures below this altitude, m.
        reference_radius: radius of the altimeter's reference sphere, m (the Moon's mean radius).
        trn_period: s between two TRN image captures.
        trn_latency: s from capture (the stamp) to delivery.
        trn_noise_std: m, per axis.
        trn_outlier_probability: probability that a fix is an outlier.
        trn_outlier_size: an outlier's extra error, in ``trn_noise_std``, random direction.
        velocimeter_period: s between two velocities.
        velocimeter_noise_std: m/s, per axis.
        velocimeter_max_altitude: the velocimeter measures below this altitude, m.
    """

    altimeter_period: float = 2.0
    altimeter_noise_std: float = 20.0
    altimeter_max_altitude: float = 60e3
    reference_radius: float = MOON_RADIUS
    trn_period: float = 10.0
    trn_latency: float = 4.0
    trn_noise_std: float = 50.0
    trn_outlier_probability: float = 0.05
    trn_outlier_size: float = 20.0
    velocimeter_period: float = 2.0
    velocimeter_noise_std: float = 0.1
    velocimeter_max_altitude: float = 40e3

    def __post_init__(self):
        values = dataclasses.asdict(self)
        if not all(math.isfinite(v) and v >= 0.0 for v in values.values()):
            raise ValueError(f"suite settings must be finite and non-negative: {values}")
        if min(self.altimeter_noise_std, self.trn_noise_std, self.velocimeter_noise_std) <= 0.0:
            raise ValueError("suite noise standard deviations must be positive")
        if self.trn_outlier_probability > 1.0:
            raise ValueError("trn_outlier_probability must lie in [0, 1]")

    @classmethod
    def from_dict(cls, data: dict) -> SuiteConfig:
        """Build from a dict of (a subset of) the fields, values numbers or their text; ValueError for
        an unknown key or a value that is not a number."""
        unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"unknown sensor-suite keys {sorted(unknown)}; known: "
                             f"{', '.join(f.name for f in dataclasses.fields(cls))}")
        values = {}
        for key, value in data.items():
            try:
                values[key] = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"sensor-suite {key} = {value!r} is not a number") from None
        return cls(**values)

    def check_grid(self, dt: float) -> None:
        """ValueError unless every period is a multiple of the step ``dt`` (or 0)."""
        for period in (self.altimeter_period, self.trn_period, self.velocimeter_period):
            _every(period, dt, 1)


@dataclass
class SuiteData:
    """The suite's measurements of one scenario, on its grid: row ``k`` is taken at ``scenario.times[k]``
    (NaN rows: no measurement).

    Attributes:
        altitude: ``(K, 1)`` m.
        position: ``(K, 3)`` TRN fixes, m, stamped at capture ``times[k]``.
        position_arrival: ``(K,)`` delivery time of each fix, s (NaN without a fix).
        position_outlier: ``(K,)`` bool, the fixes that are outliers.
        velocity: ``(K, 3)`` m/s.
        config: the suite's settings.
    """

    altitude: np.ndarray
    position: np.ndarray
    position_arrival: np.ndarray
    position_outlier: np.ndarray
    velocity: np.ndarray
    config: SuiteConfig


def _every(period: float, dt: float, steps: int) -> np.ndarray:
    """``(steps,)`` bool: the grid steps ``k`` (at ``(k + 1) dt``) on which a sensor of ``period`` s
    measures; none for period 0. ValueError unless ``period`` is a multiple of ``dt``."""
    if period == 0.0:
        return np.zeros(steps, bool)
    every = round(period / dt)
    if every < 1 or abs(every * dt - period) > 1e-9 * max(period, 1.0):
        raise ValueError(f"a sensor period ({period} s) must be a multiple of the step dt = {dt} s")
    return (np.arange(1, steps + 1) % every) == 0


def generate_suite(scenario: Scenario, config: SuiteConfig, seed: int) -> SuiteData:
    """Draw the suite's data of ``scenario`` (module docstring); the same seed gives the same arrays."""
    alt_rng, trn_rng, outlier_rng, vel_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence([int(seed), _SUITE_ENTROPY]).spawn(4))
    steps, dt = scenario.times.shape[0], scenario.config.dt
    truth = scenario.truth[1:]
    radius = np.linalg.norm(truth[:, :3], axis=1)
    altitude = radius - MOON_RADIUS

    alt = ((radius - config.reference_radius)[:, None]
           + config.altimeter_noise_std * alt_rng.standard_normal((steps, 1)))
    alt[~(_every(config.altimeter_period, dt, steps) & (altitude < config.altimeter_max_altitude))] = np.nan

    fix = truth[:, :3] + config.trn_noise_std * trn_rng.standard_normal((steps, 3))
    hit, direction = outlier_rng.random(steps), outlier_rng.standard_normal((steps, 3))
    outlier = hit < config.trn_outlier_probability
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    fix[outlier] += config.trn_outlier_size * config.trn_noise_std * direction[outlier]
    captured = _every(config.trn_period, dt, steps)
    fix[~captured] = np.nan
    arrival = np.where(captured, scenario.times + config.trn_latency, np.nan)

    vel = truth[:, 3:] + config.velocimeter_noise_std * vel_rng.standard_normal((steps, 3))
    vel[~(_every(config.velocimeter_period, dt, steps) & (altitude < config.velocimeter_max_altitude))] = np.nan
    return SuiteData(altitude=alt, position=fix, position_arrival=arrival, position_outlier=outlier & captured,
                     velocity=vel, config=config)


def suite_sensors(config: SuiteConfig) -> dict[str, Sensor]:
    """The sensors of the suite's data: ``{"altitude", "position", "velocity"}``."""
    return {"altitude": AltitudeSensor(config.altimeter_noise_std, config.reference_radius),
            "position": PositionSensor(config.trn_noise_std),
            "velocity": VelocitySensor(config.velocimeter_noise_std)}
