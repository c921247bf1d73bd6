"""The estimator as a managed node, driven as a lifecycle manager drives it: the ``estimator`` process
(``python -m gpf_nav.ros.estimator_node``) on a private domain, every transition through the standard
``lifecycle_msgs`` services (``~/change_state``, ``~/get_state``). Also TF on ``/tf`` checked by a real
subscriber, with ``tf2_msgs`` built from its definition (test/interfaces.py), and the one warning that
names an undeclared parameter. Conditions are awaited; "publishes nothing" is judged by the stamps
(the node stamps its predictions with its clock), not by how long we listened.

A prior (``set_state``), a pose or a ``~/reset`` that reaches the node while it is not active is kept and
applied at ``activate``; measurements that arrive then are counted, not processed. With the simulator
already running (its latched prior sent long before) and ``autostart:=false``, odometry flows as soon as
a manager activates the estimator, not after the ``init_window`` measurements (20 s) it waited for before."""
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from domains import fresh_domain

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import Vector3Stamped  # noqa: E402
from lifecycle_msgs.msg import Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

import interfaces  # noqa: E402
from gpf_nav.ros import conversions as conv  # noqa: E402
from gpf_nav.ros.diagnostics import STATUS_NAME, parse_values  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NODE = "/gpf_estimator"
WAIT = 120.0  # s: generous deadline of every awaited condition (a busy 2-core machine)
RESEND = 5.0  # s: an unanswered service request is sent again after this (see Graph.call)
GOAL = {Transition.TRANSITION_CONFIGURE: "inactive", Transition.TRANSITION_ACTIVATE: "active",
        Transition.TRANSITION_DEACTIVATE: "inactive", Transition.TRANSITION_CLEANUP: "unconfigured",
        Transition.TRANSITION_UNCONFIGURED_SHUTDOWN: "finalized"}
"""The state each transition the tests send leads to."""
STATE = [1.8e6, 0.0, 0.0, 0.0, 1.6e3, 0.0]  # a lunar orbit state [m, m/s] handed over on set_state


