"""rosbag2: ``gpf-nav record`` and ``gpf-nav replay`` on real bags, read back by independent readers.

* record -> a bag whose messages are exactly the simulator's (events, stamps, frames, the prior handed
  over on ``set_state``), whose metadata
  a ROS 2 Jazzy ``ros2 bag play`` accepts (version 9, cdr, QoS, type hashes equal to the installed
  message packages');
* record -> replay round trip, MCAP (output read by ``mcap-ros2-support``) and sqlite3 (output read and
  decoded by ``rosbags``' own CDR decoder);
* a bag written by ``rosbags`` alone, on a remapped topic, with garbage of every kind: counted by
  reason exactly as the node counts them, never a NaN out;
* the same messages through a real ``EstimatorNode`` over DDS: the same estimates and counters;
* truncated bags and other unusable input: one line on stderr, exit status 2, no traceback.
"""
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from domains import fresh_domain

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from geometry_msgs.msg import PoseWithCovarianceStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402

from gpf_nav.ros import conversions as conv  # noqa: E402
from gpf_nav.bags.bag import BagReader, deserialize  # noqa: E402
from gpf_nav.estimator.params import ESTIMATOR, ParameterError, parameters_from_files  # noqa: E402
from gpf_nav.sim.simulator_params import simulator_specs  # noqa: E402
from gpf_nav.sim.playback import build_events  # noqa: E402
from gpf_nav.bags.record import record  # noqa: E402
from gpf_nav.bags.replay import REPLAY_PARAMETERS, replay  # noqa: E402
from gpf_nav.ros.simulator_node import (EVENT_TOPICS, event_message, handover_message,  # noqa: E402
                                        scenario_from_parameters)

S = 1_000_000_000
ROOT = Path(__file__).resolve().parents[1]
SIM_SECONDS = 150.0  # simulated seconds of the recorded scenario
START_TIME = 1000.0  # ROS time of the recorded trajectory's start [s] (the default, -1, is the wall clock)


def _sim_params(**overrides):
    assignments = [f"scenario.duration:={SIM_SECONDS}", f"start_time:={START_TIME}"] + \
        [f"{k}:={v}" for k, v in overrides.items()]
    return parameters_from_files(simulator_specs(), "lunar_simulator", [ROOT / "config/simulator.yaml"], assignments)


def _est_params(*assignments):
    return parameters_from_files(REPLAY_PARAMETERS, "gpf_estimator", [ROOT / "config/estimator.yaml"], assignments)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A recorded scenario bag (MCAP) and the simulator parameters it was made with."""
    p = _sim_params()
    path = tmp_path_factory.mktemp("rec") / "scenario"
    counts = record(str(path), p, "mcap")
    return path, p, counts


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "gpf_nav.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)


def _mcap_messages(bag_dir: Path):
    """``(topic, schema name, log time, decoded message)`` of an MCAP bag, by mcap-ros2-support."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    (path,) = bag_dir.glob("*.mcap")
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(ch.topic, schema.name, m.log_time, msg)
                for schema, ch, m, msg in reader.iter_decoded_messages(log_time_order=True)]


def _odometry_values(msg):
    p, v = msg.pose.pose.position, msg.twist.twist.linear
    return [p.x, p.y, p.z, v.x, v.y, v.z, *msg.pose.covariance, *msg.twist.covariance]


