"""Parameters of the two nodes: names, defaults, units and descriptions in one table each.

``config/estimator.yaml`` and ``config/simulator.yaml`` repeat the defaults (a test checks they agree).
:func:`gpf_nav.ros.parameters.declare` declares a table on a node and :func:`coerce` converts each value
to the default's type; a value of the wrong type raises :class:`ParameterError` naming the parameter.
No parameter may be changed at run time except those marked ``live``. No ROS here.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from gpf_nav.models.lunar import MU_MOON


class ParameterError(ValueError):
    """An invalid parameter value; the message names the parameter and says what is allowed."""


@dataclass(frozen=True)
class Spec:
    name: str
    default: object      # None: optional double array with no default (``initial_state``)
    description: str
    live: bool = False   # may be changed at run time with ros2 param set


ESTIMATOR = [
    # filter
    Spec("filter", "gpf", "Filter: gpf (geometric projection PF, multiple model: nominal or compensated), gpf-single (one compensated GPF), gpf-mm (= gpf), spf (bootstrap PF), ekf, ukf or enkf."),
    Spec("n_particles", 500, "Number of particles / ensemble members N (gpf, spf, enkf); integer >= 1 (>= 2 for enkf)."),
    Spec("seed", 0, "Seed of the filter's random stream; negative: a random seed."),
    Spec("reference", "innovation", "GPF projection reference: innovation or increment."),
    Spec("weighting", "corrected", "GPF weighting: corrected (exact proposal correction) or likelihood (paper)."),
    Spec("metric", "cloud", "GPF projection metric: cloud (predicted cloud's covariance; navigation default), euclidean (paper) or process_noise (metric of Q(dt))."),
    Spec("regularization", 0.0, "Tikhonov eps of the projection, >= 0; 0: the metric's default (1 for cloud, 1e-6 otherwise); relative for euclidean, in measurement-noise units otherwise."),
    Spec("unmodelled_acceleration_std", 0.1, "gpf: stationary std of the estimated unmodelled acceleration [m/s^2]; 0 turns the compensation off."),
    Spec("unmodelled_acceleration_time", 1.0e6, "gpf: correlation time of the unmodelled acceleration [s], > 0."),
    Spec("nominal_prior", 0.5, "gpf-single: prior probability that the model needs no unmodelled acceleration; the estimate averages the two hypotheses; 0 publishes the compensated posterior as it is; in [0, 1)."),
    Spec("model_switch_time", 2.0e5, "gpf: mean sojourn time of the nominal / compensated model chain [s], > 0."),
    Spec("kernel_bandwidth", 0.0, "gpf, cloud metric: kernel bandwidth h in (0, 1); 0: the default, 1.6 times the Gaussian-optimal one for N and the state dimension (at most 0.95)."),
    Spec("collapse_steps", 0, "gpf/spf: re-initialise after this many consecutive updates with ESS < 1.5 particles; 0 never."),
    Spec("resampling", "systematic", "Resampling scheme: systematic, stratified, residual or multinomial."),
    Spec("ess_threshold", 0.5, "tau in (0, 1]: resample when ESS < tau N."),
    Spec("compute_costate", True, "spf only: also compute the diagnostic co-state (costs one projection)."),
    Spec("ukf_alpha", 1e-3, "UKF sigma-point spread alpha > 0."),
    Spec("ukf_beta", 2.0, "UKF beta."),
    Spec("ukf_kappa", 0.0, "UKF kappa, n + kappa > 0."),
    # model
    Spec("mu", MU_MOON, "Gravitational parameter the filter assumes [m^3/s^2]."),
    Spec("station", [0.0, 0.0, 0.0], "Observer position in world_frame [m] (x, y, z)."),
    Spec("range_noise_std", 30.0, "Range noise standard deviation [m]."),
    Spec("angle_noise_std", math.radians(0.03), "Azimuth/elevation noise standard deviation [rad]."),
    Spec("accel_noise_density", 1e-3, "Process-noise white-acceleration density [m/s^1.5]."),
    Spec("max_step", 10.0, "Longest integration sub-step of the model [s]."),
    # frames
    Spec("world_frame", "moon_inertial", "Frame of the state and of odometry header.frame_id (Moon-centred inertial)."),
    Spec("base_frame", "base_link", "odometry child_frame_id (axes taken aligned with world_frame)."),
    Spec("measurement_frame", "station", "Required header.frame_id of measurements/rae and measurements/range ('' = any); measurements/position and measurements/velocity must be in world_frame."),
    Spec("imu_frame", "base_link", "Required header.frame_id of imu ('' = any)."),
    # initialisation
    Spec("initial_state", None, "Initial [x, y, z, vx, vy, vz] in world_frame [m, m/s]; unset: set_state, set_pose or measurements."),
    Spec("initial_std", [1e3, 1e3, 1e3, 1.0, 1.0, 1.0], "Initial standard deviations [m, m, m, m/s, m/s, m/s]."),
    Spec("initial_stamp", -1.0, "ROS time of initial_state [s]; negative: the first accepted measurement's stamp."),
    Spec("init_window", 10, "Measurements used to initialise from the data when no initial state is given (>= 2)."),
    # timing and input handling
    Spec("publish_rate", 10.0, "Rate of predicted odometry between measurements [Hz, node clock]; 0 disables."),
    Spec("max_future", 1.0, "Refuse stamps more than this ahead of the node clock [s]."),
    Spec("imu_timeout", 1.0, "An IMU sample older than this (relative to the measurement) is not used [s]."),
    Spec("max_extrapolation", 300.0, "Do not publish predictions more than this past the last measurement [s]."),
    Spec("max_measurement_rate", 1000.0, "Process at most this many measurements per second (steady clock) [Hz]; 0: unlimited."),
    Spec("queue_depth", 10, "Depth of the sensor-data (best-effort) subscription queues."),
    Spec("quaternion_tolerance", 0.01, "Allowed | |q| - 1 | of an IMU orientation."),
    # sensors beyond the model's own measurement, late measurements, biases
    Spec("history_length", 10.0, "A measurement stamped up to this long before the filter's time is fused at its stamp (the later inputs are re-applied); older ones are refused [s]; 0: none."),
    Spec("altitude_frame", "base_link", "Required header.frame_id of measurements/altitude ('' = any)."),
    Spec("altitude_noise_std", 20.0, "Altitude (measurements/altitude) noise standard deviation [m]."),
    Spec("reference_radius", 1737.4e3, "Radius of the sphere measurements/altitude is measured above [m] (the Moon's mean radius)."),
    Spec("position_gate", 0.9999, "Innovation gate of measurements/position: chi-square probability (3 dof), in [0, 1); 0: no gate."),
    Spec("velocity_gate", 0.9999, "Innovation gate of measurements/velocity: chi-square probability (3 dof), in [0, 1); 0: no gate."),
    Spec("altitude_gate", 0.9999, "Innovation gate of measurements/altitude: chi-square probability (1 dof), in [0, 1); 0: no gate."),
    Spec("gate_limit", 5, "After this many refusals of a gate in a row the next measurement of that stream is used; >= 0."),
    Spec("range_bias_std", 0.0, "Estimate a range bias (rae and range) of this prior std [m]; 0: none."),
    Spec("range_bias_time", 0.0, "Correlation time of the range bias [s] (first-order Gauss-Markov); 0: a random constant."),
    Spec("position_bias_std", 0.0, "Estimate a bias per axis of measurements/position of this prior std [m]; 0: none."),
    Spec("position_bias_time", 0.0, "Correlation time of the position bias [s]; 0: a random constant."),
    Spec("velocity_bias_std", 0.0, "Estimate a bias per axis of measurements/velocity of this prior std [m/s]; 0: none."),
    Spec("velocity_bias_time", 0.0, "Correlation time of the velocity bias [s]; 0: a random constant."),
    Spec("altitude_bias_std", 0.0, "Estimate a bias of measurements/altitude of this prior std [m]; 0: none."),
    Spec("altitude_bias_time", 0.0, "Correlation time of the altitude bias [s]; 0: a random constant."),
    # outputs and diagnostics
    Spec("max_published_particles", 100, "Particles published on gpf/particles (systematic selection); 0 disables."),
    Spec("diagnostics_period", 1.0, "Period of /diagnostics [s, steady clock]."),
    Spec("ess_warn_threshold", 0.05, "WARN when ESS/N falls below this.", live=True),
    Spec("costate_warn_threshold", 50.0, "WARN when the mean co-state norm exceeds this [1/s with the cloud and process_noise metrics (whitened; about 1 nominally), m^2/s with euclidean].", live=True),
    Spec("sensor_timeout", 10.0, "WARN when no measurement was accepted for this long [s, node clock].", live=True),
    Spec("reinit_hold", 10.0, "Diagnostics stay ERROR this long after a re-initialisation [s, steady clock]."),
    # integrity monitor (gpf_nav.integrity.CostateMonitor on the co-state; gpf, and spf with compute_costate)
    Spec("monitor_enabled", True, "Run the co-state integrity monitor: WARN/ERROR in /diagnostics on a biased co-state (gpf, spf with compute_costate)."),
    Spec("monitor_window", 10, "Monitor: updates per window mean (the test window and each reference window); >= 1."),
    Spec("monitor_reference", 20, "Monitor: largest number of reference windows kept; >= monitor_min_reference."),
    Spec("monitor_min_reference", 6, "Monitor: reference windows needed before testing (ready after (this + 1) * (window + gap) updates); >= 2."),
    Spec("monitor_gap", 2, "Monitor: updates skipped between windows (decorrelation guard); >= 0."),
    Spec("monitor_false_alarm_rate", 1e-3, "Monitor: per-update probability of FAULT (diagnostics ERROR) on a consistent filter, in (0, 1)."),
    Spec("monitor_warn_false_alarm_rate", 1e-2, "Monitor: per-update probability of WARN or worse on a consistent filter, in [monitor_false_alarm_rate, 1)."),
    Spec("monitor_quarantine_rate", -1.0, "Monitor: p-value below which a window is kept out of the reference; negative: monitor_false_alarm_rate / 100; 0: no quarantine."),
    Spec("monitor_hold", 5.0, "A monitor WARN or FAULT stays in /diagnostics this long after the update that raised it [s, steady clock]; negative: latched until ~/reset or a re-initialisation."),
    # node only (gpf-nav replay accepts and ignores them): lifecycle and TF
    Spec("autostart", True, "Configure and activate at start-up; false: wait unconfigured for a lifecycle manager (lifecycle_msgs services ~/change_state, ~/get_state)."),
    Spec("publish_tf", True, "Publish tf_frame_id -> tf_child_frame_id on /tf with every odometry message (needs tf2_msgs)."),
    Spec("tf_frame_id", "", "Parent frame of the published transform; '' = world_frame."),
    Spec("tf_child_frame_id", "", "Child frame of the published transform; '' = base_frame."),
]

SCENARIO_DESCRIPTIONS = {
    "epsilon": "Truth gravity is mu (1 + epsilon) [-].",
    "apolune_altitude": "Start (apolune) altitude [m].",
    "perilune_altitude": "Planned perilune altitude [m].",
    "inclination_deg": "Orbit inclination [deg].",
    "orbit_design": "Gravity the start velocity is designed with: truth or filter.",
    "duration": "Trajectory length [s].",
    "dt": "Measurement period [s] (measurements/rae rate = 1/dt in simulated time).",
    "truth_step": "Longest RK4 sub-step of the truth [s].",
    "truth_accel_noise_density": "Truth white-acceleration density [m/s^1.5].",
    "filter_accel_noise_density": "Unused by the simulator (the estimator's accel_noise_density) [m/s^1.5].",
    "range_noise_std": "Range noise standard deviation [m].",
    "angle_noise_std": "Azimuth/elevation noise standard deviation [rad].",
    "station": "Observer position in world_frame [m].",
    "prior_position_std": "Prior position std the simulator logs [m].",
    "prior_velocity_std": "Prior velocity std the simulator logs [m/s].",
    "case": "full (range, azimuth, elevation) or partial (azimuth never measured).",
    "measurement_noise_scale": "Multiplies both measurement noise stds [-].",
    "dropout_probability": "Probability a whole measurement is lost [-].",
    "thrust": "Retrograde specific force magnitude [m/s^2]; 0 = coasting.",
    "disturbance": "Constant acceleration on the truth in world_frame that the IMU does not sense, like a gravity-field error [m/s^2].",
    "measurement_bias_sigma": "Constant error added to range, azimuth and elevation, in their noise standard deviations [-] (the estimator's range_bias_std can estimate the range one).",
}


SUITE_DESCRIPTIONS = {
    "altimeter_period": "Altimeter period [s], a multiple of scenario.dt; 0 switches measurements/altitude off.",
    "altimeter_noise_std": "Altimeter noise standard deviation [m].",
    "altimeter_max_altitude": "The altimeter measures below this altitude [m].",
    "reference_radius": "Radius of the altimeter's reference sphere [m].",
    "trn_period": "s between two TRN image captures (measurements/position), a multiple of scenario.dt; 0: off.",
    "trn_latency": "s from a TRN capture (the stamp) to the fix's publication.",
    "trn_noise_std": "TRN fix noise standard deviation per axis [m] (the message's covariance).",
    "trn_outlier_probability": "Probability that a TRN fix is an outlier [-].",
    "trn_outlier_size": "An outlier's extra error, in trn_noise_std, in a random direction [-].",
    "velocimeter_period": "Velocimeter period [s], a multiple of scenario.dt; 0 switches measurements/velocity off.",
    "velocimeter_noise_std": "Velocimeter noise standard deviation per axis [m/s] (the message's covariance).",
    "velocimeter_max_altitude": "The velocimeter measures below this altitude [m].",
}


def simulator_specs() -> list[Spec]:
    """The simulator's table: its own parameters plus ``scenario.<field>`` for every ScenarioConfig field."""
    from gpf_nav.sim.scenario import ScenarioConfig
    base = ScenarioConfig()
    specs = [
        Spec("seed", 0, "Scenario seed: same seed, same messages."),
        Spec("truth_csv", "", "Replay this CSV truth (t, x, y, z, vx, vy, vz[, ax, ay, az], SI) instead of generating one."),
        Spec("imu_rate", 10.0, "IMU rate [Hz, simulated time]; 0 disables imu."),
        Spec("imu_noise_std", 1e-4, "IMU specific-force noise standard deviation per axis [m/s^2]."),
        Spec("truth_rate", 10.0, "truth/odometry rate [Hz, simulated time] (also at every measurement time)."),
        Spec("publish_clock", True, "Publish /clock (simulated time); otherwise stamps follow the wall clock (start_time ignored)."),
        Spec("clock_rate", 50.0, "Wall-clock rate [Hz] of the release loop (and of /clock)."),
        Spec("rate_factor", 1.0, "Simulated seconds per wall second (needs publish_clock when not 1)."),
        Spec("start_delay", 1.0, "Wall-clock wait before the trajectory starts, for subscribers to connect [s]; /clock is held at start_time meanwhile."),
        Spec("start_time", -1.0, "ROS time of the trajectory start [s] when publish_clock; negative: the wall-clock time then, so at rate_factor 1 stamps and /clock follow the wall clock (0 means 'unset' in ROS)."),
        Spec("hand_over_prior", True, "Publish the scenario's prior (mean, covariance) on set_state at the start of the trajectory and of each lap, as a vehicle hands its pre-descent state over."),
        Spec("loop", False, "At the end of the trajectory: true restarts it (time keeps increasing); false exits."),
        Spec("world_frame", "moon_inertial", "frame_id of truth/odometry."),
        Spec("base_frame", "base_link", "child_frame_id of truth/odometry."),
        Spec("measurement_frame", "station", "frame_id of measurements/rae."),
        Spec("imu_frame", "base_link", "frame_id of imu."),
    ]
    for name, description in SCENARIO_DESCRIPTIONS.items():
        default = getattr(base, name)
        if name == "thrust":
            default = 0.0 if default is None else float(default)
        elif isinstance(default, tuple):
            default = [float(v) for v in default]
        specs.append(Spec("scenario." + name, default, description))
    from gpf_nav.sim.sensor_suite import SuiteConfig
    suite = SuiteConfig()
    specs += [Spec("publish_suite", False, "Also publish the sensor suite (suite.*): measurements/altitude, measurements/position (TRN, late by suite.trn_latency) and measurements/velocity."),
              Spec("altimeter_frame", "base_link", "frame_id of measurements/altitude.")]
    specs += [Spec("suite." + name, float(getattr(suite, name)), description)
              for name, description in SUITE_DESCRIPTIONS.items()]
    return specs


