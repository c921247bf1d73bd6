"""The estimator's ``/diagnostics`` status: a pure builder plus its message conversion.

:func:`filter_status` decides level, message and key/values from an :class:`EstimatorEngine` snapshot
and the thresholds; :func:`to_msg` turns that into ``diagnostic_msgs/DiagnosticArray``. Levels:

* ERROR: the filter was re-initialised (non-finite output or an exception) within ``reinit_hold`` s;
  or the co-state integrity monitor is at FAULT (held ``monitor_hold`` s);
* WARN: not initialised yet; ESS/N below ``ess_warn_threshold``; mean co-state norm above
  ``costate_warn_threshold``; no measurement accepted for ``sensor_timeout`` s (node clock); an IMU
  heard before and silent for longer than ``imu_timeout`` (the filter predicts without its input); the
  integrity monitor at WARN (held ``monitor_hold`` s); or, from :data:`OBSERVABILITY_WARN_AFTER` s after
  the prior, a direction of the state the measurements have not determined (the observability report,
  :mod:`gpf_nav.integrity.observability`: along it the estimate is the prior's, whatever the
  covariance's size); or the consistency monitor at FAULT (held ``monitor_hold`` s: the innovations are
  larger than the published covariance allows, :mod:`gpf_nav.integrity.consistency`);
* OK otherwise.

The message names every cause (``filter re-initialised (...)``, ``integrity FAULT: ...``), so an ERROR
from a re-initialisation and one from the monitor are told apart.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from gpf_nav.estimator.input_checks import REASONS

if TYPE_CHECKING:
    from gpf_nav.estimator.engine import EstimatorEngine

OK, WARN, ERROR = 0, 1, 2
STATUS_NAME = "gpf_estimator: filter"
COMPONENT_NAMES = ("range", "azimuth", "elevation")
INTEGRITY_LEVEL = {"OK": OK, "WARN": WARN, "FAULT": ERROR}
MEASUREMENT_STREAMS = ("rae", "range", "position", "velocity", "altitude")
STREAMS = (*MEASUREMENT_STREAMS, "imu", "set_state", "set_pose")


@dataclass
class Thresholds:
    ess_warn: float = 0.05        # ESS/N below this is WARN
    costate_warn: float = 50.0    # mean co-state norm (1/s, cloud metric) above this is WARN
    sensor_timeout: float = 10.0  # s without an accepted measurement is WARN


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def _vector(value) -> str:
    """``"x y z"`` of a vector, or ``n/a``."""
    return "n/a" if value is None else " ".join(f"{float(v):.6g}" for v in value)


def filter_status(engine: EstimatorEngine, now_ns: int | None, thresholds: Thresholds, filter_name: str,
                  uptime: float = 0.0) -> tuple[int, str, list[tuple[str, str]]]:
    """``(level, message, [(key, value), ...])`` describing ``engine`` at node time ``now_ns``.

    ``uptime`` [s] is how long the node has been running; before any measurement it stands in for the
    measurement age, so a node that never hears a sensor goes stale after ``sensor_timeout``.
    """
    c = engine.counters
    stats = engine.filter_stats()
    age = engine.measurement_age(now_ns)
    problems: list[str] = []
    level = OK
    if engine.in_error:
        level = ERROR
        problems.append(f"filter re-initialised ({engine.last_reinit_reason})")
    if not engine.initialized:
        level = max(level, WARN)
        problems.append("not initialised")
    if "ess" in stats and stats["ess"] < thresholds.ess_warn:
        level = max(level, WARN)
        problems.append(f"ESS/N {stats['ess']:.3g} < {thresholds.ess_warn:g}")
    if "costate_norm_mean" in stats and stats["costate_norm_mean"] > thresholds.costate_warn:
        level = max(level, WARN)
        problems.append(f"co-state norm {stats['costate_norm_mean']:.3g} > {thresholds.costate_warn:g}")
    silent_for = age if age is not None else uptime
    if silent_for > thresholds.sensor_timeout:
        level = max(level, WARN)
        problems.append(f"no measurement for {silent_for:.1f} s")
    imu_age = engine.imu_age(now_ns)
    if engine.imu_silent(now_ns):
        level = max(level, WARN)
        problems.append(f"no IMU sample for {imu_age:.1f} s: predicting without input")
    report = engine.integrity()
    if report.level != "OK":
        level = max(level, INTEGRITY_LEVEL[report.level])
        problems.append(_integrity_problem(report))
    observability = engine.observability()
    if (observability is not None and observability.undetermined
            and observability.elapsed >= OBSERVABILITY_WARN_AFTER):
        level = max(level, WARN)
        problems.append(f"{observability.undetermined} undetermined direction"
                        f"{'s' if observability.undetermined > 1 else ''}: "
                        + "; ".join(observability.describe(state_names(observability.information.size))))
    consistency = engine.consistency_report()
    if consistency is not None and consistency.level == "FAULT":
        level = max(level, WARN)
        s = consistency.alarm if consistency.alarm is not None else consistency.status
        when = f" {consistency.alarm_age:.1f} s ago" if consistency.alarm is not None else ""
        problems.append(f"consistency FAULT{when}: innovations too large for the covariance (NIS sum "
                        f"{s.statistic:.4g} over {s.dof} components, p = {s.p_value:.2g})")
    message = "; ".join(problems) if problems else "tracking"

    measurements = MEASUREMENT_STREAMS
    accepted = sum(c.accepted[s] for s in measurements)
    rejected = sum(n for (stream, _), n in c.rejected_by_stream.items() if stream in measurements)
    values = [
        ("filter", filter_name),
        ("initialized", str(engine.initialized).lower()),
        ("initialized from", engine.init_source or "-"),
        ("ESS", _fmt(stats["ess"]) if "ess" in stats else "n/a"),
        ("co-state norm", _fmt(stats["costate_norm_mean"]) if "costate_norm_mean" in stats else "n/a"),
        ("co-state norm max", _fmt(stats["costate_norm_max"]) if "costate_norm_max" in stats else "n/a"),
        ("resample count", str(stats.get("resample_count", "n/a"))),
        ("outlier components gated", str(stats.get("gated", "n/a"))),
        ("tempered updates", str(stats.get("tempered_updates", "n/a"))),
        ("unmodelled acceleration [m/s^2]", _vector(stats.get("unmodelled_acceleration"))),
        ("unmodelled acceleration std [m/s^2]", _vector(stats.get("unmodelled_acceleration_std"))),
        ("compensated model probability", _fmt(stats["compensated_model_probability"])
         if "compensated_model_probability" in stats else "n/a"),
        ("measurements accepted", str(accepted)),
        ("measurements rejected", str(rejected)),
        ("messages rejected", str(c.total_rejected)),
        ("masked components", str(c.masked)),
        ("last measurement age", _fmt(age) if age is not None else "none yet"),
        ("last IMU sample age", _fmt(imu_age) if imu_age is not None else "none yet"),
        ("reinitializations", str(engine.reinit_count)),
        ("integrity fault reinitializations", str(engine.fault_reinit_count)),
    ]
    for stream in STREAMS:
        values.append((f"accepted {stream}", str(c.accepted[stream])))
    for reason in REASONS:
        values.append((f"rejected {reason}", str(c.rejected[reason])))
    values.extend(stream_values(engine))
    values.extend(integrity_values(report, filter_name))
    values.extend(observability_values(observability))
    values.extend(consistency_values(consistency))
    return level, message, values


def consistency_values(report) -> list[tuple[str, str]]:
    """The ``consistency ...`` key/values of an :class:`gpf_nav.estimator.consistency_watch.ConsistencyReport`
    (None: disabled)."""
    if report is None:
        return [("consistency level", "disabled")]
    s = report.status
    tested = s.dof > 0
    return [("consistency level", report.level),
            ("consistency NIS", _fmt(s.nis) if math.isfinite(s.nis) else "n/a"),
            ("consistency window statistic", _fmt(s.statistic) if tested else "n/a"),
            ("consistency window dof", str(s.dof)),
            ("consistency p-value", _fmt(s.p_value) if tested else "n/a"),
            ("consistency updates", str(report.updates)),
            ("consistency rejected", str(report.rejected)),
            ("consistency fault updates", str(report.fault_updates)),
            ("consistency error", report.error or "none")]


OBSERVABILITY_WARN_AFTER = 100.0
"""s of filter time after its prior before an undetermined direction is a WARN: a good prior knows the
velocity better than the first minute of measurements, and that is no fault (the values show the report
from the start)."""
STATE_NAMES = ("px", "py", "pz", "vx", "vy", "vz")
"""Names of the user's state components in the reports (position, velocity; world frame)."""


