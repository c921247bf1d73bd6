"""The simulator node's parameter schema: its own parameters, ``scenario.<field>`` for the
:class:`~gpf_nav.sim.scenario.ScenarioConfig` fields it exposes and ``suite.<field>`` for every
:class:`~gpf_nav.sim.sensor_suite.SuiteConfig` field (defaults taken from those classes, which check
them), and the rules that tie some of them together. No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import replace

from gpf_nav.schema import Spec, check
from gpf_nav.models.gravity import FIELDS
from gpf_nav.sim.scenario import CASES, ORBIT_DESIGNS, ScenarioConfig
from gpf_nav.sim.sensor_suite import SuiteConfig

_SCENARIO = "ScenarioConfig"
_SUITE = "SuiteConfig"

NODE = [
    Spec("seed", 0, "Scenario seed: same seed, same messages."),
    Spec("truth_csv", "", "Replay this CSV truth (t, x, y, z, vx, vy, vz[, ax, ay, az], SI) instead of generating one."),
    Spec("imu_rate", 10.0, "IMU rate (simulated time); 0 disables imu.", "Hz", ">= 0"),
    Spec("imu_noise_std", 1e-4, "IMU specific-force noise standard deviation per axis.", "m/s^2", ">= 0"),
    Spec("truth_rate", 10.0, "truth/odometry rate (simulated time; also at every measurement time).", "Hz", ">= 0"),
    Spec("publish_clock", True, "Publish /clock (simulated time); otherwise stamps follow the wall clock (start_time ignored)."),
    Spec("clock_rate", 50.0, "Wall-clock rate of the release loop (and of /clock).", "Hz", "> 0"),
    Spec("rate_factor", 1.0, "Simulated seconds per wall second (needs publish_clock when not 1).", bounds="> 0"),
    Spec("start_delay", 1.0, "Wall-clock wait before the trajectory starts, for subscribers to connect; /clock is held at start_time meanwhile.", "s", ">= 0"),
    Spec("start_time", -1.0, "ROS time of the trajectory start when publish_clock; negative: the wall-clock time then, so at rate_factor 1 stamps and /clock follow the wall clock (0 means 'unset' in ROS).", "s", "finite"),
    Spec("hand_over_prior", True, "Publish the scenario's prior (mean, covariance) on set_state at the start of the trajectory and of each lap, as a vehicle hands its pre-descent state over."),
    Spec("loop", False, "At the end of the trajectory: true restarts it (time keeps increasing); false exits."),
    Spec("world_frame", "moon_inertial", "frame_id of truth/odometry."),
    Spec("base_frame", "base_link", "child_frame_id of truth/odometry."),
    Spec("measurement_frame", "station", "frame_id of measurements/rae."),
    Spec("imu_frame", "base_link", "frame_id of imu."),
    Spec("station_names", None, "Surface stations on the rotating Moon, as the estimator's: each publishes measurements/rae with its name as header.frame_id at every measurement time it sees the vehicle (elevation > 0), besides the station's.", item="string"),
    Spec("station_lat_lon_height", None, "Latitude (rad), longitude (rad, east positive) and height (m above the mean radius) of each of station_names in turn, 3 numbers per station.", "rad, rad, m", "finite"),
    Spec("moon_epoch", 0.0, "The stamp (start_time + scenario time) at which the Moon-fixed x axis is world_frame's x axis: the surface stations turn with the Moon from there (the estimator's moon_epoch).", "s", "finite"),
]

SCENARIO = [  # name, description, unit, choices
    ("epsilon", "Truth gravity is mu (1 + epsilon).", "", ()),
    ("apolune_altitude", "Start (apolune) altitude.", "m", ()),
    ("perilune_altitude", "Planned perilune altitude.", "m", ()),
    ("inclination_deg", "Orbit inclination.", "deg", ()),
    ("orbit_design", "Gravity the start velocity is designed with.", "", ORBIT_DESIGNS),
    ("duration", "Trajectory length.", "s", ()),
    ("dt", "Measurement period (measurements/rae rate = 1/dt in simulated time).", "s", ()),
    ("truth_step", "Longest RK4 sub-step of the truth.", "s", ()),
    ("truth_accel_noise_density", "Truth white-acceleration density.", "m/s^1.5", ()),
    ("filter_accel_noise_density", "Unused by the simulator (the estimator's accel_noise_density).", "m/s^1.5", ()),
    ("range_noise_std", "Range noise standard deviation.", "m", ()),
    ("angle_noise_std", "Azimuth/elevation noise standard deviation.", "rad", ()),
    ("station", "Observer position in world_frame.", "m", ()),
    ("prior_position_std", "Prior position std the simulator logs.", "m", ()),
    ("prior_velocity_std", "Prior velocity std the simulator logs.", "m/s", ()),
    ("case", "full (range, azimuth, elevation), partial (azimuth never measured) or range (range only).", "", CASES),
    ("measurement_noise_scale", "Multiplies both measurement noise stds.", "", ()),
    ("dropout_probability", "Probability a whole measurement is lost.", "", ()),
    ("thrust", "Retrograde specific force magnitude; 0 = coasting.", "m/s^2", ()),
    ("disturbance", "Constant acceleration on the truth in world_frame that the IMU does not sense, like a gravity-field error.", "m/s^2", ()),
    ("truth_gravity", "Gravity field of the truth beyond the point mass (degree4 turns with the Moon, its x axis world_frame's at the trajectory start); never given to the estimator (its gravity_field).", "", FIELDS),
    ("thrust_drift_rate", "With thrust: rate at which its direction turns in the orbit plane from retrograde towards the radial.", "rad/s", ()),
    ("measurement_bias_sigma", "Constant error added to range, azimuth and elevation, in their noise standard deviations (the estimator's range_bias_std can estimate the range one).", "", ()),
]
"""The :class:`ScenarioConfig` fields the simulator exposes as ``scenario.<name>``."""

SUITE = {
    "altimeter_period": ("Altimeter period, a multiple of scenario.dt; 0 switches measurements/altitude off.", "s"),
    "altimeter_noise_std": ("Altimeter noise standard deviation.", "m"),
    "altimeter_max_altitude": ("The altimeter measures below this altitude.", "m"),
    "reference_radius": ("Radius of the altimeter's reference sphere.", "m"),
    "trn_period": ("Time between two TRN image captures (measurements/position), a multiple of scenario.dt; 0: off.", "s"),
    "trn_latency": ("Time from a TRN capture (the stamp) to the fix's publication.", "s"),
    "trn_noise_std": ("TRN fix noise standard deviation per axis (the message's covariance).", "m"),
    "trn_outlier_probability": ("Probability that a TRN fix is an outlier.", ""),
    "trn_outlier_size": ("An outlier's extra error, in trn_noise_std, in a random direction.", ""),
    "velocimeter_period": ("Velocimeter period, a multiple of scenario.dt; 0 switches measurements/velocity off.", "s"),
    "velocimeter_noise_std": ("Velocimeter noise standard deviation per axis (the message's covariance).", "m/s"),
    "velocimeter_max_altitude": ("The velocimeter measures below this altitude.", "m"),
}
"""Description and unit of every :class:`SuiteConfig` field, exposed as ``suite.<name>``."""


def _scenario_default(value):
    if value is None:  # thrust: None (coasting) is 0 on the node
        return 0.0
    return [float(v) for v in value] if isinstance(value, tuple) else value


def simulator_specs() -> list[Spec]:
    """The simulator's table: :data:`NODE`, then ``scenario.*`` and the sensor suite's ``suite.*``."""
    scenario, suite = ScenarioConfig(), SuiteConfig()
    return [
        *NODE,
        *(Spec("scenario." + name, _scenario_default(getattr(scenario, name)), description, unit, choices=choices,
               group="Scenario (gpf_nav.sim.scenario.ScenarioConfig; docs/scenario.md)", checked_by=_SCENARIO)
          for name, description, unit, choices in SCENARIO),
        *(replace(spec, group="Sensor suite (gpf_nav.sim.sensor_suite.SuiteConfig)") for spec in [
            Spec("publish_suite", False, "Also publish the sensor suite (suite.*): measurements/altitude, measurements/position (TRN, late by suite.trn_latency) and measurements/velocity."),
            Spec("altimeter_frame", "base_link", "frame_id of measurements/altitude."),
            *(Spec("suite." + name, float(getattr(suite, name)), description, unit, checked_by=_SUITE)
              for name, (description, unit) in SUITE.items())]),
    ]


def check_simulator_parameters(p: dict) -> list[str]:
    """Errors in the simulator's own parameters (the scenario's and the suite's are their classes' to check)."""
    errors = check(NODE, p)
    names, values = p["station_names"] or [], p["station_lat_lon_height"] or []
    if len(values) != 3 * len(names):
        errors.append(f"parameter 'station_lat_lon_height' has {len(values)} numbers; 'station_names' names "
                      f"{len(names)} station(s), 3 numbers each")
    if any(abs(lat) > math.pi / 2 for lat in values[::3]):
        errors.append("parameter 'station_lat_lon_height': a latitude must lie in [-pi/2, pi/2] rad")
    repeated = sorted({n for n in names if names.count(n) > 1} | set(names) & {p["measurement_frame"]})
    if repeated:
        errors.append(f"station name(s) {', '.join(repeated)} given more than once or equal to measurement_frame")
    if names and p["loop"]:
        errors.append("parameter 'station_names' with loop: true: the surface stations' measurements are drawn "
                      "for the first lap only (the Moon has turned further in the next)")
    if not p["publish_clock"] and p["rate_factor"] != 1.0:
        errors.append("parameter 'rate_factor' != 1 needs publish_clock: true (stamps would run ahead "
                      "of the wall clock)")
    return errors
