"""The co-state integrity monitor in the estimator: engine rules without DDS, then real nodes over DDS.

* engine: the monitor is fed after each update with a co-state (not at ``dt = 0``), reset with the
  filter (``reset``, ``set_pose``, recovery), its alarms held ``monitor_hold`` s; EKF: unavailable;
* DDS: a probe publishes a consistent measurement stream (``epsilon = 0``) to a real estimator node in
  lockstep (every message answered before the next), then the same stream with a sudden +3 km
  (100 sigma) range bias: ``/diagnostics`` stays below ERROR while the monitor is ready on the clean
  stream, goes to ERROR with ``integrity FAULT`` as the cause after the bias, and ``~/reset`` resets the
  monitor; an EKF reports the monitor unavailable, ``monitor_enabled: false`` disabled; bad monitor
  parameters are refused at start-up.
The ROS helpers (private domain, executor, recording probe) are those of test_ros_nodes.py.
"""
import numpy as np
import pytest

from gpf_nav.ros import diagnostics as diag
from gpf_nav.estimator.engine import EngineConfig, EstimatorEngine
from gpf_nav.estimator.factory import make_filter
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

S = 1_000_000_000
CLEAN = ScenarioConfig(duration=300.0, epsilon=0.0)  # the filter's model is the truth's: no mismatch
BIAS = 3000.0  # m, 100 range sigmas


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _engine(scenario, name="gpf", clock=None, **config):
    model = filter_model(scenario.config)
    cfg = EngineConfig(initial_state=scenario.prior_mean, initial_std=np.sqrt(np.diag(scenario.prior_cov)),
                       initial_stamp=scenario.start_time, **config)
    return EstimatorEngine(lambda: make_filter(name, model, n_particles=200, seed=1), model, cfg,
                           clock or _Clock())


def _stamp(scenario, k):
    return int(round(scenario.times[k] * S))


# --- engine ---------------------------------------------------------------------------------------------
def test_engine_feeds_holds_and_resets_the_monitor():
    s = generate(CLEAN, 0)
    clock = _Clock()
    eng = _engine(s, clock=clock, monitor_hold=5.0)
    n_clean = 100
    for k in range(n_clean):
        assert eng.measurement(_stamp(s, k), s.measurements[k], None) == (True, "")
    report = eng.integrity()
    assert report.state == "active" and report.samples == n_clean and report.status.ready
    assert report.level == "OK" and report.fault_updates == 0

    # a duplicate (same stamp, dt = 0): used by the filter, but it has no co-state: not fed
    assert eng.measurement(_stamp(s, n_clean - 1), s.measurements[n_clean - 1], None) == (True, "")
    assert eng.integrity().samples == n_clean and eng.integrity().skipped == 1

    # a sudden range bias: FAULT at once, diagnostics ERROR with the monitor as the cause
    y = s.measurements[n_clean].copy()
    y[0] += BIAS
    eng.measurement(_stamp(s, n_clean), y, None)
    report = eng.integrity()
    assert report.level == "FAULT" and report.alarm is None and report.fault_updates == 1
    level, message, values = diag.filter_status(eng, _stamp(s, n_clean), diag.Thresholds(costate_warn=1e12), "gpf")
    kv = dict(values)
    # (the default GPF's weights also collapse on a 10-sigma range outlier: an ESS WARN may come first)
    assert level == diag.ERROR and "integrity FAULT: co-state mean T^2" in message
    assert "re-initialised" not in message
    assert kv["integrity level"] == "FAULT" and kv["integrity ready"] == "true"
    assert float(kv["integrity statistic"]) > float(kv["integrity threshold"]) > 0
    assert float(kv["integrity p-value"]) < 1e-3 and "range" in kv["integrity components"]

    # the alarm is held monitor_hold s of the steady clock, then the last update's level is reported
    # (clean updates until the instantaneous level has left FAULT: the outlier pulled the default GPF's
    # state, whose co-state then stays biased for a few tens of updates)
    for k in range(n_clean + 1, n_clean + 300):
        eng.measurement(_stamp(s, k), s.measurements[k], None)
        if k > n_clean + 30 and eng.integrity().status.level != "FAULT":
            break
    report = eng.integrity()
    assert report.status.level != "FAULT" and report.level == "FAULT" and report.alarm is not None
    assert "s ago" in diag.filter_status(eng, _stamp(s, k), diag.Thresholds(costate_warn=1e12), "gpf")[1]
    clock.t += 5.1
    assert eng.integrity().level == report.status.level

    # reset and set_pose forget every sample; the cumulative counters stay
    faults = eng.integrity().fault_updates
    assert faults >= 1
    eng.reset()
    report = eng.integrity()
    assert report.samples == 0 and not report.status.ready and report.fault_updates == faults
    assert report.resets == 1
    for k in range(3):
        eng.measurement(_stamp(s, k), s.measurements[k], None)
    assert eng.integrity().samples == 3
    ok, _ = eng.set_pose(_stamp(s, 3), s.truth[4, :3], None, None)
    assert ok and eng.integrity().samples == 0 and eng.integrity().resets == 2


