"""Timing faults a ROS stack produces, on real nodes over DDS (private domain, simulated time):

* the node clock jumps back (a restarted simulator) with ``publish_rate`` 0: with ``reset_on_time_jump``
  (default) the filter resets at the first input after the jump and odometry resumes on the new
  stamps; without it the jump is counted and the old stamps are refused;
* a stream of late measurements: the re-application budget (``reapply_budget``, seconds of lateness
  per second of stamps) refuses the excess as ``reapply_budget``, the same messages on every run;
* a persistent integrity FAULT: after ``integrity_fault_updates`` FAULT updates in a row the filter
  re-initialises (``integrity_fault_action``), logged and counted.

A probe drives ``/clock`` and sends one measurement at a time, waiting until the estimator has counted
it, so nothing depends on how fast this machine is.
"""
import pytest

rclpy = pytest.importorskip("rclpy")

from rosgraph_msgs.msg import Clock as ClockMsg  # noqa: E402

from gpf_nav.ros import conversions as conv  # noqa: E402
from gpf_nav.ros import diagnostics as diag  # noqa: E402
from gpf_nav.sim.scenario import ScenarioConfig, generate  # noqa: E402
from test_ros_integrity import _Feed  # noqa: E402
from test_ros_nodes import _assert_diagnostics_finite, _rae, ros  # noqa: E402,F401

S = 1_000_000_000
SCENARIO = ScenarioConfig(duration=400.0, epsilon=0.0)


class _Probe(_Feed):
    """An estimator on simulated time, initialised from parameters at ``base``, and a probe that sets
    ``/clock`` and sends measurements one at a time."""

    def clock(self, stamp: int) -> None:
        """Set ``/clock`` to ``stamp`` (forward or back) and wait until the estimator's clock reads it."""
        for _ in range(100):
            self.clock_pub.publish(ClockMsg(clock=conv.ns_to_stamp(stamp)))
            if self.ros.spin_until(lambda: self.est.get_clock().now().nanoseconds == stamp, 1.0):
                return
        raise AssertionError(f"the estimator's clock did not reach {stamp}")

    def counted(self) -> int:
        c = self.est.engine.counters
        return c.total_accepted + c.total_rejected

    def send(self, k: int, stamp: int | None = None, bias: float = 0.0) -> None:
        """Measurement ``k`` (stamped ``stamp``, default its own), waiting until the estimator counted it."""
        y = self.scenario.measurements[k].copy()
        y[0] += bias
        before = self.counted()
        self.pub.publish(_rae(self.stamp(k) if stamp is None else stamp, y))
        assert self.ros.spin_until(lambda: self.counted() > before, 30.0), f"measurement {k} was not counted"

    def step(self, k: int, bias: float = 0.0) -> None:
        """Clock to measurement ``k``'s stamp, then the measurement."""
        self.clock(self.stamp(k))
        self.send(k, bias=bias)

    def odometry_at(self, stamp: int) -> bool:
        """Whether odometry stamped ``stamp`` arrives (within 10 s)."""
        return self.ros.spin_until(lambda: any(conv.stamp_to_ns(m.header.stamp) == stamp for m in self.odom), 10.0)

    def values(self, condition=lambda v: True, timeout: float = 10.0) -> dict:
        """The key/values of the first /diagnostics status from now on that satisfies ``condition``."""
        start = len(self.diagnostics)

        def found():
            return next((diag.parse_values(st) for m in self.diagnostics[start:] for st in m.status
                         if condition(diag.parse_values(st))), None)
        assert self.ros.spin_until(lambda: found() is not None, timeout)
        return found()


@pytest.mark.parametrize("reset", [True, False])
def test_backward_clock_jump_without_publish_timer_resets_over_dds(ros, reset):
    probe = _Probe(ros, generate(SCENARIO, 0), reset_on_time_jump=reset)
    for k in range(20):
        probe.step(k)
    assert probe.odometry_at(probe.stamp(19))

    # the simulator restarts: its clock goes back to the start, its measurements come again
    probe.clock(probe.base)
    n_odom = len(probe.odom)
    for k in range(5):
        probe.step(k)
    def settled(v: dict) -> bool:  # every repeated measurement taken or refused
        refused = int(v["rejected older_than_history"]) + int(v["rejected stale_stamp"])
        return v["measurements accepted"] == str(20 + (5 if reset else 0)) and (reset or refused >= 5)

    values = probe.values(settled)
    assert values["node clock jumps back"] == "1"
    assert not reset or probe.odometry_at(probe.stamp(4))
    stamps = [conv.stamp_to_ns(m.header.stamp) for m in probe.odom[n_odom:]]
    if reset:
        assert stamps == [probe.stamp(k) for k in range(5)], stamps
        assert values["rejected older_than_history"] == "0" and values["rejected stale_stamp"] == "0"
        assert values["initialized from"] == "parameters"
    else:
        assert stamps == []
        assert values["rejected older_than_history"] == "5"
    _assert_diagnostics_finite(probe.diagnostics)


