"""The estimator's ``/diagnostics`` status: a pure builder plus its message conversion.

:func:`filter_status` decides level, message and key/values from an :class:`EstimatorEngine` snapshot
and the thresholds; :func:`to_msg` turns that into ``diagnostic_msgs/DiagnosticArray``. Levels:

* ERROR: the filter was re-initialised (non-finite output or an exception) within ``reinit_hold`` s;
* WARN: not initialised yet; ESS/N below ``ess_warn_threshold``; mean co-state norm above
  ``costate_warn_threshold``; or no measurement accepted for ``sensor_timeout`` s (node clock);
* OK otherwise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from gpf_nav.ros.validation import REASONS

OK, WARN, ERROR = 0, 1, 2
STATUS_NAME = "gpf_estimator: filter"


@dataclass
class Thresholds:
    ess_warn: float = 0.05        # ESS/N below this is WARN
    costate_warn: float = 1e7     # mean co-state norm (whitened units / s) above this is WARN
    sensor_timeout: float = 10.0  # s without an accepted measurement is WARN


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def filter_status(engine, now_ns: int | None, thresholds: Thresholds, filter_name: str,
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
    message = "; ".join(problems) if problems else "tracking"

    measurements = ("rae", "range")
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
        ("measurements accepted", str(accepted)),
        ("measurements rejected", str(rejected)),
        ("messages rejected", str(c.total_rejected)),
        ("masked components", str(c.masked)),
        ("last measurement age", _fmt(age) if age is not None else "none yet"),
        ("reinitializations", str(engine.reinit_count)),
    ]
    for stream in ("rae", "range", "imu", "set_pose"):
        values.append((f"accepted {stream}", str(c.accepted[stream])))
    for reason in REASONS:
        values.append((f"rejected {reason}", str(c.rejected[reason])))
    return level, message, values


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