# --- record --------------------------------------------------------------------------------------------
def test_record_writes_the_simulators_messages_with_metadata_ros2_bag_play_accepts(recorded):
    import yaml
    path, p, counts = recorded
    meta = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert set(topics) == {"/measurements/rae", "/imu", "/truth/odometry", "/clock", "/set_state"}
    for name, t in topics.items():
        md = t["topic_metadata"]
        assert md["serialization_format"] == "cdr"
        (qos,) = md["offered_qos_profiles"]
        assert (qos["reliability"], qos["durability"], qos["history"], qos["depth"]) == \
            (("reliable", "transient_local", "keep_last", 1) if name == "/set_state" else
             ("reliable", "volatile", "keep_last", 1000))
        assert t["message_count"] == counts[name] > 0
        # the type hash ros2 bag play checks against the installed message package's own description
        package, _, type_ = md["type"].split("/")
        description = Path(sys.prefix, "share", package, "msg", f"{type_}.json")
        if description.exists():
            assert md["type_description_hash"] in description.read_text()

    # the messages are the simulator node's: same events, stamps (start_time + t), frames and values
    _, scenario = scenario_from_parameters(p)
    events = build_events(scenario, p["imu_rate"], p["imu_noise_std"], p["truth_rate"], p["seed"])
    epoch = int(p["start_time"] * S)
    expected = {}
    for e in events:
        topic, msg = event_message(e, epoch + e.t_ns, p)
        expected.setdefault("/" + topic, []).append((epoch + e.t_ns, msg))
    types = {"/" + topic: msg_type for topic, msg_type in EVENT_TOPICS.values() if "/" + topic in expected}
    got = {topic: [] for topic in types}
    with BagReader(path) as reader:
        assert reader.start_ns == epoch and reader.end_ns == epoch + int(SIM_SECONDS * S)
        for topic, t_ns, raw in reader.messages(types):
            got[topic].append((t_ns, deserialize(raw, types[topic])))
        clock = [deserialize(raw, __import__("rosgraph_msgs.msg", fromlist=["Clock"]).Clock)
                 for _, _, raw in reader.messages(["/clock"])]
        handover = [(t_ns, deserialize(raw, Odometry)) for _, t_ns, raw in reader.messages(["/set_state"])]
    # the prior, handed over once at the trajectory start as the simulator does
    assert handover == [(epoch, handover_message(scenario, epoch, p))]
    np.testing.assert_array_equal(conv.odometry_state(handover[0][1]), scenario.prior_mean)
    for topic in types:
        assert len(got[topic]) == len(expected[topic])
        for (t_got, m_got), (t_exp, m_exp) in zip(got[topic], expected[topic]):
            assert t_got == t_exp == conv.stamp_to_ns(m_got.header.stamp)
            assert m_got == m_exp
    measured = np.array([conv.rae_values(m) for _, m in got["/measurements/rae"]])
    np.testing.assert_array_equal(measured, scenario.measurements[np.any(np.isfinite(scenario.measurements), 1)])
    ticks = [conv.stamp_to_ns(c.clock) for c in clock]
    assert ticks == list(range(epoch, epoch + int(SIM_SECONDS * S) + 1, int(S / p["clock_rate"])))


def test_record_refuses_an_existing_bag_and_bad_parameters(tmp_path, recorded):
    r = _cli("record", recorded[0], "--duration", 10)
    assert r.returncode == 2 and "exists already" in r.stderr and "Traceback" not in r.stderr
    r = _cli("record", tmp_path / "x", "-p", "imu_rate:=-1")
    assert r.returncode == 2 and "imu_rate" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_record_starts_at_the_wall_clock_time_by_default(tmp_path):
    """start_time -1 (the default, as for the simulator): the trajectory starts at the wall-clock time of
    the recording; the prior is handed over then."""
    p = _sim_params(start_time=-1.0, **{"scenario.duration": 10.0})
    before = time.time_ns()
    record(str(tmp_path / "now"), p, "mcap")
    after = time.time_ns()
    with BagReader(tmp_path / "now") as reader:
        assert before <= reader.start_ns <= after
        ((_, t_ns, raw),) = list(reader.messages(["/set_state"]))
    assert t_ns == reader.start_ns == conv.stamp_to_ns(deserialize(raw, Odometry).header.stamp)


def test_record_without_clock_stamps_by_the_wall_clock_like_the_simulator(tmp_path):
    """publish_clock false: no /clock in the bag, and start_time is ignored (the simulator's stamps then
    follow the wall clock); every other topic is there."""
    p = _sim_params(publish_clock=False, start_time=1000.0, **{"scenario.duration": 10.0})
    before = time.time_ns()
    counts = record(str(tmp_path / "wall"), p, "mcap")
    after = time.time_ns()
    assert "/clock" not in counts and counts["/measurements/rae"] == 5 and counts["/set_state"] == 1
    with BagReader(tmp_path / "wall") as reader:
        assert before <= reader.start_ns <= after
        assert not list(reader.messages(["/clock"]))


def test_record_and_replay_carry_the_sensor_suite(tmp_path):
    p = _sim_params(publish_suite="true", **{"suite.trn_outlier_probability": 0.0,
                                            "suite.altimeter_max_altitude": 1e6,
                                            "suite.velocimeter_max_altitude": 1e6})
    counts = record(str(tmp_path / "suite"), p, "mcap")
    for topic in ("/measurements/altitude", "/measurements/velocity", "/measurements/position"):
        assert counts[topic] > 5, counts
    types = {"/measurements/position": PoseWithCovarianceStamped}
    with BagReader(tmp_path / "suite") as reader:
        fixes = [(t_ns, deserialize(raw, PoseWithCovarianceStamped)) for _, t_ns, raw in reader.messages(types)]
    latency = int(p["suite.trn_latency"] * S)
    assert all(t_ns - conv.stamp_to_ns(m.header.stamp) == latency for t_ns, m in fixes)  # stamped at capture
    r = _cli("replay", tmp_path / "suite", "--out", tmp_path / "out", "--params-file",
             ROOT / "config/estimator.yaml", "-p", "n_particles:=200", "--no-progress", "--no-figure")
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "out/summary.json").read_text())
    for topic in ("/measurements/altitude", "/measurements/velocity", "/measurements/position"):
        assert summary["inputs"][topic]["accepted"] == counts[topic], summary["inputs"][topic]
    assert summary["rejected_by_reason"] == {}
    assert 0 < summary["position_rmse_second_half_m"] < summary["position_rmse_m"]