def _budget_verdicts(lateness: float, step: float, n: int, rate: float, capacity: float) -> list[bool]:
    """Which of ``n`` late measurements (each ``lateness`` s late, one per ``step`` s of filter time) a
    bucket of ``capacity`` s refilled at ``rate`` s per s accepts: the rule written out independently."""
    level, out = capacity, []
    for i in range(n):
        if i:
            level = min(capacity, level + rate * step)
        out.append(level >= lateness)
        if out[-1]:
            level -= lateness
    return out


def test_stream_of_late_measurements_is_held_to_the_budget_over_dds(ros):
    scenario = generate(SCENARIO, 1)
    probe = _Probe(ros, scenario)
    for k in range(20):
        probe.step(k)
    engine = probe.est.engine
    replayed = engine.replayed_count
    n_late, lag = 20, 3  # each in-order measurement k followed by a copy of k - 3: 6 s late
    for k in range(20, 20 + n_late):
        probe.step(k)
        probe.send(k - lag, stamp=probe.stamp(k - lag))
    step = SCENARIO.dt
    expected = _budget_verdicts(lag * step, step, n_late, rate=0.5, capacity=10.0)
    def settled(v: dict) -> bool:  # every measurement sent taken or refused (the last may be a refusal)
        return int(v["measurements accepted"]) + int(v["measurements rejected"]) == 20 + 2 * n_late

    values = probe.values(settled)
    assert values["measurements accepted"] == str(20 + n_late + sum(expected))
    assert 0 < sum(expected) < n_late
    assert values["rejected reapply_budget"] == str(n_late - sum(expected))
    assert values["late measurements fused"] == str(sum(expected))
    assert values["rejected older_than_history"] == "0"
    # each late one fused re-applied at most its 3 successors and the inputs back to the snapshot before it
    assert engine.replayed_count - replayed <= sum(expected) * (lag + 4)
    assert probe.odometry_at(probe.stamp(20 + n_late - 1))
    _assert_diagnostics_finite(probe.diagnostics)


@pytest.mark.parametrize("action", ["measurements", "prior"])
def test_persistent_integrity_fault_reinitialises_over_dds(ros, action):
    probe = _Probe(ros, generate(SCENARIO, 2), integrity_fault_action=action, integrity_fault_updates=3)
    n_clean = 100  # the monitor is ready after (6 + 1) * (10 + 2) = 84 updates
    for k in range(n_clean):
        probe.step(k)
    engine = probe.est.engine
    assert engine.init_source == "parameters"
    k = n_clean
    while engine.initialized and engine.init_source == "parameters" and k < n_clean + 30:  # a +3 km range bias until the filter gives up
        probe.step(k, bias=3000.0)
        k += 1
    assert k < n_clean + 30, f"30 updates after the bias the filter still holds {engine.init_source}'s state"
    values = probe.values(lambda v: v.get("integrity fault reinitializations") == "1")
    assert int(values["integrity fault updates"]) >= 3 and values["reinitializations"] == "1"
    assert "integrity FAULT for 3 updates in a row" in engine.last_reinit_reason
    if action == "prior":
        assert values["initialized from"] == "prior" and probe.odometry_at(probe.stamp(k - 1))
        first = k
    else:
        assert values["initialized"] == "false"
        for j in range(k, k + 10):  # the batch fit of init_window clean measurements
            probe.step(j)
        first = k + 9
        values = probe.values(lambda v: v["initialized"] == "true")
        assert values["initialized from"] == "measurements"
    probe.step(first + 1)
    assert probe.odometry_at(probe.stamp(first + 1))
    _assert_diagnostics_finite(probe.diagnostics)
