"""Real rclpy nodes exchanging real messages over DDS (isolated: private ROS_DOMAIN_ID, localhost only).

* simulator -> estimator -> a subscriber here that compares odometry/filtered with truth/odometry, on
  simulated time (and a stopped clock stops the predictions);
* every kind of bad input sent on the wire, seen counted in /diagnostics, never a NaN out; a flood;
  the ~/reset service and set_pose;
* invalid parameters refused at start-up.
The estimator as a separate process from its installed console script is in test_ros_colcon.py.
"""
import math
import threading
import time

import numpy as np
import pytest

from domains import fresh_domain

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped, Vector3Stamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph_msgs.msg import Clock as ClockMsg  # noqa: E402
from sensor_msgs.msg import Imu, Range  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from gpf_nav.ros import conversions as conv  # noqa: E402
from gpf_nav.ros.diagnostics import STATUS_NAME, parse_values  # noqa: E402
from gpf_nav.ros.estimator_node import EstimatorNode  # noqa: E402
from gpf_nav.estimator.params import ParameterError  # noqa: E402
from gpf_nav.ros.simulator_node import SimulatorNode  # noqa: E402
from gpf_nav.sim.scenario import ScenarioConfig, generate  # noqa: E402

S = 1_000_000_000


class Ros:
    """One private rclpy context on a fresh domain, an executor and a recording test node."""

    def __init__(self):
        self.domain = fresh_domain()
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context, domain_id=self.domain)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes = []
        self.node = self.add(rclpy.create_node("gpf_test_probe", context=self.context))
        self.received: dict[str, list] = {}

    def add(self, node):
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def record(self, msg_type, topic, depth=1000):
        self.received[topic] = []
        self.node.create_subscription(msg_type, topic, self.received[topic].append, depth)
        return self.received[topic]

    def spin_until(self, condition, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return condition()

    def spin_for(self, seconds):
        self.spin_until(lambda: False, seconds)

    def close(self):
        self.executor.shutdown()
        for node in self.nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def ros():
    r = Ros()
    yield r
    r.close()


def _finite_odometry(msg) -> bool:
    values = [msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z,
              msg.pose.pose.orientation.w, msg.twist.twist.linear.x, msg.twist.twist.linear.y,
              msg.twist.twist.linear.z, *msg.pose.covariance, *msg.twist.covariance]
    return all(math.isfinite(v) for v in values)


def _latest_status(diagnostics):
    for msg in reversed(diagnostics):
        for status in msg.status:
            if status.name == STATUS_NAME:
                return status
    return None


def _assert_diagnostics_finite(diagnostics):
    for msg in diagnostics:
        for status in msg.status:
            for kv in status.values:
                try:
                    value = float(kv.value)
                except ValueError:
                    continue
                assert math.isfinite(value), (kv.key, kv.value)


# --- simulator -> estimator ---------------------------------------------------------------------------
@pytest.mark.parametrize("filter_name", ["gpf", "gpf-single"])
def test_simulator_to_estimator_on_sim_time_tracks_truth(ros, filter_name):
    sim_seconds, start = 200.0, 1000.0
    odom = ros.record(Odometry, "odometry/filtered")
    truth = ros.record(Odometry, "truth/odometry")
    ess = ros.record(Float64, "gpf/ess")
    costate = ros.record(Vector3Stamped, "gpf/costate")
    acceleration = ros.record(Vector3Stamped, "gpf/unmodelled_acceleration")
    particles = ros.record(PoseArray, "gpf/particles")
    clock = ros.record(ClockMsg, "/clock")
    diagnostics = ros.record(DiagnosticArray, "/diagnostics")
    # The simulator releases messages by the wall clock; on a busy machine this executor falls behind and
    # they arrive in bursts. Queues deeper than the whole run (100 measurements; truth only at their
    # stamps, no IMU) lose none of them, and every wait below is on a condition, not a duration.
    est = ros.add(EstimatorNode(context=ros.context, parameter_overrides=[
        Parameter("use_sim_time", value=True), Parameter("n_particles", value=300),
        Parameter("filter", value=filter_name),
        Parameter("diagnostics_period", value=0.5), Parameter("queue_depth", value=200)]))
    sim = ros.add(SimulatorNode(context=ros.context, parameter_overrides=[
        Parameter("rate_factor", value=25.0), Parameter("scenario.duration", value=sim_seconds),
        Parameter("start_time", value=start), Parameter("start_delay", value=1.5),
        Parameter("truth_rate", value=0.0), Parameter("imu_rate", value=0.0),
        Parameter("hand_over_prior", value=False)]))  # initialised from the measurements
    assert ros.spin_until(lambda: sim.finished, 300.0), "the simulator did not finish"
    counters = est.engine.counters

    def processed():  # every measurement the simulator sent has been accepted or refused
        refused = sum(n for (stream, _), n in counters.rejected_by_stream.items() if stream == "rae")
        return counters.accepted["rae"] + refused >= sim.published["measurement"]

    def answered():  # ... and every update's odometry and the last diagnostics have reached us
        seen = {conv.stamp_to_ns(m.header.stamp) for m in truth}
        updates = sum(conv.stamp_to_ns(m.header.stamp) in seen for m in odom)
        status = _latest_status(diagnostics)
        return (updates >= counters.accepted["rae"] - 9 and status is not None
                and parse_values(status)["measurements accepted"] == str(counters.accepted["rae"]))

    assert ros.spin_until(processed, 120.0), (counters.accepted, counters.rejected_by_stream)
    assert ros.spin_until(answered, 120.0)

    # simulated time: every stamp is on the simulated clock, none on the wall clock
    stamps = [conv.stamp_to_ns(m.header.stamp) for m in odom]
    assert stamps and min(stamps) >= start * S and max(stamps) <= (start + sim_seconds + 1.0) * S
    assert max(conv.stamp_to_ns(m.clock) for m in clock) == (start + sim_seconds) * S
    # accuracy against truth at the measurement stamps (after the 10-measurement initialisation)
    truth_at = {conv.stamp_to_ns(m.header.stamp): conv.odometry_state(m) for m in truth}
    errors = np.array([conv.odometry_state(m) - truth_at[conv.stamp_to_ns(m.header.stamp)]
                       for m in odom if conv.stamp_to_ns(m.header.stamp) in truth_at])
    assert len(errors) >= 70, f"only {len(errors)} estimates at truth stamps"
    pos = np.linalg.norm(errors[:, :3], axis=1)
    vel = np.linalg.norm(errors[:, 3:], axis=1)
    assert np.median(pos) < 5e3 and pos.max() < 25e3, (np.median(pos), pos.max())
    assert np.median(vel) < 300.0, np.median(vel)
    assert all(_finite_odometry(m) for m in odom)
    assert ess and all(0.0 < m.data <= 1.0 for m in ess)
    assert costate and all(math.isfinite(v) for m in costate for v in (m.vector.x, m.vector.y, m.vector.z))
    assert particles and 0 < len(particles[-1].poses) <= 100
    # the default GPF's estimated unmodelled acceleration (the scenario's gravity is 9 % off): finite,
    # in the world frame, a fraction of a m/s^2, and in the diagnostics with its standard deviations
    assert acceleration and all(m.header.frame_id == "moon_inertial" for m in acceleration)
    last = acceleration[-1].vector
    assert all(math.isfinite(v) for m in acceleration for v in (m.vector.x, m.vector.y, m.vector.z))
    assert 0.0 < math.hypot(last.x, last.y, last.z) < 1.0
    status = _latest_status(diagnostics)
    values = parse_values(status)
    assert len(values["unmodelled acceleration [m/s^2]"].split()) == 3
    assert all(float(v) > 0.0 for v in values["unmodelled acceleration std [m/s^2]"].split())
    probability = values["compensated model probability"]
    assert 0.0 <= float(probability) <= 1.0  # gpf: its IMM; gpf-single: its model average
    assert values["initialized from"] == "measurements"
    assert sim.published["measurement"] == 100
    assert int(values["measurements accepted"]) >= 95
    _assert_diagnostics_finite(diagnostics)
    assert est.engine.reinit_count == 0

    # the simulator has stopped its clock: the estimator's prediction timer stops with it (no odometry
    # stamped after the last /clock, however long we wait)
    ros.spin_for(1.5)
    assert max(conv.stamp_to_ns(m.header.stamp) for m in odom) <= (start + sim_seconds) * S


# --- bad input ----------------------------------------------------------------------------------------
def _rae(stamp_ns, values, frame="station", nanosec=None):
    msg = conv.vector3_stamped([0.0, 0.0, 0.0], stamp_ns, frame)
    msg.vector.x, msg.vector.y, msg.vector.z = (float(v) for v in values)
    if nanosec is not None:
        msg.header.stamp.nanosec = nanosec
    return msg


def _imu(stamp_ns, accel=(0.0, 0.0, 0.0), quat=(0.0, 0.0, 0.0, 1.0), accel_cov0=0.0, frame="base_link"):
    msg = Imu()
    msg.header.stamp = conv.ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = quat
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = accel
    msg.linear_acceleration_covariance[0] = accel_cov0
    return msg


def _imu_before_each_measurement(ros, samples: int) -> dict[str, str]:
    """Ten measurements, each published after ``samples`` IMU samples stamped in the 0.1 s before it (all
    waiting together when the estimator's executor looks); the estimator's diagnostics once every sample
    is counted."""
    scenario = generate(ScenarioConfig(duration=60.0), 11)
    base = ros.node.get_clock().now().nanoseconds - int(100 * S)
    stamp = [base + int(round(t * S)) for t in scenario.times]
    odom = ros.record(Odometry, "odometry/filtered")
    diagnostics = ros.record(DiagnosticArray, "/diagnostics")
    ros.add(EstimatorNode(context=ros.context, parameter_overrides=[
        Parameter("n_particles", value=200), Parameter("publish_rate", value=0.0),
        Parameter("initial_state", value=[float(v) for v in scenario.prior_mean]),
        Parameter("initial_std", value=[float(v) for v in np.sqrt(np.diag(scenario.prior_cov))]),
        Parameter("initial_stamp", value=base * 1e-9), Parameter("diagnostics_period", value=0.25)]))
    rae = ros.node.create_publisher(Vector3Stamped, "measurements/rae", 100)
    imu = ros.node.create_publisher(Imu, "imu", 100)
    assert ros.spin_until(lambda: rae.get_subscription_count() and imu.get_subscription_count() and diagnostics,
                          30.0)
    for k in range(1, 11):
        for j in range(samples):
            imu.publish(_imu(stamp[k] - (samples - j) * S // (10 * samples), accel=(0.0, 0.0, 0.1)))
        rae.publish(_rae(stamp[k], scenario.measurements[k]))
        assert ros.spin_until(lambda: any(conv.stamp_to_ns(m.header.stamp) == stamp[k] for m in odom), 20.0)

    def imu_counted() -> bool:  # a loaded machine can deliver the last sample after its measurement's odometry
        status = _latest_status(diagnostics)
        return status is not None and int(parse_values(status)["accepted imu"]) >= 10 * samples

    assert ros.spin_until(imu_counted, 10.0)
    return parse_values(_latest_status(diagnostics))


def test_an_imu_sample_and_the_measurement_after_it_ready_together_are_taken_in_stamp_order(ros):
    """The estimator subscribes to the IMU first: the executor takes the ready subscriptions in the order they
    were made, so a sample and the measurement stamped after it, waiting together, are handled in stamp order.
    The other way round (the measurements first), each measurement's history would be re-applied when
    its sample came: 10 of 10 here."""
    values = _imu_before_each_measurement(ros, 1)
    assert values["accepted imu"] == "10"
    assert int(values["late IMU samples applied"]) <= 1, values["late IMU samples applied"]


def test_a_burst_of_imu_samples_is_handled_before_the_measurement_after_it(ros):
    """Four samples and the measurement after them, waiting together: the executor takes one sample per
    round, but the measurement first takes the samples already received, so none comes late. Without that,
    the later samples of each burst came after their measurement, each re-applying it, and the queue, read
    one sample per round, overflowed (26 late, 13 lost here)."""
    values = _imu_before_each_measurement(ros, 4)
    assert values["accepted imu"] == "40"
    assert int(values["late IMU samples applied"]) <= 2, values["late IMU samples applied"]


def test_bad_inputs_are_dropped_counted_and_never_leak_nan(ros):
    scenario = generate(ScenarioConfig(duration=400.0), 11)
    now = ros.node.get_clock().now().nanoseconds
    base = now - int(300 * S)  # measurement k at base + times[k]; the first 150 lie in the past
    stamp = [base + int(round(t * S)) for t in scenario.times]
    y = scenario.measurements
    prior_std = np.sqrt(np.diag(scenario.prior_cov))
    odom = ros.record(Odometry, "odometry/filtered")
    ess = ros.record(Float64, "gpf/ess")
    costate = ros.record(Vector3Stamped, "gpf/costate")
    particles = ros.record(PoseArray, "gpf/particles")
    diagnostics = ros.record(DiagnosticArray, "/diagnostics")
    est = ros.add(EstimatorNode(context=ros.context, parameter_overrides=[
        Parameter("n_particles", value=200), Parameter("publish_rate", value=0.0),
        Parameter("initial_state", value=[float(v) for v in scenario.prior_mean]),
        Parameter("initial_std", value=[float(v) for v in prior_std]),
        Parameter("initial_stamp", value=base * 1e-9), Parameter("diagnostics_period", value=0.25),
        Parameter("max_measurement_rate", value=50.0), Parameter("range_noise_std", value=30.0)]))
    node = ros.node
    rae = node.create_publisher(Vector3Stamped, "measurements/rae", 100)
    rng = node.create_publisher(Range, "measurements/range", 100)
    imu = node.create_publisher(Imu, "imu", 100)
    pose = node.create_publisher(PoseWithCovarianceStamped, "set_pose", 10)
    assert ros.spin_until(lambda: rae.get_subscription_count() and imu.get_subscription_count()
                          and pose.get_subscription_count() and diagnostics, 30.0)

    def stamps_seen():
        return {conv.stamp_to_ns(m.header.stamp) for m in odom}

    def send(pub, msg):
        pub.publish(msg)
        ros.spin_for(0.05)

    for k in range(3):
        send(rae, _rae(stamp[k], y[k]))
    assert ros.spin_until(lambda: {stamp[0], stamp[1], stamp[2]} <= stamps_seen(), 20.0)

    partial = y[3].copy()
    partial[1] = np.nan  # azimuth not measured: masked, the update goes on
    send(rae, _rae(stamp[3], partial))

    def costates_at(ns):
        return [m for m in costate if conv.stamp_to_ns(m.header.stamp) == ns]

    # the odometry and the co-state are separate topics: either may arrive first
    assert ros.spin_until(lambda: stamp[3] in stamps_seen() and costates_at(stamp[3]), 20.0)
    lam = costates_at(stamp[3])
    assert lam and lam[0].vector.y == 0.0 and lam[0].vector.x != 0.0  # missing component reads 0

    r = Range()
    r.header.frame_id, r.min_range, r.max_range = "station", 1.0, 1.0e7
    bad = [
        ("non_finite", rae, _rae(stamp[4], [math.inf, y[4][1], y[4][2]])),
        ("no_measured_component", rae, _rae(stamp[4], [math.nan] * 3)),
        ("non_positive_range", rae, _rae(stamp[4], [-10.0, y[4][1], y[4][2]])),
        ("angle_out_of_range", rae, _rae(stamp[4], [y[4][0], 4.0, y[4][2]])),
        ("angle_out_of_range", rae, _rae(stamp[4], [y[4][0], y[4][1], -2.0])),
        ("bad_stamp", rae, _rae(stamp[4], y[4], nanosec=1_000_000_000)),
        ("older_than_history", rae, _rae(stamp[1] - 20 * S, y[1])),  # history_length 10 s
        ("future_stamp", rae, _rae(now + 3600 * S, y[4])),
        ("wrong_frame", rae, _rae(stamp[4], y[4], frame="map")),
        ("non_unit_quaternion", imu, _imu(stamp[3] + S, quat=(0.0, 0.0, 0.5, 1.0))),
        ("non_finite", imu, _imu(stamp[3] + S, accel=(math.nan, 0.0, 0.0))),
        ("not_provided", imu, _imu(stamp[3] + S, accel_cov0=-1.0)),
        ("wrong_frame", imu, _imu(stamp[3] + S, frame="odom")),
    ]
    for value, reason in ((math.nan, "non_finite"), (2.0e7, "range_out_of_limits"), (-1.0, "non_positive_range")):
        msg = Range()
        msg.header.stamp = conv.ns_to_stamp(stamp[4])
        msg.header.frame_id, msg.min_range, msg.max_range, msg.range = "station", 1.0, 1.0e7, value
        bad.append((reason, rng, msg))
    nan_pose = PoseWithCovarianceStamped()
    nan_pose.header.stamp = conv.ns_to_stamp(stamp[4])
    nan_pose.header.frame_id = "moon_inertial"
    nan_pose.pose.pose.position.x = math.nan
    bad.append(("non_finite", pose, nan_pose))
    expected: dict[str, int] = {}
    for reason, pub, msg in bad:
        send(pub, msg)
        expected[reason] = expected.get(reason, 0) + 1

    def counted():
        status = _latest_status(diagnostics)
        if status is None:
            return False
        v = parse_values(status)
        return all(int(v[f"rejected {reason}"]) >= n for reason, n in expected.items())

    assert ros.spin_until(counted, 30.0), (expected, parse_values(_latest_status(diagnostics)))
    values = parse_values(_latest_status(diagnostics))
    assert int(values["masked components"]) >= 1

    # still tracking after all that: a good range-only and a good full measurement are used
    good = Range()
    good.header.stamp = conv.ns_to_stamp(stamp[4])
    good.header.frame_id, good.min_range, good.max_range, good.range = "station", 1.0, 1.0e7, float(y[4][0])
    send(rng, good)
    send(imu, _imu(stamp[4] + S // 2))
    send(rae, _rae(stamp[5], y[5]))
    assert ros.spin_until(lambda: {stamp[4], stamp[5]} <= stamps_seen(), 20.0)

    # a flood: shed by the queue and the rate cap (50 per second of the engine's steady clock), the node
    # survives. The engine's clock is held still meanwhile, so the cap is reached however slowly this
    # busy machine lets the node take messages: the flood goes on until the node reports a rate_limit
    # refusal (stamps 0.1 ms apart, all between stamp[5] and stamp[7]).
    counters = est.engine.counters
    before = counters.accepted["rae"]
    held = time.monotonic() + 10.0  # a fresh one-second window starts at the first flood message
    est.engine.monotonic = lambda: held
    stop = threading.Event()
    flood_start = stamp[5] + S // 10_000

    def publish_flood():  # bursts at several kHz while the executor spins, as another process would
        for i in range(19_000):
            if stop.is_set():
                return
            rae.publish(_rae(flood_start + i * S // 10_000, y[6]))
            if i % 10 == 9:
                time.sleep(0.005)

    thread = threading.Thread(target=publish_flood, daemon=True)
    thread.start()
    try:
        assert ros.spin_until(lambda: int(parse_values(_latest_status(diagnostics))["rejected rate_limit"]) > 0,
                              120.0)
        assert counters.accepted["rae"] - before == 50  # the cap, exactly, within the held second
    finally:
        stop.set()
        thread.join(30.0)
        est.engine.monotonic = lambda: time.monotonic() + 20.0  # time goes on: a new window
    send(rae, _rae(stamp[7], y[7]))
    assert ros.spin_until(lambda: stamp[7] in stamps_seen(), 20.0)

    # ~/reset, then set_pose re-initialises at the pose
    client = node.create_client(Trigger, "/gpf_estimator/reset")
    assert client.wait_for_service(timeout_sec=20.0)
    future = client.call_async(Trigger.Request())
    assert ros.spin_until(future.done, 20.0) and future.result().success
    good_pose = PoseWithCovarianceStamped()
    good_pose.header.stamp = conv.ns_to_stamp(stamp[9])
    good_pose.header.frame_id = "moon_inertial"
    p = good_pose.pose.pose.position
    p.x, p.y, p.z = (float(v) for v in scenario.truth[10, :3])
    good_pose.pose.covariance = (np.eye(6) * 100.0).reshape(-1).tolist()
    send(pose, good_pose)
    assert ros.spin_until(lambda: stamp[9] in stamps_seen(), 20.0)
    at_pose = [m for m in odom if conv.stamp_to_ns(m.header.stamp) == stamp[9]][-1]
    assert np.linalg.norm(conv.odometry_state(at_pose)[:3] - scenario.truth[10, :3]) < 200.0
    assert est.engine.init_source == "set_pose"

    ros.spin_for(0.5)
    assert all(_finite_odometry(m) for m in odom)
    assert all(math.isfinite(m.data) for m in ess)
    assert all(math.isfinite(v) for m in costate for v in (m.vector.x, m.vector.y, m.vector.z))
    assert all(math.isfinite(q.position.x) for m in particles for q in m.poses)
    _assert_diagnostics_finite(diagnostics)


# --- parameters ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("name, value, text", [
    ("filter", "bogus", "'filter' = 'bogus' is not a known filter; choose one of gpf, gpf-mm, gpf-ladder, spf, ekf, ukf, enkf, gpf-single"),
    ("n_particles", -5, "'n_particles' = -5 must be an integer >= 1"),
    ("ess_threshold", 1.5, "'ess_threshold' (tau) = 1.5 must lie in (0, 1]"),
    ("ess_threshold", 0.0, "'ess_threshold' (tau) = 0.0 must lie in (0, 1]"),
    ("initial_state", [1.0, 2.0], "'initial_state'"),
    ("publish_rate", -1.0, "'publish_rate'"),
])
def test_invalid_parameters_are_refused_at_start_up(ros, name, value, text):
    with pytest.raises(ParameterError) as err:
        EstimatorNode(context=ros.context, parameter_overrides=[Parameter(name, value=value)])
    assert text in str(err.value)


def test_simulator_refuses_rate_factor_without_clock(ros):
    with pytest.raises(ParameterError, match="publish_clock"):
        SimulatorNode(context=ros.context, parameter_overrides=[
            Parameter("publish_clock", value=False), Parameter("rate_factor", value=5.0)])


def test_simulator_loops_with_increasing_stamps(ros):
    rae = ros.record(Vector3Stamped, "measurements/rae")
    sim = ros.add(SimulatorNode(context=ros.context, parameter_overrides=[
        Parameter("rate_factor", value=40.0), Parameter("scenario.duration", value=20.0),
        Parameter("loop", value=True), Parameter("start_delay", value=0.5), Parameter("seed", value=5)]))
    assert ros.spin_until(lambda: len(rae) >= 25, 30.0)
    assert not sim.finished
    stamps = [conv.stamp_to_ns(m.header.stamp) for m in rae]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    first, second = rae[0].vector, rae[10].vector  # the same trajectory point, one lap later
    assert (first.x, first.y, first.z) == (second.x, second.y, second.z)


def test_same_seed_same_messages_on_the_wire(ros):
    runs = []
    for _ in range(2):
        rae = ros.record(Vector3Stamped, "measurements/rae")
        imu = ros.record(Imu, "imu")
        truth = ros.record(Odometry, "truth/odometry")
        sim = ros.add(SimulatorNode(context=ros.context, parameter_overrides=[
            Parameter("rate_factor", value=40.0), Parameter("scenario.duration", value=20.0),
            Parameter("start_delay", value=0.5), Parameter("seed", value=9), Parameter("start_time", value=500.0),
            Parameter("scenario.case", value="partial")]))
        assert ros.spin_until(lambda: sim.finished, 120.0)
        assert ros.spin_until(lambda: (len(rae), len(imu), len(truth)) == tuple(
            sim.published[k] for k in ("measurement", "imu", "truth")), 120.0)  # all of them, however slow
        runs.append((
            [(conv.stamp_to_ns(m.header.stamp), repr((m.vector.x, m.vector.y, m.vector.z))) for m in rae],
            [(conv.stamp_to_ns(m.header.stamp), m.linear_acceleration.x, m.linear_acceleration.z) for m in imu],
            [(conv.stamp_to_ns(m.header.stamp), *conv.odometry_state(m)) for m in truth]))
        ros.executor.remove_node(sim)
        sim.destroy_node()
        ros.nodes.remove(sim)
    assert len(runs[0][0]) == 10 and len(runs[0][1]) == 201 and len(runs[0][2]) == 201
    assert runs[0] == runs[1]


class _TurnsNaN:
    """A filter proxy whose mean becomes NaN after its second update."""

    def __init__(self, inner):
        self.inner, self.updates = inner, 0

    def __getattr__(self, name):
        if name == "inner":  # not set yet (copy.deepcopy builds the copy without __init__)
            raise AttributeError(name)
        return getattr(self.inner, name)

    def update(self, y):
        self.updates += 1
        self.inner.update(y)

    @property
    def mean(self):
        return self.inner.mean * (np.nan if self.updates >= 2 else 1.0)

    @property
    def covariance(self):
        return self.inner.covariance


def test_non_finite_filter_output_is_recovered_and_reported_as_error(ros):
    scenario = generate(ScenarioConfig(duration=60.0), 12)
    base = ros.node.get_clock().now().nanoseconds - 100 * S
    stamp = [base + int(round(t * S)) for t in scenario.times]
    odom = ros.record(Odometry, "odometry/filtered")
    diagnostics = ros.record(DiagnosticArray, "/diagnostics")
    est = ros.add(EstimatorNode(context=ros.context, parameter_overrides=[
        Parameter("n_particles", value=100), Parameter("publish_rate", value=0.0),
        Parameter("initial_state", value=[float(v) for v in scenario.prior_mean]),
        Parameter("initial_stamp", value=base * 1e-9), Parameter("diagnostics_period", value=0.25)]))
    est.engine.filter = _TurnsNaN(est.engine.filter)
    rae = ros.node.create_publisher(Vector3Stamped, "measurements/rae", 100)
    assert ros.spin_until(lambda: rae.get_subscription_count() > 0, 30.0)
    for k in range(4):
        rae.publish(_rae(stamp[k], scenario.measurements[k]))
        ros.spin_for(0.1)

    def error_reported():
        status = _latest_status(diagnostics)
        return status is not None and status.level == b"\x02"

    assert ros.spin_until(error_reported, 20.0)
    status = _latest_status(diagnostics)
    assert "filter re-initialised" in status.message
    values = parse_values(status)
    assert values["reinitializations"] == "1" and values["rejected filter_error"] == "1"
    assert ros.spin_until(lambda: {stamp[2], stamp[3]} & {conv.stamp_to_ns(m.header.stamp) for m in odom}, 20.0)
    assert all(_finite_odometry(m) for m in odom)
    _assert_diagnostics_finite(diagnostics)