# --- replay --------------------------------------------------------------------------------------------
def test_round_trip_record_replay_mcap_read_back_by_mcap_ros2_support(recorded, tmp_path):
    path, p, counts = recorded
    r = _cli("replay", path, "--out", tmp_path / "out", "--params-file", ROOT / "config/estimator.yaml",
             "-p", "n_particles:=200", "--no-progress")
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "out/summary.json").read_text())
    n_meas = counts["/measurements/rae"]
    assert summary["particles"] == 200
    assert summary["inputs"]["/measurements/rae"] == {"read": n_meas, "undecodable": 0, "accepted": n_meas,
                                                      "rejected": {}}
    assert summary["inputs"]["/imu"]["accepted"] == counts["/imu"]
    assert summary["inputs"]["/set_state"] == {"read": 1, "undecodable": 0, "accepted": 1, "rejected": {}}
    assert summary["rejected_by_reason"] == {}
    assert summary["initialized_from"] == "set_state"
    assert summary["updates"] == n_meas  # initialised from the prior handed over: every measurement updates
    assert summary["truth"]["compared_updates"] == summary["updates"]
    for key in ("position_rmse_m", "velocity_rmse_mps", "mean_nees"):
        assert math.isfinite(summary[key]) and summary[key] > 0
    assert summary["bag_seconds"] == pytest.approx(SIM_SECONDS)
    assert summary["real_time_factor"] > 0
    assert "real time" in r.stdout and "position RMSE" in r.stdout
    assert (tmp_path / "out/errors.png").stat().st_size > 10_000

    messages = _mcap_messages(tmp_path / "out/estimates")
    by_topic = {}
    for topic, schema, log_time, msg in messages:
        by_topic.setdefault(topic, []).append((schema, log_time, msg))
    assert {t: len(v) for t, v in by_topic.items()} == summary["outputs"]["messages"]
    assert {t: v[0][0] for t, v in by_topic.items()} == {
        "/odometry/filtered": "nav_msgs/msg/Odometry", "/gpf/ess": "std_msgs/msg/Float64",
        "/gpf/costate": "geometry_msgs/msg/Vector3Stamped", "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
        "/gpf/unmodelled_acceleration": "geometry_msgs/msg/Vector3Stamped"}
    odom = by_topic["/odometry/filtered"]
    stamps = [m.header.stamp.sec * S + m.header.stamp.nanosec for _, _, m in odom]
    assert all(m.header.frame_id == "moon_inertial" and m.child_frame_id == "base_link" for _, _, m in odom)
    assert all(math.isfinite(v) for _, _, m in odom for v in _odometry_values(m))
    assert all(log_time >= stamp for (_, log_time, _), stamp in zip(odom, stamps))  # published after the data
    # updates at every measurement stamp after initialisation, predictions at publish_rate in between
    updates = sorted(set(stamps) & {int(p["start_time"] * S) + int(k * 2 * S) for k in range(1, 200)})
    assert len(updates) == summary["updates"]
    assert len(odom) > 5 * summary["updates"]
    assert len(by_topic["/gpf/ess"]) == len(by_topic["/gpf/costate"]) == summary["updates"]
    assert len(by_topic["/gpf/unmodelled_acceleration"]) == summary["updates"]
    last = by_topic["/diagnostics"][-1][2].status[0]
    values = {kv.key: kv.value for kv in last.values}
    assert values["measurements accepted"] == str(n_meas) and values["messages rejected"] == "0"


