"""The estimator node's parameter schema (:data:`ESTIMATOR`), the rules that tie parameters together
(:func:`check_estimator_parameters`), and ROS 2 params files read without a node.

Each parameter is one :class:`gpf_nav.schema.Spec`: the node declares the table
(:func:`gpf_nav.ros.parameters.declare`), :func:`check_estimator_parameters` validates it,
``gpf-nav parameters`` writes ``config/estimator.yaml`` and ``docs/parameters.md`` from it, and the launch
file takes its choices from it. The measurement streams bring their own parameters
(:func:`gpf_nav.estimator.streams.stream_parameters`). The filter's options are checked by ``make_filter`` for the chosen filter.
No parameter may be changed at run time except those marked ``live``. No ROS here.
"""
from __future__ import annotations

import math
import re
from dataclasses import replace

from gpf_nav import resampling
from gpf_nav.estimator.engine_config import NODE_FAULT_ACTION, NODE_MAX_MEASUREMENT_RATE, EngineConfig
from gpf_nav.estimator.factory import FILTERS
from gpf_nav.estimator.integrity_watch import FAULT_ACTIONS
from gpf_nav.estimator.stations import station_errors
from gpf_nav.estimator.streams import STREAMS, stream_parameters
from gpf_nav.filters.gpf import METRICS, REFERENCES, WEIGHTINGS
from gpf_nav.filters.compensated import UNMODELLED_ACCELERATION_STD, UNMODELLED_ACCELERATION_TIME
from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.filters.model_averaging import NOMINAL_PRIOR
from gpf_nav.filters.multiple_model import (COMPENSATION_SCALES, COMPENSATION_TIMES, NARROW_FILTER, NARROW_FILTERS,
                                            NESTING_GATE, NOMINAL_ACCELERATION_NOISE, NOMINAL_SWITCH_TIME, SIZE_GATE,
                                            SWITCH_TIME)
from gpf_nav.models.gravity import FIELDS
from gpf_nav.models.lunar import MU_MOON
from gpf_nav.registry import FLATTENING_HORIZON
from gpf_nav.schema import ParameterError, Spec, check, coerce

FILTER_GROUP = "Filter"
"""The group of ``make_filter``'s options (every parameter in it but ``filter`` itself)."""
_BY_FILTER = "make_filter"
_ENGINE = EngineConfig()
"""The engine's defaults, which are the node's (:mod:`gpf_nav.estimator.engine_config`)."""


def _group(name: str, *specs: Spec) -> list[Spec]:
    return [replace(spec, group=name) for spec in specs]