class Graph:
    """A private domain: a probe node that records topics, hands a state over and calls the lifecycle
    services, and the estimator processes it started."""

    def __init__(self, tmp_path: Path):
        self.tmp_path = tmp_path
        self.domain = fresh_domain()
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                        PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context, domain_id=self.domain)
        self.node = rclpy.create_node("gpf_lifecycle_probe", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.odometry: list = []
        self.diagnostics: list = []
        self.rae: list = []
        self.node.create_subscription(Odometry, "odometry/filtered", self.odometry.append, 1000)
        self.node.create_subscription(Vector3Stamped, "measurements/rae", self.rae.append, qos_profile_sensor_data)
        self._rae = self.node.create_publisher(Vector3Stamped, "measurements/rae", qos_profile_sensor_data)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 100)
        latched = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=1,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._set_state = self.node.create_publisher(Odometry, "set_state", latched)
        self._change = self.node.create_client(ChangeState, f"{NODE}/change_state")
        self._get = self.node.create_client(GetState, f"{NODE}/get_state")
        self._reset = self.node.create_client(Trigger, f"{NODE}/reset")
        self.procs: list[tuple[subprocess.Popen, Path]] = []

    def start(self, *ros_args: str, env: dict | None = None,
              module: str = "gpf_nav.ros.estimator_node") -> tuple[subprocess.Popen, Path]:
        log = self.tmp_path / f"{module.rsplit('.', 1)[-1]}{len(self.procs)}.log"
        with open(log, "w") as out:
            proc = subprocess.Popen([sys.executable, "-m", module, "--ros-args", *ros_args],
                                    env=env or self.env, cwd=self.tmp_path, stdout=out, stderr=subprocess.STDOUT)
        self.procs.append((proc, log))
        return proc, log

    def now_ns(self) -> int:
        return self.node.get_clock().now().nanoseconds

    def spin_until(self, condition, timeout: float = WAIT) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            for proc, log in self.procs:
                assert proc.poll() is None or proc.returncode == 0, log.read_text()
            self.executor.spin_once(timeout_sec=0.05)
        return condition()

    def call(self, client, request, resend=lambda: True):
        """The answer to ``request``. DDS can lose a request or its response while the two processes
        still discover each other (the client may see the service before the server sees the client's
        response reader, or a participant of an earlier test on this domain may still be announced),
        so an unanswered request is sent again every RESEND s while ``resend()`` says it should be."""
        assert self.spin_until(client.service_is_ready), f"{client.srv_name} never appeared"
        deadline = time.monotonic() + WAIT
        while time.monotonic() < deadline:
            future = client.call_async(request)
            if self.spin_until(future.done, timeout=RESEND):
                return future.result()
            client.remove_pending_request(future)
            if not resend():
                return None
        pytest.fail(f"no answer from {client.srv_name} within {WAIT:g} s")

    def state(self) -> str:
        return self.call(self._get, GetState.Request()).current_state.label

    def change(self, transition: int) -> bool:
        """Whether the transition succeeded. A transition is sent again only if the node is not
        already in its goal state (its answer, not the request, may have been lost)."""
        reached = []
        def resend() -> bool:
            reached.append(self.state() == GOAL[transition])
            return not reached[-1]
        answer = self.call(self._change, ChangeState.Request(transition=Transition(id=transition)), resend)
        return answer.success if answer is not None else reached[-1]

    def hand_over(self) -> None:
        """A state on set_state (latched), stamped now: the estimator initialises from it when active."""
        import numpy as np
        self._set_state.publish(conv.odometry_msg(np.array(STATE), np.diag([1e6, 1e6, 1e6, 1.0, 1.0, 1.0]),
                                                  self.now_ns(), "moon_inertial", "base_link"))

    def measure(self) -> None:
        """One rae measurement (best effort, as sensors publish), stamped now, of the handed-over state."""
        msg = Vector3Stamped()
        msg.header.stamp = conv.ns_to_stamp(self.now_ns())
        msg.header.frame_id = "station"
        msg.vector.x, msg.vector.y, msg.vector.z = 1.8e6, 0.0, 0.0
        self._rae.publish(msg)

    def reset(self) -> str:
        return self.call(self._reset, Trigger.Request()).message

    def odometry_after(self, t_ns: int) -> list:
        return [m for m in self.odometry if conv.stamp_to_ns(m.header.stamp) > t_ns]

    def status(self) -> dict:
        for msg in reversed(self.diagnostics):
            for status in msg.status:
                if status.name == STATUS_NAME:
                    return parse_values(status)
        return {}

    def close(self) -> None:
        for proc, _ in self.procs:
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def graph(tmp_path):
    g = Graph(tmp_path)
    yield g
    g.close()


def _tf2_msgs_in(env: dict) -> bool:
    return subprocess.run([sys.executable, "-c", "import tf2_msgs.msg"], env=env, capture_output=True).returncode == 0


