"""Input validation for the ROS adapters: pure functions returning ``(ok, reason)``, plus counters.

Nothing here imports rclpy or message types, so every rule is unit-testable on plain numbers. A
*reason* is a short snake_case token; the estimator counts rejected messages per reason and reports
the counts in ``/diagnostics`` (see ``docs/ros.md``). The reasons are:

===========================  =====================================================================
``bad_stamp``                ``nanosec >= 1e9`` or a negative ``sec``
``wrong_frame``              ``header.frame_id`` differs from the configured frame
``non_finite``               an inf anywhere, or a NaN where NaN does not mean "not measured"
``no_measured_component``    every component NaN: nothing to update with
``non_positive_range``       range <= 0
``range_out_of_limits``      range outside ``[min_range, max_range]`` of a ``sensor_msgs/Range``
``angle_out_of_range``       azimuth outside [-pi, pi] or elevation outside [-pi/2, pi/2]
``non_unit_quaternion``      an orientation given but ``| |q| - 1 |`` above the tolerance
``not_provided``             ``linear_acceleration_covariance[0] == -1`` (the field is not provided)
``stale_stamp``              older than the last processed message of the same stream (IMU; measurements
                             before initialisation or with ``history_length`` 0), or before the
                             filter's (re-)initialisation
``older_than_history``       a measurement stamped more than ``history_length`` s before the filter's time
``not_positive_definite``    a message's covariance block is not symmetric positive definite
``innovation_gate``          refused by the stream's innovation gate (chi-square, ``<stream>_gate``)
``reapply_budget``           a late measurement whose lateness exceeds what is left of the re-application
                             budget (``reapply_budget``, :class:`ReapplyBudget`)
``future_stamp``             more than ``max_future`` seconds ahead of the node clock
``rate_limit``               above ``max_measurement_rate`` messages per second
``not_initialized``          arrived before the filter could be initialised and not usable for it
``no_velocity``              ``set_pose`` before any velocity is known (no estimate, no parameter)
``filter_error``             the filter raised or produced a non-finite estimate (then re-initialised)
``internal_error``           any other exception in a callback (logged with its message; the node goes on)
===========================  =====================================================================
"""
from __future__ import annotations

import math
from collections import Counter

import numpy as np

REASONS = (
    "bad_stamp", "wrong_frame", "non_finite", "no_measured_component", "non_positive_range",
    "range_out_of_limits", "angle_out_of_range", "non_unit_quaternion", "not_provided", "stale_stamp",
    "future_stamp", "rate_limit", "not_initialized", "no_velocity", "filter_error", "internal_error",
    "older_than_history", "not_positive_definite", "innovation_gate", "unknown_station", "reapply_budget",
)

OK = (True, "")
ANGLE_TOLERANCE = 1e-9
"""rad: slack on the angle limits so that exactly +-pi and +-pi/2 (and rounding) are accepted."""


def check_stamp(sec: int, nanosec: int) -> tuple[bool, str]:
    """A ``builtin_interfaces/Time`` must have ``sec >= 0`` and ``0 <= nanosec < 1e9``."""
    if sec < 0 or nanosec < 0 or nanosec >= 1_000_000_000:
        return False, "bad_stamp"
    return OK


def check_frame(frame_id: str, expected: str) -> tuple[bool, str]:
    """``frame_id`` must equal ``expected``; an empty ``expected`` accepts any frame."""
    if expected and frame_id != expected:
        return False, "wrong_frame"
    return OK


def check_rae(rng: float, azimuth: float, elevation: float) -> tuple[bool, str, tuple]:
    """Range [m], azimuth and elevation [rad]; NaN = component not measured (masked, not refused).

    Returns ``(ok, reason, (range, azimuth, elevation))`` with the NaNs kept (the filter's "not
    measured" convention). Refused: any inf, all three NaN, range <= 0, azimuth outside [-pi, pi],
    elevation outside [-pi/2, pi/2].
    """
    values = (float(rng), float(azimuth), float(elevation))
    if any(math.isinf(v) for v in values):
        return False, "non_finite", values
    if all(math.isnan(v) for v in values):
        return False, "no_measured_component", values
    r, a, e = values
    if not math.isnan(r) and r <= 0.0:
        return False, "non_positive_range", values
    if not math.isnan(a) and abs(a) > math.pi + ANGLE_TOLERANCE:
        return False, "angle_out_of_range", values
    if not math.isnan(e) and abs(e) > 0.5 * math.pi + ANGLE_TOLERANCE:
        return False, "angle_out_of_range", values
    return True, "", values