ESTIMATOR = [
    *_group(
        FILTER_GROUP,
        Spec("filter", "gpf", "gpf (geometric projection PF, multiple model: nominal or compensated at 2e-3 and 0.1 m/s^2), gpf-single (one compensated GPF), gpf-mm and gpf-ladder (= gpf), spf (bootstrap PF), ekf, ukf or enkf.", choices=FILTERS, checked_by=_BY_FILTER),
        Spec("n_particles", N_PARTICLES, "Number of particles / ensemble members (gpf, spf, enkf); >= 2 for enkf.", bounds=">= 1", symbol="N", checked_by=_BY_FILTER),
        Spec("seed", 0, "Seed of the filter's random stream; negative: a random seed."),
        Spec("reference", "innovation", "GPF projection reference; increment needs metric euclidean or process_noise.", choices=REFERENCES, checked_by=_BY_FILTER),
        Spec("weighting", "corrected", "GPF weighting: corrected (exact proposal correction) or likelihood (paper).", choices=WEIGHTINGS, checked_by=_BY_FILTER),
        Spec("metric", "cloud", "GPF projection metric: cloud (predicted cloud's covariance; navigation default), euclidean (paper) or process_noise (metric of Q(dt)).", choices=METRICS, checked_by=_BY_FILTER),
        Spec("regularization", 0.0, "Tikhonov eps of the projection; 0: the metric's default (1 for cloud, 1e-6 otherwise); relative for euclidean, in measurement-noise units otherwise.", bounds=">= 0", checked_by=_BY_FILTER),
        Spec("unmodelled_acceleration_std", UNMODELLED_ACCELERATION_STD, "gpf: stationary std of the estimated unmodelled acceleration; 0 turns the compensation off (gpf-mm needs it positive).", "m/s^2", ">= 0", checked_by=_BY_FILTER),
        Spec("unmodelled_acceleration_time", UNMODELLED_ACCELERATION_TIME, "gpf: correlation time of the unmodelled acceleration.", "s", "> 0", checked_by=_BY_FILTER),
        Spec("nominal_prior", NOMINAL_PRIOR, "gpf-single: prior probability that the model needs no unmodelled acceleration; the estimate averages the two hypotheses; 0 publishes the compensated posterior as it is.", bounds="[0, 1)", checked_by=_BY_FILTER),
        Spec("compensation_scales", list(COMPENSATION_SCALES), "gpf: the compensated members' acceleration stds as fractions of unmodelled_acceleration_std, increasing to 1: one member per scale beside the nominal one, so that a force up to the size of unmodelled_acceleration_std has a member of its size.", bounds="(0, 1]", checked_by=_BY_FILTER),
        Spec("compensation_times", list(COMPENSATION_TIMES), "gpf: the compensated members' correlation times as fractions of unmodelled_acceleration_time, one per compensation scale, the last 1: a member of short time follows a force that varies along the orbit.", bounds="> 0", checked_by=_BY_FILTER),
        Spec("nesting_gate", NESTING_GATE, "gpf: chi-square probability of the gate by which the widest compensated member must admit another member's estimate for it to keep its probability while the data leave a direction undetermined (a member that explains an error the data cannot see with a narrower model); 0: no gate.", bounds="[0, 1)", checked_by=_BY_FILTER),
        Spec("size_gate", SIZE_GATE, "gpf: chi-square probability of the gate beyond which a narrow compensated member's estimated acceleration, in its own prior's sigmas, says the force is a wider member's size: the member loses its probability for that update; 0: no gate.", bounds="[0, 1)", checked_by=_BY_FILTER),
        Spec("narrow_filter", NARROW_FILTER, "gpf: the filter of the compensated members narrower than the widest: ekf (a compensated EKF with the GPF's innovation gate; the nominal and the widest member stay GPFs) or gpf.", choices=NARROW_FILTERS, checked_by=_BY_FILTER),
        Spec("model_switch_time", SWITCH_TIME, "gpf: mean sojourn time of the nominal / compensated model chain.", "s", "> 0", checked_by=_BY_FILTER),
        Spec("nominal_acceleration_noise", NOMINAL_ACCELERATION_NOISE, "gpf: spectral density of a white acceleration added to the nominal member's process noise, so that its covariance holds forces below every compensated member's size (the Moon's J2); 0: the model as it is.", "m^2/s^3", ">= 0", checked_by=_BY_FILTER),
        Spec("nominal_switch_time", NOMINAL_SWITCH_TIME, "gpf: mean time after which the nominal model also switches to the narrowest compensated one, which keeps that member in the estimate; 0: no such switch.", "s", ">= 0", checked_by=_BY_FILTER),
        Spec("kernel_bandwidth", 0.0, "gpf, cloud metric: kernel bandwidth h; 0: the default, the Gaussian-optimal one for N and the state dimension, 1.6 times it while an update is tempered or gated (gpf-single: 1.6 times it always; at most 0.95).", bounds="[0, 1)", symbol="h", checked_by=_BY_FILTER),
        Spec("flattening_horizon", FLATTENING_HORIZON, "gpf: the update runs in coordinates where the measurement now and of the state flowed half this and this far ahead is linear, so the cloud keeps its spread along what the data cannot see; 0: the measurement now only.", "s", ">= 0", checked_by=_BY_FILTER),
        Spec("collapse_steps", 0, "gpf/spf: re-initialise after this many consecutive updates with ESS < 1.5 particles; 0 never.", bounds=">= 0", checked_by=_BY_FILTER),
        Spec("resampling", "systematic", "Resampling scheme.", choices=tuple(sorted(resampling.SCHEMES)), checked_by=_BY_FILTER),
        Spec("ess_threshold", 0.5, "Resample when ESS < tau N.", bounds="(0, 1]", symbol="tau", checked_by=_BY_FILTER),
        Spec("compute_costate", True, "spf only: also compute the diagnostic co-state (costs one projection)."),
        Spec("ukf_alpha", 1e-3, "UKF sigma-point spread alpha.", bounds="> 0", symbol="alpha", checked_by=_BY_FILTER),
        Spec("ukf_beta", 2.0, "UKF beta.", symbol="beta"),
        Spec("ukf_kappa", 0.0, "UKF kappa; n + kappa > 0 (n: the state dimension).", symbol="kappa", checked_by=_BY_FILTER),
    ),
    *_group(
        "Model",
        Spec("mu", MU_MOON, "Gravitational parameter the filter assumes.", "m^3/s^2", "> 0"),
        Spec("station", [0.0, 0.0, 0.0], "Observer position in world_frame (x, y, z).", "m", "finite", length=3),
        Spec("range_noise_std", 30.0, "Range noise standard deviation.", "m", "> 0"),
        Spec("angle_noise_std", math.radians(0.03), "Azimuth/elevation noise standard deviation.", "rad", "> 0"),
        Spec("accel_noise_density", 1e-3, "Process-noise white-acceleration density.", "m/s^1.5", ">= 0"),
        Spec("max_step", 10.0, "Longest integration sub-step of the model.", "s", "> 0"),
        Spec("gravity_field", "point", "Gravity beyond the point mass the model integrates: point (none), j2, zonal (J2-J4) or degree4 (DE430's lunar field through degree 4, turning with the Moon).", choices=FIELDS),
    ),
    *_group(
        "Frames",
        Spec("world_frame", "moon_inertial", "Frame of the state and of odometry header.frame_id (Moon-centred inertial).", bounds="non-empty"),
        Spec("base_frame", "base_link", "odometry child_frame_id (axes taken aligned with world_frame)."),
        Spec("measurement_frame", "station", "header.frame_id of measurements/rae and measurements/range from the station parameter's station ('' = any frame that names no other station); measurements/position may be in world_frame, moon_fixed_frame or site_frame, measurements/velocity must be in world_frame."),
        Spec("imu_frame", "base_link", "Required header.frame_id of imu ('' = any)."),
        Spec("moon_fixed_frame", "moon_fixed", "The Moon-fixed frame (turning with the Moon about world_frame's z axis at 2.6617e-6 rad/s) on TF and in measurements/position header.frame_id.", bounds="non-empty"),
        Spec("moon_epoch", 0.0, "The time (header stamps' scale) at which moon_fixed_frame's x axis is world_frame's x axis; also the phase of gravity_field degree4.", "s", "finite"),
        Spec("site_frame", "map", "The landing site's east-north-up frame (REP 105 map) on TF and in measurements/position header.frame_id.", bounds="non-empty"),
        Spec("site_latitude", 0.0, "Latitude of site_frame's origin (spherical, REP 103).", "rad", "[-1.5707963267948966, 1.5707963267948966]"),
        Spec("site_longitude", 0.0, "Longitude of site_frame's origin, east positive.", "rad", "finite"),
        Spec("site_height", 0.0, "Height of site_frame's origin above the Moon's mean radius (1737.4 km).", "m", "finite"),
    ),
    *_group(
        "Stations (measurements/rae and measurements/range name theirs in header.frame_id)",
        Spec("station_names", None, "Stations on the rotating Moon: a message from one has its name as header.frame_id; measurement_frame stays the station parameter's.", item="string"),
        Spec("station_lat_lon_height", None, "Latitude (rad), longitude (rad, east positive) and height (m above the mean radius) of each of station_names in turn, 3 numbers per station.", "rad, rad, m", "finite"),
        Spec("inertial_station_names", None, "Stations fixed in world_frame, named as station_names (azimuth atan2(dy, dx) as the station parameter's).", item="string"),
        Spec("inertial_station_positions", None, "Position in world_frame of each of inertial_station_names in turn, 3 numbers per station.", "m", "finite"),
    ),
    *_group(
        "Initialisation",
        Spec("initial_state", None, "Initial [x, y, z, vx, vy, vz] in world_frame; unset: set_state, set_pose or measurements.", "m, m/s", "finite", length=6),
        Spec("initial_std", _ENGINE.initial_std.tolist(), "Initial standard deviations.", "m, m/s", "> 0", length=6),
        Spec("initial_stamp", _ENGINE.initial_stamp, "ROS time of initial_state; negative: the first accepted measurement's stamp.", "s", "finite"),
        Spec("init_window", _ENGINE.init_window, "Measurements used to initialise from the data when no initial state is given.", bounds=">= 2"),
    ),
    *_group(
        "Timing and input handling",
        Spec("publish_rate", 10.0, "Rate of predicted odometry between measurements (node clock); 0 disables.", "Hz", ">= 0"),
        Spec("max_future", _ENGINE.max_future, "Refuse stamps more than this ahead of the node clock.", "s", "> 0"),
        Spec("reset_on_time_jump", True, "Reset the filter when the node clock jumps back by more than 1 s (a restarted simulator or bag), checked on every input and every diagnostics_period, whatever publish_rate; false: the jump is only counted and logged."),
        Spec("imu_timeout", _ENGINE.imu_timeout, "An IMU sample older than this (relative to the measurement) is not used.", "s", "> 0"),
        Spec("max_extrapolation", _ENGINE.max_extrapolation, "Do not publish predictions more than this past the last measurement.", "s", "> 0"),
        Spec("max_measurement_rate", NODE_MAX_MEASUREMENT_RATE, "Process at most this many measurements per second (steady clock); 0: unlimited.", "Hz", ">= 0"),
        Spec("queue_depth", 10, "Depth of the sensor-data (best-effort) subscription queues; also the most IMU samples taken before another input.", bounds=">= 1"),
        Spec("quaternion_tolerance", 0.01, "Allowed | |q| - 1 | of an IMU orientation.", bounds="> 0"),
    ),
    *_group(
        "Measurement streams (gpf_nav.estimator.streams), late measurements",
        Spec("history_length", _ENGINE.history_length, "A measurement stamped up to this long before the filter's time is fused at its stamp (the later inputs are re-applied); older ones are refused; 0: none.", "s", ">= 0"),
        Spec("reapply_budget", _ENGINE.reapply_budget, "Seconds of lateness that late measurements may have re-applied per second of the filter's time (at most history_length s saved up, full at start): one whose lateness exceeds what is left is refused (reapply_budget); 0: unlimited.", "s/s", ">= 0"),
        *stream_parameters(STREAMS),
        Spec("gate_limit", _ENGINE.gate_limit, "After this many refusals of a gate in a row the next measurement of that stream is used.", bounds=">= 0"),
    ),
    *_group(
        "Outputs and diagnostics",
        Spec("max_published_particles", 100, "Particles published on gpf/particles (systematic selection); 0 disables.", bounds=">= 0"),
        Spec("diagnostics_period", 1.0, "Period of /diagnostics (steady clock).", "s", "> 0"),
        Spec("ess_warn_threshold", 0.05, "WARN when ESS/N falls below this.", bounds="[0, 1]", live=True),
        Spec("costate_warn_threshold", 50.0, "WARN when the mean co-state norm exceeds this (1/s with the cloud and process_noise metrics, whitened, about 1 nominally; m^2/s with euclidean).", "1/s or m^2/s", "> 0", live=True),
        Spec("sensor_timeout", 10.0, "WARN when no measurement was accepted for this long (node clock).", "s", "> 0", live=True),
        Spec("reinit_hold", _ENGINE.reinit_hold, "Diagnostics stay ERROR this long after a re-initialisation (steady clock).", "s", ">= 0"),
    ),
    *_group(
        "Integrity monitor (co-state; gpf, and spf with compute_costate)",
        Spec("monitor_enabled", True, "Run the co-state integrity monitor: WARN/ERROR in /diagnostics on a biased co-state."),
        Spec("monitor_window", 10, "Updates per window mean (the test window and each reference window).", bounds=">= 1"),
        Spec("monitor_reference", 20, "Largest number of reference windows kept; >= monitor_min_reference."),
        Spec("monitor_min_reference", 6, "Reference windows needed before testing (ready after (this + 1) * (window + gap) updates); 2 <= this <= monitor_reference."),
        Spec("monitor_gap", 2, "Updates skipped between windows (decorrelation guard).", bounds=">= 0"),
        Spec("monitor_false_alarm_rate", 1e-3, "Per-update probability of FAULT (diagnostics ERROR) on a consistent filter.", bounds="(0, 1)"),
        Spec("monitor_warn_false_alarm_rate", 1e-2, "Per-update probability of WARN or worse on a consistent filter; >= monitor_false_alarm_rate.", bounds="(0, 1)"),
        Spec("monitor_quarantine_rate", -1.0, "p-value below which a window is kept out of the reference; negative: monitor_false_alarm_rate / 100; 0: no quarantine; at most monitor_false_alarm_rate.", bounds="finite"),
        Spec("integrity_fault_action", NODE_FAULT_ACTION, "After integrity_fault_updates co-state monitor FAULT updates in a row: measurements (start again from the next init_window measurements), prior (from the last initial state: parameters, set_state, set_pose or batch fit, predicted to now) or none (report only).", choices=FAULT_ACTIONS),
        Spec("integrity_fault_updates", _ENGINE.fault_updates, "Co-state monitor FAULT updates in a row that make integrity_fault_action act.", bounds=">= 1"),
        Spec("monitor_hold", _ENGINE.monitor_hold, "A monitor WARN or FAULT (co-state or consistency) stays in /diagnostics this long after the update that raised it (steady clock); negative: latched until ~/reset or a re-initialisation.", "s", "finite"),
    ),
    *_group(
        "Consistency monitor (normalised innovations; every filter)",
        Spec("consistency_enabled", True, "Test the innovations of the model's and the sensors' measurements against the predicted covariance: WARN in /diagnostics when they are too large for it (an overconfident estimate)."),
        Spec("consistency_window", 10, "Updates whose normalised innovations squared are summed.", bounds=">= 1"),
        Spec("consistency_false_alarm_rate", 1e-3, "Per-update probability of a consistency FAULT (diagnostics WARN) on a consistent filter.", bounds="(0, 1)"),
    ),
    *_group(
        "Node only (gpf-nav replay accepts and ignores them): lifecycle and TF",
        Spec("autostart", True, "Configure and activate at start-up; false: wait unconfigured for a lifecycle manager (lifecycle_msgs services ~/change_state, ~/get_state)."),
        Spec("warm_up", True, "On configure, before subscribing, run a throwaway copy of the filter on a short noise-free trajectory, and a reanchoring of its observability trackers, so that its compiled kernels are loaded (compiled on an install's first start, about 16 s on 2 cores) before the first message; false: the first update, and the first reanchoring, wait for them."),
        Spec("publish_tf", True, "Publish tf_frame_id -> tf_child_frame_id on /tf with every odometry message (needs tf2_msgs)."),
        Spec("tf_frame_id", "", "Parent frame of the published transform; '' = world_frame."),
        Spec("tf_child_frame_id", "", "Child frame of the published transform; '' = base_frame."),
    ),
]
BY_NAME = {spec.name: spec for spec in ESTIMATOR}