def state_names(n: int) -> tuple[str, ...]:
    """Names of ``n`` state components: the user's six, then ``s6, s7, ...`` for the filter's own (an
    estimated acceleration, sensor biases)."""
    return STATE_NAMES[:n] + tuple(f"s{i}" for i in range(len(STATE_NAMES), n))


def observability_values(report) -> list[tuple[str, str]]:
    """The ``observability ...`` key/values of an observability report (None: not available yet)."""
    if report is None:
        return [("observability", "n/a")]
    values = [("observability", "determined" if report.determined else "UNDETERMINED"),
              ("observability undetermined directions", str(report.undetermined)),
              ("observability threshold", _fmt(report.threshold)),
              ("observability smallest information", _fmt(float(report.information[0]))),
              ("observability updates", str(report.updates)),
              ("observability elapsed [s]", _fmt(float(report.elapsed)))]
    for i, text in enumerate(report.describe(state_names(report.information.size)), 1):
        values.append((f"observability direction {i}", text))
    return values


def stream_values(engine: EstimatorEngine) -> list[tuple[str, str]]:
    """Per-stream refusals (``rejected <stream>`` always; ``rejected <stream> <reason>`` when counted),
    the late-measurement history and the estimated sensor biases (``bias <sensor>``, ``bias std <sensor>``:
    one value per component, in the measurement's units)."""
    c = engine.counters
    values = []
    for stream in STREAMS:
        by_reason = {reason: n for (s, reason), n in c.rejected_by_stream.items() if s == stream and n}
        values.append((f"rejected {stream}", str(sum(by_reason.values()))))
        values.extend((f"rejected {stream} {reason}", str(n)) for reason, n in sorted(by_reason.items()))
    history = engine.history
    span = (history.entries[-1].t_ns - history.entries[0].t_ns) * 1e-9 if len(history) else 0.0
    values += [("late measurements fused", str(engine.late_count)),
               ("late IMU samples applied", str(engine.late_imu_count)),
               ("inputs re-applied", str(engine.replayed_count)),
               ("history inputs", str(len(history))), ("history span [s]", _fmt(span)),
               ("history snapshot failures", str(engine.snapshot_failures))]
    f = engine.filter
    for name in f.sensor_names if engine.initialized else ():
        mean, std = f.sensor_bias(name)
        values += [(f"bias {name}", _vector(mean)), (f"bias std {name}", _vector(std))]
    return values