def test_round_trip_sqlite3_read_back_by_rosbags(tmp_path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore
    bag = tmp_path / "scenario"
    assert _cli("record", bag, "--duration", 60, "--case", "partial", "--seed", 3, "--storage", "sqlite3",
                "-p", "imu_rate:=2.0", "-p", "hand_over_prior:=false").returncode == 0
    assert list(bag.glob("*.db3"))
    with BagReader(bag) as reader:
        assert "/set_state" not in reader.topics and reader.counts["/clock"] > 0
    # the partial case never measures azimuth: no batch initialisation, the prior as initial_state
    from gpf_nav.sim.scenario import ScenarioConfig, generate
    prior = generate(ScenarioConfig(duration=60.0, case="partial"), 3)
    out = tmp_path / "out"
    r = _cli("replay", bag, "--out", out, "--storage", "sqlite3", "--no-progress", "--no-figure", "-p", "filter:=ekf",
             "-p", f"initial_state:={[float(v) for v in prior.prior_mean]}",
             "-p", f"initial_std:={[float(v) for v in np.sqrt(np.diag(prior.prior_cov))]}")
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["filter"] == "ekf" and summary["masked_components"] == 30
    assert summary["updates"] == 30 and summary["initialized_from"] == "parameters"
    typestore = get_typestore(Stores.ROS2_JAZZY)
    seen = {}
    with Reader(out / "estimates") as reader:
        assert list((out / "estimates").glob("*.db3"))
        for connection, t_ns, raw in reader.messages():
            msg = typestore.deserialize_cdr(raw, connection.msgtype)  # rosbags' own CDR decoder
            seen[connection.topic] = seen.get(connection.topic, 0) + 1
            if connection.topic == "/odometry/filtered":
                assert np.all(np.isfinite(msg.pose.covariance)) and math.isfinite(msg.pose.pose.position.x)
    assert seen == {topic: n for topic, n in summary["outputs"]["messages"].items() if n}
    assert summary["outputs"]["messages"]["/gpf/ess"] == 0  # the EKF has no ESS, as in the node


# --- garbage -------------------------------------------------------------------------------------------
def _garbage_bag(path: Path, topic: str):
    """A bag written by rosbags alone: 40 s of scenario measurements on ``topic`` plus IMU, with garbage,
    and a ``set_state`` (the truth at 20 s) once the filter has initialised from the measurements.

    Returns (expected rejections by reason, expected masked components, undecodable messages)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    from gpf_nav.sim.scenario import ScenarioConfig, generate
    ts = get_typestore(Stores.ROS2_JAZZY)
    T, H = ts.types["builtin_interfaces/msg/Time"], ts.types["std_msgs/msg/Header"]
    V3, VS = ts.types["geometry_msgs/msg/Vector3"], ts.types["geometry_msgs/msg/Vector3Stamped"]
    Q, Imu = ts.types["geometry_msgs/msg/Quaternion"], ts.types["sensor_msgs/msg/Imu"]
    scenario = generate(ScenarioConfig(duration=40.0), 5)
    start = 1000 * S
    Od = ts.types["nav_msgs/msg/Odometry"]
    Pose, Point, Twist = (ts.types[f"geometry_msgs/msg/{t}"] for t in ("Pose", "Point", "Twist"))
    PWC, TWC = (ts.types[f"geometry_msgs/msg/{t}WithCovariance"] for t in ("Pose", "Twist"))

    def rae(stamp_ns, values, frame="station", nanosec=None):
        stamp = T(sec=stamp_ns // S, nanosec=stamp_ns % S if nanosec is None else nanosec)
        return ts.serialize_cdr(VS(header=H(stamp=stamp, frame_id=frame), vector=V3(*map(float, values))), VS.__msgtype__)

    def imu(stamp_ns, accel, frame="base_link"):
        cov = np.zeros(9)
        cov[[0, 4, 8]] = 1e-8
        msg = Imu(header=H(stamp=T(sec=stamp_ns // S, nanosec=stamp_ns % S), frame_id=frame),
                  orientation=Q(0.0, 0.0, 0.0, 1.0), orientation_covariance=np.zeros(9),
                  angular_velocity=V3(0.0, 0.0, 0.0), angular_velocity_covariance=np.r_[-1.0, np.zeros(8)],
                  linear_acceleration=V3(*map(float, accel)), linear_acceleration_covariance=cov)
        return ts.serialize_cdr(msg, Imu.__msgtype__)

    def set_state(stamp_ns, state, cov, frame="moon_inertial"):
        pose_cov, twist_cov = np.zeros((6, 6)), np.zeros((6, 6))
        pose_cov[:3, :3], twist_cov[:3, :3] = cov[:3, :3], cov[3:, 3:]
        msg = Od(header=H(stamp=T(sec=stamp_ns // S, nanosec=stamp_ns % S), frame_id=frame),
                 child_frame_id="base_link",
                 pose=PWC(pose=Pose(position=Point(*map(float, state[:3])), orientation=Q(0.0, 0.0, 0.0, 1.0)),
                          covariance=pose_cov.reshape(-1)),
                 twist=TWC(twist=Twist(linear=V3(*map(float, state[3:])), angular=V3(0.0, 0.0, 0.0)),
                           covariance=twist_cov.reshape(-1)))
        return ts.serialize_cdr(msg, Od.__msgtype__)

    records = []  # (recording time, topic, bytes)
    for t, y in zip(scenario.times, scenario.measurements):
        records.append((start + int(t * S), topic, rae(start + int(t * S), y)))
        records.append((start + int(t * S) - S // 2, "/imu", imu(start + int(t * S) - S // 2, (0.0, 0.0, 0.0))))
    y0 = scenario.measurements[0]
    at = start + 21 * S  # recording time of the garbage: after the filter initialised (10 x 2 s)
    records += [
        (at, "/set_state", set_state(start + 20 * S, scenario.truth[10], scenario.prior_cov)),  # truth at 20 s
        (at, "/set_state", set_state(start + 20 * S, scenario.truth[10], scenario.prior_cov, frame="map")),
        (at, topic, rae(at, (-5.0, y0[1], y0[2]))),                          # non_positive_range
        (at, topic, rae(at, (math.nan, math.nan, math.nan))),                # no_measured_component
        (at, topic, rae(at, (math.inf, y0[1], y0[2]))),                      # non_finite
        (at, topic, rae(at, y0, frame="map")),                               # wrong_frame
        (at, topic, rae(start + 5 * S, y0)),                                 # older_than_history (> 10 s)
        (at, topic, rae(at, y0, nanosec=2_000_000_000)),                     # bad_stamp
        (at, topic, rae(at + 100 * S, y0)),                                  # future_stamp (max_future 1 s)
        (at, topic, b"\x00\x01\x00\x00\x07"),                                # does not deserialise
        (at, topic, rae(at, (y0[0] + 300.0, math.nan, y0[2]))),              # valid, azimuth masked
        (at, "/imu", imu(at, (math.nan, 0.0, 0.0))),                         # non_finite
        (at, "/imu", imu(at, (0.0, 0.0, 0.0), frame="imu_link")),            # wrong_frame
    ]
    records.sort(key=lambda r: r[0])
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        conns = {topic: writer.add_connection(topic, VS.__msgtype__, typestore=ts),
                 "/imu": writer.add_connection("/imu", Imu.__msgtype__, typestore=ts),
                 "/set_state": writer.add_connection("/set_state", Od.__msgtype__, typestore=ts)}
        for t_ns, name, data in records:
            writer.write(conns[name], t_ns, data)
    expected = {"non_positive_range": 1, "no_measured_component": 1, "non_finite": 2, "wrong_frame": 3,
                "older_than_history": 1, "bad_stamp": 1, "future_stamp": 1}
    return expected, 1, 1, len(scenario.times)


def test_garbage_is_counted_by_reason_like_the_node_and_never_output_as_nan(tmp_path):
    bag = tmp_path / "garbage"
    expected, masked, undecodable, n_valid = _garbage_bag(bag, "/tracking/rae")
    r = _cli("replay", bag, "--out", tmp_path / "out", "--remap", "measurements/rae:=/tracking/rae",
             "--no-progress")
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "out/summary.json").read_text())
    assert summary["rejected_by_reason"] == expected
    assert summary["undecodable"] == undecodable
    assert summary["masked_components"] == masked
    assert summary["inputs"]["/tracking/rae"]["accepted"] == n_valid + 1
    assert summary["inputs"]["/set_state"]["accepted"] == 1 and summary["initialized_from"] == "set_state"
    assert summary["truth"]["messages"] == 0 and "position_rmse_m" not in summary
    assert not (tmp_path / "out/errors.png").exists()
    assert "dropped rae message: non_positive_range" in r.stderr  # the node's log line
    messages = _mcap_messages(tmp_path / "out/estimates")
    odom = [m for topic, _, _, m in messages if topic == "/odometry/filtered"]
    assert len(odom) > n_valid
    assert all(math.isfinite(v) for m in odom for v in _odometry_values(m))
    assert all(math.isfinite(m.data) for topic, _, _, m in messages if topic == "/gpf/ess")
    assert all(math.isfinite(c) for topic, _, _, m in messages
               if topic in ("/gpf/costate", "/gpf/unmodelled_acceleration") for c in (m.vector.x, m.vector.y, m.vector.z))
    last = {kv.key: kv.value for kv in [m for t, _, _, m in messages if t == "/diagnostics"][-1].status[0].values}
    for reason, n in expected.items():
        assert last[f"rejected {reason}"] == str(n)
    for value in last.values():
        assert value.lower() != "nan"


def test_replay_gives_the_nodes_estimates_and_counters(tmp_path):
    """The garbage bag's messages published to a real EstimatorNode (use_sim_time) over DDS, one at a time
    after a /clock at the message's recording time (set_state by a latched publisher, as the simulator's):
    the node's odometry (at every update and at the set_state) and its counters equal the replay's."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from geometry_msgs.msg import Vector3Stamped
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu
    from gpf_nav.ros.estimator_node import EstimatorNode
    bag = tmp_path / "garbage"
    expected, _, _, _ = _garbage_bag(bag, "/measurements/rae")
    params = ["publish_rate:=0.0", "n_particles:=100"]
    summary, _ = replay(str(bag), str(tmp_path / "out"), _est_params(*params), progress=False)
    replayed = [(conv.stamp_to_ns(m.header.stamp), _odometry_values(m))
                for topic, _, _, m in _mcap_messages(tmp_path / "out/estimates") if topic == "/odometry/filtered"]
    assert len(replayed) == summary["updates"] + 1  # publish_rate 0: the updates and the set_state's

    context = rclpy.Context()
    rclpy.init(args=[], context=context, domain_id=fresh_domain())
    executor = SingleThreadedExecutor(context=context)
    overrides = [Parameter(k, value=v) for k, v in (("publish_rate", 0.0), ("n_particles", 100),
                                                     ("use_sim_time", True))]
    est = EstimatorNode(context=context, parameter_overrides=overrides)
    probe = rclpy.create_node("gpf_bag_probe", context=context)
    odom = []
    probe.create_subscription(Odometry, "odometry/filtered", odom.append, 1000)
    pubs = {"/measurements/rae": (probe.create_publisher(Vector3Stamped, "measurements/rae", 10), Vector3Stamped),
            "/imu": (probe.create_publisher(Imu, "imu", 10), Imu),
            "/set_state": (probe.create_publisher(Odometry, "set_state", QoSProfile(
                depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)), Odometry)}
    clock_pub = probe.create_publisher(Clock, "/clock", 10)
    for node in (est, probe):
        executor.add_node(node)
    try:
        c = est.engine.counters

        def spin_until(condition, timeout=30.0):
            deadline = time.monotonic() + timeout
            while not condition() and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.02)
            return condition()

        assert spin_until(lambda: all(p.get_subscription_count() for p, _ in pubs.values()))
        with BagReader(bag) as reader:
            for topic, t_ns, raw in reader.messages(pubs):
                clock_pub.publish(Clock(clock=conv.ns_to_stamp(t_ns)))
                assert spin_until(lambda: est.get_clock().now().nanoseconds == t_ns)
                pub, msg_type = pubs[topic]
                try:
                    msg = deserialize(raw, msg_type)
                except Exception:  # noqa: BLE001 - the undecodable record never reaches a node
                    continue
                before = c.total_accepted + c.total_rejected
                pub.publish(msg)
                assert spin_until(lambda: c.total_accepted + c.total_rejected > before)
        assert spin_until(lambda: len(odom) >= len(replayed))
        node_rejected = {r: n for r, n in c.rejected.items() if n}
    finally:
        executor.shutdown()
        est.destroy_node()
        probe.destroy_node()
        rclpy.try_shutdown(context=context)
    assert node_rejected == summary["rejected_by_reason"] == expected
    node = [(conv.stamp_to_ns(m.header.stamp), _odometry_values(m)) for m in odom]
    assert [stamp for stamp, _ in node] == [stamp for stamp, _ in replayed]
    for (_, values), (_, expected_values) in zip(node, replayed):
        np.testing.assert_allclose(values, expected_values, rtol=1e-12, atol=0)