def coerce(spec: Spec, value):
    """``value`` converted to the type of ``spec.default``; ParameterError when it cannot be."""
    default = spec.default
    try:
        if default is None:
            return None if value is None or len(value) == 0 else [float(v) for v in value]
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise TypeError
            return value
        if isinstance(default, int):
            if isinstance(value, bool) or not float(value).is_integer():
                raise TypeError
            return int(value)
        if isinstance(default, float):
            if isinstance(value, (bool, str)):
                raise TypeError
            return float(value)
        if isinstance(default, list):
            return [float(v) for v in value]
        if isinstance(default, str):
            if not isinstance(value, str):
                raise TypeError
            return value
    except (TypeError, ValueError):
        pass
    raise ParameterError(f"parameter '{spec.name}' = {value!r} has the wrong type; expected "
                         f"{type(default).__name__ if default is not None else 'a list of 6 floats'}")


IGNORED_OFFLINE = ("use_sim_time",)
"""Parameters a params file may set for a node that mean nothing without one (accepted, not used)."""


def section_matches(key: str, fully_qualified_name: str) -> bool:
    """Whether the params-file section ``key`` applies to the node ``fully_qualified_name``, by rcl's rules:
    a key without a leading ``/`` is taken from the root (``gpf_estimator`` is ``/gpf_estimator`` and does
    not match ``/lander/gpf_estimator``); a ``*`` level stands for any one name (rcl refuses
    other uses of ``*``); a ``**`` level for any number of levels, none included (``/**`` matches every node, ``/**/gpf_estimator`` the node of that
    name in any namespace)."""
    key = "/" + str(key).lstrip("/")
    parts = []
    for token in key.strip("/").split("/"):
        if token == "**":
            parts.append("(?:/[^/]+)*")
        else:
            parts.append("/[^/]+" if token == "*" else "/" + re.escape(token))
    return re.fullmatch("".join(parts), "/" + fully_qualified_name.strip("/")) is not None