def check_range(rng: float, min_range: float, max_range: float) -> tuple[bool, str]:
    """A ``sensor_msgs/Range`` reading: finite, positive and within ``[min_range, max_range]``.

    REP 117's +-inf readings ("nothing detected" / "too close") carry no range and are refused as
    ``range_out_of_limits``; NaN as ``non_finite``. Limits that are not finite, or ``max_range <= 0``
    or ``min_range > max_range``, are treated as "not given" and not applied.
    """
    rng = float(rng)
    if math.isnan(rng):
        return False, "non_finite"
    if math.isinf(rng):
        return False, "range_out_of_limits"
    if rng <= 0.0:
        return False, "non_positive_range"
    lo, hi = float(min_range), float(max_range)
    if math.isfinite(lo) and math.isfinite(hi) and 0.0 < hi and lo <= hi and not lo <= rng <= hi:
        return False, "range_out_of_limits"
    return OK


def check_finite(*values: float) -> tuple[bool, str]:
    """All values finite."""
    if all(math.isfinite(float(v)) for v in values):
        return OK
    return False, "non_finite"


def check_covariance(cov) -> tuple[bool, str]:
    """A covariance block ``(k, k)``: finite (``non_finite``), symmetric and positive definite
    (``not_positive_definite``)."""
    a = np.asarray(cov, dtype=float)
    if not np.all(np.isfinite(a)):
        return False, "non_finite"
    if not np.allclose(a, a.T, rtol=1e-9, atol=0.0) or np.linalg.eigvalsh(0.5 * (a + a.T)).min() <= 0.0:
        return False, "not_positive_definite"
    return OK


def check_quaternion(x: float, y: float, z: float, w: float, tolerance: float) -> tuple[bool, str]:
    """A finite quaternion of norm within ``tolerance`` of 1."""
    if not check_finite(x, y, z, w)[0]:
        return False, "non_finite"
    if abs(math.sqrt(x * x + y * y + z * z + w * w) - 1.0) > tolerance:
        return False, "non_unit_quaternion"
    return OK


def check_timing(stamp_ns: int, last_ns: int | None, now_ns: int | None,
                 max_future_ns: int) -> tuple[bool, str]:
    """``stamp_ns`` not older than ``last_ns`` (equal is fine) and at most ``max_future_ns`` ahead of
    ``now_ns``. ``None`` (or ``now_ns == 0``: a simulated clock that has not ticked yet) skips a check."""
    if now_ns and stamp_ns - now_ns > max_future_ns:
        return False, "future_stamp"
    if last_ns is not None and stamp_ns < last_ns:
        return False, "stale_stamp"
    return OK


class RateLimiter:
    """At most ``rate`` events per one-second window of a monotonic clock (``rate <= 0``: unlimited)."""

    def __init__(self, rate: float):
        self.rate = float(rate)
        self._window_start = -math.inf
        self._count = 0

    def allow(self, now: float) -> bool:
        """Count an event at monotonic time ``now`` [s]; False when it exceeds the rate."""
        if self.rate <= 0.0:
            return True
        if now - self._window_start >= 1.0:
            self._window_start = now
            self._count = 0
        self._count += 1
        return self._count <= self.rate


class ReapplyBudget:
    """How much history late measurements may have re-applied, in seconds of stamps per second of the
    filter's time: a bucket of ``capacity`` s, full at start, refilled at ``rate`` s per second the filter's
    time advances; a late measurement costs its lateness (filter time minus its stamp). Decisions depend on
    the stamps only, so the same input sequence gets the same verdicts on any machine. ``rate <= 0``:
    unlimited."""

    def __init__(self, rate: float, capacity: float, t_ns: int):
        self.rate = float(rate)
        self.capacity = float(capacity)
        self.level = self.capacity
        self._t_ns = int(t_ns)

    def spend(self, t_ns: int, cost: float) -> bool:
        """Refill up to the filter time ``t_ns``, then take ``cost`` [s]; False (nothing taken) when less
        than ``cost`` is left."""
        if self.rate <= 0.0:
            return True
        if t_ns > self._t_ns:
            self.level = min(self.capacity, self.level + self.rate * (t_ns - self._t_ns) * 1e-9)
            self._t_ns = int(t_ns)
        if cost > self.level:
            return False
        self.level -= cost
        return True


class Counters:
    """Accepted messages per stream, refused messages per reason, masked components.

    Attributes:
        accepted: ``Counter`` of stream name -> messages used.
        rejected: ``Counter`` of reason -> messages refused (every reason of :data:`REASONS` is present).
        rejected_by_stream: ``Counter`` of ``(stream, reason)``.
        masked: number of NaN components masked in otherwise accepted measurements.
    """

    def __init__(self):
        self.accepted: Counter = Counter()
        self.rejected: Counter = Counter({reason: 0 for reason in REASONS})
        self.rejected_by_stream: Counter = Counter()
        self.masked = 0

    def accept(self, stream: str) -> None:
        self.accepted[stream] += 1

    def reject(self, stream: str, reason: str) -> int:
        """Count a refusal; returns how many times ``reason`` has been counted so far."""
        self.rejected[reason] += 1
        self.rejected_by_stream[(stream, reason)] += 1
        return self.rejected[reason]

    @property
    def total_accepted(self) -> int:
        return sum(self.accepted.values())

    @property
    def total_rejected(self) -> int:
        return sum(self.rejected.values())