def test_engine_latches_with_a_negative_hold_and_masks_the_increment_reference():
    """The mask is the filter's ``costate_measured`` (part of the co-state capability of the interface)."""
    s = generate(CLEAN, 0)
    clock = _Clock()
    eng = _engine(s, clock=clock, monitor_hold=-1.0)
    for k in range(90):
        eng.measurement(_stamp(s, k), s.measurements[k], None)
    y = s.measurements[90].copy()
    y[0] += BIAS
    eng.measurement(_stamp(s, 90), y, None)
    for k in range(91, 130):
        eng.measurement(_stamp(s, k), s.measurements[k], None)
    clock.t += 1e6
    report = eng.integrity()
    assert report.status.level == "OK" and report.level == "FAULT"  # latched
    eng.reset()
    assert eng.integrity().level == "OK"

    # increment reference: a component not measured at the previous update has no co-state
    inc = EstimatorEngine(lambda: make_filter("gpf", filter_model(CLEAN), n_particles=100, seed=1,
                                              reference="increment", metric="euclidean"), filter_model(CLEAN), eng.config, clock)
    masks = []
    update = inc.monitor.update
    inc.monitor.update = lambda lam, measured: masks.append(np.asarray(measured).tolist()) or update(lam, measured)
    for k in range(6):
        y = s.measurements[k].copy()
        if k == 2:
            y[1] = np.nan
        inc.measurement(_stamp(s, k), y, None)
    # update 0 has no previous measurement; the azimuth is missing at update 2, and before update 3
    assert masks == [[False] * 3, [True] * 3, [True, False, True], [True, False, True], [True] * 3, [True] * 3]
    assert inc.monitor.unmeasured == 1 and inc.monitor.samples == 5


def test_engine_recovery_resets_the_monitor_and_ekf_has_none():
    s = generate(CLEAN, 1)
    eng = _engine(s)
    for k in range(20):
        eng.measurement(_stamp(s, k), s.measurements[k], None)
    assert eng.integrity().samples == 20
    eng._recover(_stamp(s, 19), "test")  # what a filter exception or a non-finite estimate leads to
    assert eng.integrity().samples == 0 and eng.init_source == "recovery"
    eng.measurement(_stamp(s, 20), s.measurements[20], None)
    assert eng.integrity().samples == 1

    ekf = _engine(s, name="ekf")
    ekf.measurement(_stamp(s, 0), s.measurements[0], None)
    assert ekf.integrity().state == "unavailable" and ekf.integrity().level == "OK"
    kv = dict(diag.filter_status(ekf, _stamp(s, 0), diag.Thresholds(), "ekf")[2])
    assert kv["integrity level"] == "unavailable" and kv["integrity monitor"] == "unavailable: ekf has no co-state"
    assert kv["integrity statistic"] == "n/a"
    off = _engine(s, monitor=None)
    off.measurement(_stamp(s, 0), s.measurements[0], None)
    assert off.integrity().state == "disabled"