def check_estimator_parameters(p: dict) -> list[str]:
    """Errors in the estimator's parameters: each against its schema entry, then the rules that tie
    parameters together (the filter's options are ``make_filter``'s to check)."""
    errors = check(ESTIMATOR, p) + station_errors(p)
    if not 2 <= p["monitor_min_reference"] <= p["monitor_reference"]:
        errors.append(f"parameters 'monitor_min_reference' = {p['monitor_min_reference']} and 'monitor_reference' "
                      f"= {p['monitor_reference']} must satisfy 2 <= monitor_min_reference <= monitor_reference")
    alpha, warn = p["monitor_false_alarm_rate"], p["monitor_warn_false_alarm_rate"]
    if 0.0 < alpha < 1.0 and not alpha <= warn:
        errors.append(f"parameter 'monitor_warn_false_alarm_rate' = {warn!r} must lie in "
                      f"[monitor_false_alarm_rate, 1) = [{alpha!r}, 1)")
    quarantine = p["monitor_quarantine_rate"]
    if quarantine >= 0.0 and math.isfinite(alpha) and quarantine > alpha:
        errors.append(f"parameter 'monitor_quarantine_rate' = {quarantine!r} must be negative (default) or "
                      "lie in [0, monitor_false_alarm_rate]")
    return errors


def filter_options(p: dict) -> dict:
    """``make_filter`` keyword arguments from the node parameters (the :data:`FILTER_GROUP` entries)."""
    return {spec.name: p[spec.name] for spec in ESTIMATOR if spec.group == FILTER_GROUP and spec.name != "filter"}


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