def read_params_file(path) -> dict:
    """``{node key: ros__parameters mapping}`` of the ROS 2 params file ``path``, node names nested as rcl
    allows (``lander: gpf_estimator: ros__parameters:`` is the key ``lander/gpf_estimator``). A file that is
    missing, unreadable, not YAML or not laid out so raises :class:`ParameterError`, one line naming it."""
    import yaml
    try:
        with open(path) as f:
            document = yaml.safe_load(f)
    except OSError as err:
        raise ParameterError(f"params file {path}: {err.strerror or err}") from None
    except yaml.YAMLError as err:
        raise ParameterError(f"params file {path} is not valid YAML: {' '.join(str(err).split())}") from None
    sections: dict = {}

    def walk(tree, key: str) -> None:
        if not isinstance(tree, dict):
            where = f"under '{key}'" if key else "at the top"
            raise ParameterError(f"params file {path}: expected node names {where} ('/**/<node>: ros__parameters: "
                                 f"...'), found {type(tree).__name__} {tree!r:.60}")
        if "ros__parameters" in tree:
            values = tree["ros__parameters"]
            if not key or not isinstance(values, (dict, type(None))):
                raise ParameterError(f"params file {path}: expected '<node>: ros__parameters: <mapping>' at "
                                     f"'{key or 'the top'}'")
            sections[key] = values or {}
            return
        for name, sub in tree.items():
            walk(sub, f"{key}/{name}" if key else str(name))

    if document is not None:
        walk(document, "")
    return sections