# --- over DDS -------------------------------------------------------------------------------------------
rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import Vector3Stamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph_msgs.msg import Clock as ClockMsg  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from gpf_nav.ros import conversions as conv  # noqa: E402
from gpf_nav.ros.estimator_node import EstimatorNode  # noqa: E402
from gpf_nav.estimator.params import ParameterError  # noqa: E402
from test_ros_nodes import _assert_diagnostics_finite, _rae, ros  # noqa: E402,F401

ERROR, WARN = b"\x02", b"\x01"


class _Feed:
    """Publishes the scenario's measurements to an estimator on simulated time, one at a time: ``/clock``
    is first set to the measurement's stamp (so its age, and the node's idea of "now", never depend on
    how fast this machine feeds), then the measurement is sent again until its odometry comes back: no
    message is lost, the stream is processed in order."""

    base = 1000 * S  # ROS time of the scenario's start

    def __init__(self, ros, scenario, **params):
        self.ros, self.scenario = ros, scenario
        self.odom = ros.record(Odometry, "odometry/filtered")
        self.diagnostics = ros.record(DiagnosticArray, "/diagnostics")
        prior_std = np.sqrt(np.diag(scenario.prior_cov))
        overrides = dict(n_particles=200, publish_rate=0.0, diagnostics_period=0.25, max_published_particles=0,
                         initial_state=[float(v) for v in scenario.prior_mean], use_sim_time=True,
                         initial_std=[float(v) for v in prior_std], initial_stamp=self.base * 1e-9)
        overrides.update(params)
        self.est = ros.add(EstimatorNode(context=ros.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in overrides.items()]))
        self.pub = ros.node.create_publisher(Vector3Stamped, "measurements/rae", 100)
        self.clock_pub = ros.node.create_publisher(ClockMsg, "/clock", 10)
        assert ros.spin_until(lambda: self.pub.get_subscription_count() > 0 and self.diagnostics
                              and self.clock_pub.get_subscription_count() > 0, 30.0)

    def stamp(self, k):
        return self.base + int(round(self.scenario.times[k] * S))

    def send(self, k, bias=0.0):
        y = self.scenario.measurements[k].copy()
        y[0] += bias
        stamp = self.stamp(k)
        for _ in range(100):
            self.clock_pub.publish(ClockMsg(clock=conv.ns_to_stamp(stamp)))
            if self.ros.spin_until(lambda: self.est.get_clock().now().nanoseconds >= stamp, 1.0):
                break
        else:
            raise AssertionError(f"the estimator's clock did not reach measurement {k}")
        for _ in range(20):
            self.pub.publish(_rae(stamp, y))
            if self.ros.spin_until(lambda: self.odom and conv.stamp_to_ns(self.odom[-1].header.stamp) == stamp, 1.0):
                return
        raise AssertionError(f"no odometry for measurement {k}")

    def status_after(self, condition=lambda v: True, timeout=10.0):
        """The first /diagnostics status that arrives from now on and satisfies ``condition``."""
        start = len(self.diagnostics)

        def found():
            return any(condition(diag.parse_values(st)) or False for m in self.diagnostics[start:]
                       for st in m.status)
        assert self.ros.spin_until(lambda: len(self.diagnostics) > start and found(), timeout)
        for m in self.diagnostics[start:]:
            for st in m.status:
                if condition(diag.parse_values(st)):
                    return st, diag.parse_values(st)