# --- unusable input ------------------------------------------------------------------------------------
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_truncated_bag_is_refused_in_one_line_with_status_2(tmp_path, storage):
    bag = tmp_path / "cut"
    assert _cli("record", bag, "--duration", 60, "--storage", storage).returncode == 0
    (data,) = [f for f in bag.iterdir() if f.suffix in (".mcap", ".db3")]
    with open(data, "r+b") as f:
        f.truncate(data.stat().st_size // 2)
    r = _cli("replay", bag, "--out", tmp_path / "out", "--no-progress")
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith("gpf-nav replay: error: cannot") and str(bag) in r.stderr
    assert not (tmp_path / "out" / "estimates").exists()


def test_unusable_input_is_refused_in_one_line_with_status_2(tmp_path, recorded):
    path = recorded[0]
    cases = [
        (["--remap", "truth/odometry:=/measurements/rae"], "has type geometry_msgs/msg/Vector3Stamped"),
        (["--remap", "measurements/rae:=/nothing"], "no measurements"),
        (["-p", "n_particles:=0"], "n_particles"),
        (["-p", "n_particle:=10"], "unknown parameter"),
        (["--params-file", ROOT / "config/simulator.yaml"], "no section for gpf_estimator"),
    ]
    for extra, text in cases:
        r = _cli("replay", path, "--out", tmp_path / "out", "--no-progress", *extra)
        assert r.returncode == 2 and text in r.stderr, (extra, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    r = _cli("replay", tmp_path / "no_such_bag", "--out", tmp_path / "out")
    assert r.returncode == 2 and "no such bag" in r.stderr


def test_simulator_disturbance_parameter_is_the_scenarios():
    """``scenario.disturbance`` reaches the simulator's truth as the scenario's hidden acceleration: the
    same truth as ``generate`` with it, and a different one from the undisturbed run."""
    from gpf_nav.sim.scenario import ScenarioConfig, generate

    push = [0.0, 0.06, -0.08]
    config, scenario = scenario_from_parameters(_sim_params(**{"scenario.disturbance": push}))
    assert config.disturbance == tuple(push)
    expected = generate(ScenarioConfig(duration=SIM_SECONDS, disturbance=tuple(push)), 0)
    np.testing.assert_array_equal(scenario.truth, expected.truth)
    np.testing.assert_array_equal(scenario.specific_force, expected.specific_force)  # the IMU does not sense it
    undisturbed = scenario_from_parameters(_sim_params())[1]
    drift = np.linalg.norm(scenario.truth[-1, :3] - undisturbed.truth[-1, :3])
    assert drift > 0.5 * 0.1 * SIM_SECONDS ** 2 * 0.5  # about a t^2 / 2 of 0.1 m/s^2


def test_parameters_from_files_like_the_node(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("/**:\n  ros__parameters:\n    n_particles: 50\n    use_sim_time: true\n"
                 "gpf_estimator:\n  ros__parameters:\n    filter: ukf\n    publish_rate: 5\n")
    p = parameters_from_files(ESTIMATOR, "gpf_estimator", [f], ["filter:=enkf", "initial_state:=[1, 2, 3, 4, 5, 6]"])
    assert (p["n_particles"], p["filter"], p["publish_rate"]) == (50, "enkf", 5.0)
    assert p["initial_state"] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0] and p["seed"] == 0
    with pytest.raises(ParameterError, match="'n_particles'"):
        parameters_from_files(ESTIMATOR, "gpf_estimator", [], ["n_particles:=1.5"])
    with pytest.raises(ParameterError, match="name:=value"):
        parameters_from_files(ESTIMATOR, "gpf_estimator", [], ["n_particles=5"])


def test_use_sim_time_takes_the_node_clock_from_the_bags_clock(tmp_path, recorded):
    """A bag recorded on the wall clock (recording times ~1.7e9 s, stamps and /clock at 1000 s, as
    ``ros2 bag record`` of the simulator writes it): with use_sim_time the predictions follow /clock; on
    recording time they cannot (the data are 1.7e9 s old for that clock), as for a node without sim time.
    The updates are the same either way: header stamps drive the filter."""
    from gpf_nav.bags.bag import BagWriter, qos_profile
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu
    from geometry_msgs.msg import Vector3Stamped
    src, p, _ = recorded
    shifted = tmp_path / "wall"
    types = {"/measurements/rae": Vector3Stamped, "/imu": Imu, "/truth/odometry": Odometry, "/clock": Clock}
    offset = 1_700_000_000 * S
    end = int(p["start_time"] * S) + 60 * S
    with BagReader(src) as reader, BagWriter(shifted, "mcap", {t: (m, qos_profile(True, 50))
                                                              for t, m in types.items()}) as writer:
        for topic, t_ns, raw in reader.messages(types):
            if t_ns <= end:
                writer.write(topic, deserialize(raw, types[topic]), t_ns + offset)
    results = {}
    for sim in (False, True):
        summary, _ = replay(str(shifted), str(tmp_path / f"out{sim}"),
                            _est_params("n_particles:=100", f"use_sim_time:={str(sim).lower()}"),
                            progress=False)
        odom = [(log, conv.stamp_to_ns(m.header.stamp), _odometry_values(m))
                for topic, _, log, m in _mcap_messages(tmp_path / f"out{sim}/estimates") if topic == "/odometry/filtered"]
        results[sim] = summary, odom
    (s_wall, odom_wall), (s_sim, odom_sim) = results[False], results[True]
    assert s_wall["updates"] == s_sim["updates"] == 30 - 10 + 1
    assert s_sim["inputs"]["/clock"]["read"] > 0 and "/clock" not in s_wall["inputs"]
    assert len(odom_wall) == s_wall["updates"]  # no predictions: max_extrapolation from 1.7e9 s
    assert "no measurement for" in s_wall["diagnostics_last"]["message"]
    predictions = sorted({stamp for _, stamp, _ in odom_sim} - {stamp for _, stamp, _ in odom_wall})
    assert len(predictions) > 5 * s_sim["updates"]
    assert all((stamp - int(p["start_time"] * S)) % (S // 10) == 0 for stamp in predictions)  # the 10 Hz timer on /clock
    assert all(log >= offset for log, _, _ in odom_sim)  # recorded at recording time
    updates_wall = {stamp: v for _, stamp, v in odom_wall}
    updates_sim = {stamp: v for _, stamp, v in odom_sim if stamp in updates_wall}
    for stamp, values in updates_wall.items():
        np.testing.assert_array_equal(values, updates_sim[stamp])


def test_truth_at_interpolates_only_between_close_samples():
    from gpf_nav.bags.replay_report import truth_at
    truth = {10 * S: np.arange(6.0), 11 * S: np.arange(6.0) + 2.0, 20 * S: np.zeros(6)}
    stamps = np.array([9 * S, 10 * S, 10 * S + S // 4, 11 * S, 15 * S, 20 * S, 21 * S], dtype=np.int64)
    out = truth_at(truth, stamps, S)
    assert np.isnan(out[[0, 4, 6]]).all()
    np.testing.assert_allclose(out[1], np.arange(6.0))
    np.testing.assert_allclose(out[2], np.arange(6.0) + 0.5)
    np.testing.assert_allclose(out[3], np.arange(6.0) + 2.0)
    np.testing.assert_allclose(out[5], np.zeros(6))


def test_header_stamp_read_from_the_cdr_bytes():
    from rclpy.serialization import serialize_message
    from rosbags.typesys import Stores, get_typestore
    from gpf_nav.bags.bag import header_stamp_ns
    stamp = 1234 * S + 567
    odom = conv.odometry_msg(np.arange(6.0), np.eye(6), stamp, "moon_inertial", "base_link")
    assert header_stamp_ns(serialize_message(odom)) == stamp
    ts = get_typestore(Stores.ROS2_JAZZY)
    VS, H, T, V3 = (ts.types[t] for t in ("geometry_msgs/msg/Vector3Stamped", "std_msgs/msg/Header",
                                          "builtin_interfaces/msg/Time", "geometry_msgs/msg/Vector3"))
    msg = VS(header=H(stamp=T(sec=1234, nanosec=567), frame_id="x"), vector=V3(1.0, 2.0, 3.0))
    for little in (True, False):
        assert header_stamp_ns(ts.serialize_cdr(msg, VS.__msgtype__, little_endian=little)) == stamp
    with pytest.raises(ValueError):
        header_stamp_ns(b"\x00\x01\x00\x00")


# --- loud failures -------------------------------------------------------------------------------------
def test_replay_of_a_bag_in_another_measurement_frame_fails_naming_the_frame(tmp_path):
    """Every measurement refused (wrong_frame): exit status 1, the counts by reason and the parameter to set."""
    p = _sim_params(**{"scenario.duration": 60.0, "measurement_frame": "radar"})
    counts = record(str(tmp_path / "radar"), p, "mcap")
    r = _cli("replay", tmp_path / "radar", "--out", tmp_path / "out", "--no-progress", "--no-figure")
    assert r.returncode == 1, (r.returncode, r.stderr)
    n = counts["/measurements/rae"]
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("gpf-nav replay: error: no measurement accepted")
    assert f"wrong_frame {n}" in last and "'radar'" in last and "measurement_frame:=radar" in last, last
    summary = json.loads((tmp_path / "out/summary.json").read_text())
    assert summary["measurements"] == {"read": n, "accepted": 0, "rejected": {"wrong_frame": n},
                                       "frames": {"radar": n}, "measurement_frame": "station"}
    fixed = _cli("replay", tmp_path / "radar", "--out", tmp_path / "fixed", "--no-progress", "--no-figure",
                 "-p", "measurement_frame:=radar")
    assert fixed.returncode == 0, fixed.stderr
    assert json.loads((tmp_path / "fixed/summary.json").read_text())["measurements"]["accepted"] == n


def test_record_without_a_measurement_fails_naming_the_parameters(tmp_path):
    r = _cli("record", tmp_path / "none", "--duration", "30", "-p", "scenario.dropout_probability:=1.0")
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert "no measurement written (/measurements/rae 0)" in r.stderr
    assert "scenario.dropout_probability (= 1.0)" in r.stderr