def _components(indices) -> str:
    return ", ".join(COMPONENT_NAMES[i] if i < len(COMPONENT_NAMES) else str(i) for i in indices) or "none"


def _integrity_problem(report) -> str:
    """``integrity FAULT: co-state mean T^2 41.2 > 16.3, p = 3.2e-07 (range, elevation)``, with ``N s
    ago`` after the level when the alarm is held from an earlier update. No ``;`` inside: the status
    message joins the causes with ``; ``."""
    s = report.alarm if report.alarm is not None else report.status
    when = f" {report.alarm_age:.1f} s ago" if report.alarm is not None else ""
    if report.level == "FAULT":
        test = f"co-state mean T^2 {s.statistic:.4g} > {s.threshold:.4g}"
    else:
        test = f"co-state mean T^2 {s.statistic:.4g}"
    return f"integrity {report.level}{when}: {test}, p = {s.p_value:.2g} ({_components(s.components)})"


def integrity_values(report, filter_name: str) -> list[tuple[str, str]]:
    """The ``integrity ...`` key/values of an :class:`gpf_nav.estimator.integrity_watch.IntegrityReport` (no NaN:
    figures that do not exist read ``n/a``)."""
    if report.state == "disabled":
        head = [("integrity level", "disabled"), ("integrity monitor", "disabled (monitor_enabled: false)")]
    elif report.state == "unavailable":
        head = [("integrity level", "unavailable"),
                ("integrity monitor", f"unavailable: {filter_name} has no co-state")]
    else:
        head = [("integrity level", report.level), ("integrity monitor", "active")]
    values = head
    s = report.status
    ready = s is not None and s.ready
    values += [
        ("integrity ready", str(ready).lower()),
        ("integrity last level", s.level if s is not None else "n/a"),
        ("integrity statistic", _fmt(s.statistic) if ready and math.isfinite(s.statistic) else "n/a"),
        ("integrity threshold", _fmt(s.threshold) if ready and math.isfinite(s.threshold) else "n/a"),
        ("integrity p-value", _fmt(s.p_value) if ready and math.isfinite(s.p_value) else "n/a"),
        ("integrity components", _components(s.components) if ready else "n/a"),
        ("integrity samples", str(report.samples)),
        ("integrity fault updates", str(report.fault_updates)),
        ("integrity warn updates", str(report.warn_updates)),
        ("integrity rejected samples", str(report.rejected)),
        ("integrity skipped updates", str(report.skipped)),
        ("integrity quarantined samples", str(report.quarantined)),
        ("integrity resets", str(report.resets)),
    ]
    if report.error:
        values.append(("integrity error", report.error))
    return values


def to_msg(level: int, message: str, values, stamp, hardware_id: str = "gpf_nav"):
    """``diagnostic_msgs/DiagnosticArray`` with one status named :data:`STATUS_NAME`."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    status = DiagnosticStatus()
    status.level = bytes([level])
    status.name = STATUS_NAME
    status.message = message
    status.hardware_id = hardware_id
    status.values = [KeyValue(key=k, value=v) for k, v in values]
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = [status]
    return msg


def parse_values(status) -> dict[str, str]:
    """Key/values of a received ``DiagnosticStatus`` as a dict (for tests and the demo)."""
    return {kv.key: kv.value for kv in status.values}


def is_finite_number(text: str) -> bool:
    """True when ``text`` parses as a finite float (tests: no NaN leaks into diagnostics)."""
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False