def test_range_bias_raises_error_with_the_monitor_as_cause_over_dds(ros):
    scenario = generate(CLEAN, 0)
    n_clean = 120  # the monitor is ready after (6 + 1) * (10 + 2) = 84 updates
    feed = _Feed(ros, scenario, monitor_hold=3.0)
    ready_levels = []
    for k in range(n_clean):
        feed.send(k)
        if k > 84:
            ready_levels.append(feed.est.engine.integrity().level)
    status, values = feed.status_after(lambda v: v["integrity samples"] == str(n_clean))
    assert values["integrity monitor"] == "active" and values["integrity ready"] == "true"
    # a consistent stream: no ERROR; loose: one FAULT update (rate 1e-3) and a few WARNs are tolerated
    assert int(values["integrity fault updates"]) <= 1, values
    assert int(values["integrity warn updates"]) <= 6, values
    if values["integrity fault updates"] == values["integrity warn updates"] == "0":
        assert status.level == b"\x00" and status.message == "tracking", status.message
    elif values["integrity fault updates"] == "0":
        assert status.level != ERROR, status.message
    assert ready_levels.count("OK") >= 0.8 * len(ready_levels)
    assert float(values["integrity p-value"]) > 1e-3 and values["integrity components"] == "range, azimuth, elevation"
    # the consistency monitor beside it: every measurement tested, at most its rate of FAULTs
    assert values["consistency updates"] == str(n_clean) and int(values["consistency fault updates"]) <= 1

    # sudden +3 km range bias from measurement n_clean on
    for k in range(n_clean, n_clean + 4):
        feed.send(k, bias=BIAS)
    status, values = feed.status_after(lambda v: v["integrity level"] == "FAULT")
    assert status.level == ERROR
    assert "integrity FAULT" in status.message and "re-initialised" not in status.message
    assert values["reinitializations"] == "0" and int(values["integrity fault updates"]) >= 4
    assert float(values["integrity statistic"]) > float(values["integrity threshold"])
    assert float(values["integrity p-value"]) < 1e-3
    # 100 range sigmas: the innovations are far larger than the covariance allows, named as a cause too
    assert values["consistency level"] == "FAULT" and "consistency FAULT" in status.message

    # ~/reset: the monitor forgets its samples and its alarm
    client = ros.node.create_client(Trigger, "/gpf_estimator/reset")
    assert client.wait_for_service(timeout_sec=20.0)
    future = client.call_async(Trigger.Request())
    assert ros.spin_until(future.done, 20.0) and future.result().success
    status, values = feed.status_after()
    assert values["integrity samples"] == "0" and values["integrity ready"] == "false"
    assert values["integrity level"] == "OK" and int(values["integrity resets"]) >= 1
    assert status.level != ERROR
    _assert_diagnostics_finite(feed.diagnostics)


@pytest.mark.parametrize("params, level, monitor", [
    (dict(filter="ekf"), "unavailable", "unavailable: ekf has no co-state"),
    (dict(filter="spf", compute_costate=False), "unavailable", "unavailable: spf has no co-state"),
    (dict(monitor_enabled=False), "disabled", "disabled (monitor_enabled: false)"),
])
def test_monitor_unavailable_or_disabled_over_dds(ros, params, level, monitor):
    feed = _Feed(ros, generate(ScenarioConfig(duration=20.0, epsilon=0.0), 2), **params)
    for k in range(3):
        feed.send(k)
    status, values = feed.status_after(lambda v: v["measurements accepted"] == "3")
    assert values["integrity level"] == level and values["integrity monitor"] == monitor
    assert values["integrity statistic"] == "n/a" and values["integrity samples"] == "0"
    assert status.level == b"\x00" and status.message == "tracking", status.message
    _assert_diagnostics_finite(feed.diagnostics)


@pytest.mark.parametrize("name, value, text", [
    ("monitor_window", 0, "'monitor_window' = 0 must be >= 1"),
    ("monitor_min_reference", 1, "2 <= monitor_min_reference <= monitor_reference"),
    ("monitor_false_alarm_rate", 0.0, "'monitor_false_alarm_rate' = 0.0 must lie in (0, 1)"),
    ("monitor_warn_false_alarm_rate", 1e-4, "'monitor_warn_false_alarm_rate' = 0.0001 must lie in"),
    ("monitor_quarantine_rate", 0.5, "'monitor_quarantine_rate' = 0.5"),
    ("monitor_hold", float("inf"), "'monitor_hold' = inf must be finite"),
])
def test_invalid_monitor_parameters_are_refused(ros, name, value, text):
    with pytest.raises(ParameterError) as err:
        EstimatorNode(context=ros.context, parameter_overrides=[Parameter(name, value=value)])
    assert text in str(err.value)