def test_lifecycle_transitions_through_the_standard_services(graph):
    proc, log = graph.start("-p", "autostart:=false", "-p", "nosuch_param:=1", "-p", "diagnostics_period:=0.5")
    assert graph.state() == "unconfigured"
    graph.hand_over()
    start = graph.now_ns()
    assert graph.node.count_publishers("odometry/filtered") == 0  # unconfigured: no publisher at all
    graph.spin_until(lambda: graph.odometry, timeout=2.0)
    assert not graph.odometry and not graph.diagnostics

    assert graph.change(Transition.TRANSITION_CONFIGURE)
    assert graph.state() == "inactive"
    assert graph.spin_until(lambda: graph.node.count_publishers("odometry/filtered") == 1)
    # the latched prior (sent while unconfigured) reaches the configured node: kept, not applied yet
    assert graph.spin_until(lambda: "keeping the set_state message" in log.read_text()), log.read_text()
    # measurements while inactive: counted, not processed (best effort: sent until one got through;
    # the count is read from /diagnostics once active)
    assert graph.spin_until(lambda: graph.node.count_subscribers("measurements/rae") >= 1)
    for _ in range(20):
        graph.measure()
        graph.spin_until(lambda: False, timeout=0.1)
    assert not graph.odometry and not graph.diagnostics  # configured but inactive: still nothing

    assert graph.change(Transition.TRANSITION_ACTIVATE)
    assert graph.state() == "active"
    # no second hand-over: the prior kept while inactive initialises the filter at activation
    assert graph.spin_until(lambda: len(graph.odometry_after(start)) >= 5), "no odometry once active"
    assert graph.spin_until(lambda: graph.status().get("initialized") == "true")
    status = graph.status()
    assert status["initialized from"] == "set_state" and int(status["accepted set_state"]) == 1, status
    assert int(status["messages ignored while inactive"]) >= 1, status
    assert int(status.get("accepted rae", 0)) == 0 and status["messages rejected"] == "0", status
    assert status["tf"].startswith("not published: ") or status["tf"] == "moon_inertial -> base_link on /tf"
    assert "applying the set_state message received while inactive" in log.read_text()

    assert graph.change(Transition.TRANSITION_DEACTIVATE)
    stopped = graph.now_ns()  # after the answer: anything stamped later was published while inactive
    assert graph.state() == "inactive"
    graph.spin_until(lambda: graph.odometry_after(stopped), timeout=3.0)
    assert not graph.odometry_after(stopped), "odometry while inactive"

    # inactive: a reset, then a new prior; the newest (the prior) is kept and applied at activation
    assert graph.reset() == "inactive: the filter resets when the node activates"
    graph.hand_over()
    assert graph.spin_until(lambda: "it replaces the ~/reset request kept before" in log.read_text()), log.read_text()
    assert graph.change(Transition.TRANSITION_ACTIVATE)
    resumed = graph.now_ns()
    assert graph.spin_until(lambda: len(graph.odometry_after(resumed)) >= 3), "no odometry after re-activation"
    assert graph.spin_until(lambda: int(graph.status().get("accepted set_state", 0)) == 2), graph.status()

    assert graph.change(Transition.TRANSITION_DEACTIVATE)
    assert graph.change(Transition.TRANSITION_CLEANUP)
    assert graph.state() == "unconfigured"
    assert graph.spin_until(lambda: graph.node.count_publishers("odometry/filtered") == 0)
    assert graph.change(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
    assert proc.wait(timeout=WAIT) == 0, log.read_text()

    text = log.read_text()
    assert "Traceback" not in text, text
    warnings = [line for line in text.splitlines() if "nosuch_param" in line]
    assert len(warnings) == 1 and "WARN" in warnings[0] and "does not declare" in warnings[0], text
    assert "inactive: stopped publishing and consuming measurements" in text
    # configure keeps the start-up's objects (about 150 000) out of the garbage collector's full scans
    frozen = [int(line.split("]: ")[1].split()[0]) for line in text.splitlines() if "start-up objects kept" in line]
    assert len(frozen) == 1 and frozen[0] > 10_000, text
    no_tf = [line for line in text.splitlines() if "no TF is published" in line]
    assert len(no_tf) == (0 if _tf2_msgs_in(graph.env) else 1), text


def test_configure_fails_on_an_invalid_parameter_and_the_node_stays_up(graph):
    proc, log = graph.start("-p", "autostart:=false", "-p", "n_particles:=0")
    assert graph.state() == "unconfigured"
    assert not graph.change(Transition.TRANSITION_CONFIGURE)
    assert graph.state() == "unconfigured" and proc.poll() is None
    text = log.read_text()
    assert "configure failed: invalid parameters: " in text and "n_particles" in text, text


def test_autostart_with_an_invalid_parameter_refuses_to_start(graph):
    proc, log = graph.start("-p", "n_particles:=0")
    assert proc.wait(timeout=WAIT) == 2
    text = log.read_text()
    assert "refusing to start: invalid parameters: " in text and "n_particles" in text, text
    assert "configure failed" not in text  # one FATAL line, not two


@pytest.fixture(scope="module")
def tf2_msgs():
    """tf2_msgs built from its definition (cached), or a skip naming what is missing to build it."""
    missing = interfaces.missing_tools()
    if missing:
        pytest.skip(f"cannot build tf2_msgs here: no {missing}")
    built = interfaces.build("tf2_msgs")
    built.load()
    return built


def test_tf_with_every_odometry_message_received_by_a_subscriber(graph, tf2_msgs):
    from tf2_msgs.msg import TFMessage
    transforms = []
    tf_qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=100,
                        durability=DurabilityPolicy.VOLATILE)
    graph.node.create_subscription(TFMessage, "/tf", lambda m: transforms.extend(m.transforms), tf_qos)
    env = tf2_msgs.environment(graph.env)
    assert _tf2_msgs_in(env)
    proc, log = graph.start("-p", "tf_child_frame_id:=vehicle", "-p", "diagnostics_period:=0.5", env=env)
    assert graph.spin_until(lambda: graph.node.count_publishers("/tf") == 1), log.read_text()
    graph.hand_over()
    assert graph.spin_until(lambda: len(graph.odometry) >= 20 and len(transforms) >= 20), log.read_text()
    assert graph.spin_until(lambda: graph.status().get("tf") == "moon_inertial -> vehicle on /tf")

    assert {(t.header.frame_id, t.child_frame_id) for t in transforms} == {
        ("moon_inertial", "vehicle"), ("moon_inertial", "moon_fixed"), ("moon_fixed", "map")}
    by_stamp = {conv.stamp_to_ns(t.header.stamp): t for t in transforms if t.child_frame_id == "vehicle"}
    matched = 0
    for odom in graph.odometry:
        t = by_stamp.get(conv.stamp_to_ns(odom.header.stamp))
        if t is None:  # the subscriber may have joined /tf a little later than odometry/filtered
            continue
        matched += 1
        assert (t.header.frame_id, t.child_frame_id) == ("moon_inertial", "vehicle")
        p = odom.pose.pose.position
        assert (t.transform.translation.x, t.transform.translation.y, t.transform.translation.z) == (p.x, p.y, p.z)
        assert t.transform.rotation.w == 1.0
    assert matched >= 15, (matched, len(graph.odometry), len(transforms))
    assert "no TF is published" not in log.read_text()