def unmatched_sections(sections: dict, fully_qualified_name: str) -> list[str] | None:
    """The node keys of a params file (:func:`read_params_file`) that name the node (``.../<its name>``)
    without applying to it, or None when no such key exists and some key applies. An empty list: no key
    at all applies to the node, and none names it. Used to warn that a file gives the node nothing."""
    name = fully_qualified_name.rstrip("/").rsplit("/", 1)[-1]
    keys = [str(k) for k in sections]
    applying = [k for k in keys if section_matches(k, fully_qualified_name)]
    named = [k for k in keys if k.rstrip("/").rsplit("/", 1)[-1] == name]
    if any(k in applying for k in named):
        return None
    if named:
        return named
    return None if applying else []


def parameters_from_files(specs: list[Spec], node_name: str, params_files=(), assignments=()) -> dict:
    """``{name: value}`` of ``specs`` without a node: defaults, then each ROS 2 params file in turn (every
    section that applies to the node ``/node_name``, by :func:`section_matches`: ``/**``,
    ``/**/node_name``, ``node_name``, ...; nested names joined with ``.``), then each ``name:=value``
    assignment (value parsed as YAML, as ``--ros-args -p`` does). Values are coerced as
    :func:`gpf_nav.ros.parameters.declare` does; an unknown name or a malformed file raises
    :class:`ParameterError`."""
    import yaml
    known = {spec.name: spec for spec in specs}
    given: dict = {}
    for path in params_files:
        sections = [section for key, section in read_params_file(path).items() if section_matches(key, node_name)]
        if not sections:
            raise ParameterError(f"params file {path} has no section for {node_name} (nor /**, /**/{node_name})")
        for section in sections:
            given.update(_flatten(section))
    for text in assignments:
        name, sep, value = text.partition(":=")
        if not sep or not name:
            raise ParameterError(f"parameter assignment {text!r} must read name:=value")
        try:
            given[name] = yaml.safe_load(value)
        except yaml.YAMLError:
            given[name] = value
    unknown = sorted(set(given) - set(known) - set(IGNORED_OFFLINE))
    if unknown:
        raise ParameterError(f"unknown parameter(s) of {node_name}: {', '.join(unknown)}")
    return {name: coerce(spec, given[name]) if name in given else
            (list(spec.default) if isinstance(spec.default, list) else spec.default)
            for name, spec in known.items()}


def _flatten(tree: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[prefix + str(key)] = value
    return out