def test_with_the_simulator_already_running_odometry_flows_at_activation(graph):
    """nav2's set-up (docs/ros.md, Lifecycle): the simulator runs and has handed its prior over (latched)
    long before a manager configures and activates the estimator. The prior reaches the node at
    ``configure`` and is applied at ``activate``: the first odometry comes before the second measurement
    stamped after activation (measurements are 2 s apart), not after the ``init_window`` (10) measurements
    the filter would otherwise wait for. Judged by the messages' stamps, all on the wall clock (the
    simulator's time starts at the wall-clock time); the wall time is printed."""
    graph.start("-p", "start_delay:=0.5", module="gpf_nav.ros.simulator_node")
    assert graph.spin_until(lambda: len(graph.rae) >= 1), "no measurement from the simulator"
    proc, log = graph.start("-p", "autostart:=false")
    assert graph.state() == "unconfigured"
    assert graph.change(Transition.TRANSITION_CONFIGURE)
    assert graph.spin_until(lambda: "keeping the set_state message" in log.read_text()), log.read_text()
    activating = graph.now_ns()
    wall = time.monotonic()
    assert graph.change(Transition.TRANSITION_ACTIVATE)
    assert graph.spin_until(lambda: graph.odometry_after(activating)), log.read_text()
    first_wall = time.monotonic() - wall
    first = min(conv.stamp_to_ns(m.header.stamp) for m in graph.odometry_after(activating))
    later = lambda: sorted(s for s in (conv.stamp_to_ns(m.header.stamp) for m in graph.rae) if s > activating)  # noqa: E731
    assert graph.spin_until(lambda: len(later()) >= 2), "the simulator stopped measuring"
    assert first < later()[1], (f"first odometry {(first - activating) * 1e-9:.2f} s after activation, after the "
                                f"second measurement ({(later()[1] - activating) * 1e-9:.2f} s)", log.read_text())
    assert graph.spin_until(lambda: graph.status().get("initialized from") == "set_state"), graph.status()
    assert "applying the set_state message received while inactive" in log.read_text()
    print(f"first odometry stamped {(first - activating) * 1e-9:.2f} s after the activate request; "
          f"received {first_wall:.2f} s (wall) after it")
