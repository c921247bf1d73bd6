"""``ros2 run gpf_nav estimator``: the GPF (or a baseline filter) as a managed ROS 2 navigation node.

A thin adapter around :class:`gpf_nav.ros.message_layer.MessageLayer` (message checks, the
engine, output messages; shared with ``gpf-nav replay``): subscriptions, publishers, timers on the
node clock, the ``~/reset`` service, the live parameters, the lifecycle and TF.

Lifecycle (``rclpy.lifecycle``, nav2's semantics; the standard ``lifecycle_msgs`` services):

* ``configure`` builds the model, the filter and every topic from the parameters; an invalid value
  makes it fail with the reason, and the node stays ``unconfigured``;
* ``activate`` starts processing and publishing; ``deactivate`` stops both (measurements that arrive
  while inactive are counted, not processed); the filter keeps its state in between;
* a ``set_state``, ``set_pose`` or ``~/reset`` that arrives while the node is configured but inactive
  (the latched prior delivered at ``configure``, typically) is kept, the newest one, and applied at
  ``activate``;
* ``cleanup`` drops the filter and the topics; ``shutdown`` is clean from any state.

``autostart`` (default true) runs configure and activate at start-up, so the node with no
arguments behaves as a plain node; an invalid parameter then stops start-up (exit code 2).
With ``autostart:=false`` it waits, unconfigured, for a lifecycle manager.

TF: with ``publish_tf`` (default true) every odometry message also goes out as ``tf_frame_id ->
tf_child_frame_id`` on ``/tf`` with tf2's broadcaster QoS, with ``world_frame -> moon_fixed_frame ->
site_frame`` at its stamp, when ``tf2_msgs`` is importable; otherwise
one log line and the ``tf`` key of ``/diagnostics`` say why there is none. Topics, parameters, frames
and the bad-input rules are documented in ``docs/ros.md``.
"""
from __future__ import annotations

import math
import sys
import time
import traceback
from collections import Counter

from diagnostic_msgs.msg import KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from gpf_nav.allocator import retain_freed_memory
from gpf_nav.blas import limit_blas_threads
from gpf_nav.openmp import passive_openmp_waits
from gpf_nav.collector import freeze_start_up, thaw
from gpf_nav.estimator.factory import FILTERS
from gpf_nav.estimator.params import ESTIMATOR, ParameterError
from gpf_nav.ros import conversions as conv
from gpf_nav.ros import shutdown
from gpf_nav.ros.message_layer import OUTPUT_TOPICS, MessageLayer
from gpf_nav.ros.parameters import declare, params_files, warn_undeclared, warn_unmatched_params_files

try:
    from tf2_msgs.msg import TFMessage
    TF_UNAVAILABLE = ""
except ImportError as err:  # no wheel on PyPI; a ROS installation (or test/interfaces.py) provides it
    TFMessage = None
    TF_UNAVAILABLE = f"tf2_msgs is not importable ({err})"

NODE_NAME = "gpf_estimator"
TF_TOPIC = "/tf"
TF_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=100,
                    durability=DurabilityPolicy.VOLATILE)
"""tf2_ros's TransformBroadcaster QoS (its DynamicBroadcasterQoS)."""
INITIALISING = ("set_state", "set_pose")
"""Streams that (re-)initialise the filter: kept while inactive (the newest, with ~/reset), applied at activate."""
LIVE = {"ess_warn_threshold": "ess_warn", "costate_warn_threshold": "costate_warn",
        "sensor_timeout": "sensor_timeout"}
"""Live parameter -> attribute of the core's diagnostics thresholds."""


class EstimatorNode(LifecycleNode):
    """The ``gpf_estimator`` node. With ``autostart`` (the default) it is active when the constructor
    returns, and raises :class:`ParameterError` on invalid parameters. ``params_files``: the
    ``--params-file`` paths of the command line; one that sets nothing for this node is warned about."""

    def __init__(self, name: str = NODE_NAME, params_files=(), **kwargs):
        super().__init__(name, **kwargs)
        self.params = declare(self, ESTIMATOR)
        warn_undeclared(self)
        warn_unmatched_params_files(self, params_files)
        self.core: MessageLayer | None = None
        self.engine = None
        self.active = False
        self.finalized = False                  # after the shutdown transition: main() then exits 0
        self.ignored: Counter[str] = Counter()  # messages received while configured but inactive
        self.pending: tuple[str, object] | None = None  # newest set_state / set_pose / reset while inactive
        self._entities: list = []               # (destroy, entity): subscriptions, timers, service of configure
        self._publishers_by_topic: dict = {}
        self._tf_publisher = None
        self._imu_subscription = None           # drained before each other input (_take_waiting_imu)
        self._configure_error = ""
        self._autostarting = self.params["autostart"]
        self._started = time.monotonic()
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        if self._autostarting:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise ParameterError(self._configure_error)
            self.trigger_activate()
            self._autostarting = False
        else:
            self.get_logger().info("autostart is false: unconfigured, waiting for a lifecycle manager "
                                   f"({self.get_fully_qualified_name()}/change_state)")

    # --- lifecycle ---------------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._configure()
        except ParameterError as err:
            return self._configure_failed(str(err), TransitionCallbackReturn.FAILURE)
        except Exception as err:  # noqa: BLE001 - rclpy would turn it into a silent ERROR
            self.get_logger().error(traceback.format_exc())
            return self._configure_failed(f"{type(err).__name__}: {err}", TransitionCallbackReturn.ERROR)
        self.get_logger().info(self.core.describe())
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        result = super().on_activate(state)  # enables the lifecycle publishers
        waiting = sum(self.ignored.values())
        self.get_logger().info("active: processing and publishing" + (
            f" ({waiting} messages that arrived while inactive were not processed: {_counts(self.ignored)})"
            if waiting else ""))
        if self.pending is not None:
            kind, msg = self.pending
            self.pending = None
            self.get_logger().info(f"applying the {_kind(kind)} received while inactive")
            if kind == "reset":
                self.get_logger().info(self.core.reset())
            else:
                self.core.handle(kind, msg, self._now_ns())
        self.active = True
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        c = self.engine.counters
        self.get_logger().info(f"inactive: stopped publishing and consuming measurements; accepted so far: "
                               f"{_counts(c.accepted) or 'none'}, refused {c.total_rejected}")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        self.get_logger().info("cleaned up: filter and topics dropped")
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.pending = None
        self._release()
        self.finalized = True
        self.get_logger().info("shut down (finalized)")
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self._release()
        return TransitionCallbackReturn.SUCCESS  # back to unconfigured

    def _configure(self) -> None:
        """Build the core and every topic, timer and service; raises ParameterError."""
        p = self.params
        self.core = MessageLayer(p, self._publish, self.get_logger(), wants_particles=self._wants_particles)
        self.engine = self.core.engine
        if p["warm_up"]:  # before any subscription: nothing piles up while the kernels load
            ok, line = self.core.warm_up()
            (self.get_logger().info if ok else self.get_logger().warning)(line)
        self.ignored.clear()
        sensor_qos = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                                depth=p["queue_depth"], durability=DurabilityPolicy.VOLATILE)
        reliable = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                              depth=10)
        handover = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=1,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)  # a late joiner gets the last one
        self._publishers_by_topic = {topic: self.create_lifecycle_publisher(msg_type, topic, reliable)
                                     for topic, msg_type in OUTPUT_TOPICS.items()}
        if p["publish_tf"] and TFMessage is not None:
            self._tf_publisher = self.create_lifecycle_publisher(TFMessage, TF_TOPIC, TF_QOS)
        elif p["publish_tf"]:
            self.get_logger().warning(f"publish_tf is true but {TF_UNAVAILABLE}: no TF is published "
                                      "(docs/ros.md, TF)")
        qos = {"set_pose": reliable, "set_state": handover}
        # the IMU first: the executor takes the subscriptions that are ready in the order they were made, so
        # a sample and the measurement it precedes, ready together, are handled in stamp order (the other way
        # round, the measurement's history is re-applied when the sample comes: engine, late IMU samples);
        # the samples after the first wait for the next round, so every other input drains them first
        inputs = sorted(self.core.inputs.items(), key=lambda item: item[1][0] != "imu")
        subscriptions = [(stream, self.create_subscription(msg_type, topic, self._callback(stream),
                                                           qos.get(stream, sensor_qos)))
                         for topic, (stream, msg_type) in inputs]
        self._imu_subscription = next((sub for stream, sub in subscriptions if stream == "imu"), None)
        self._entities = [(self.destroy_subscription, sub) for _, sub in subscriptions]
        self._entities.append((self.destroy_service, self.create_service(Trigger, "~/reset", self._on_reset)))
        if p["publish_rate"] > 0:
            self._entities.append((self.destroy_timer,
                                   self.create_timer(1.0 / p["publish_rate"], self._on_publish_timer)))
        self._entities.append((self.destroy_timer, self.create_timer(p["diagnostics_period"],
                                                                     self._on_diagnostics_timer, clock=self._steady)))
        frozen = freeze_start_up()  # out of the collector's full scans (gpf_nav.collector)
        self.get_logger().info(f"{frozen} start-up objects kept out of the garbage collector's full scans")

    def _configure_failed(self, reason: str, result: TransitionCallbackReturn) -> TransitionCallbackReturn:
        self._release()
        self._configure_error = reason
        if not self._autostarting:  # at start-up main() reports it (FATAL, exit code 2)
            self.get_logger().error(f"configure failed: {reason}")
        return result

    def _release(self) -> None:
        """Destroy what configure created; the node is as constructed."""
        for destroy, entity in self._entities:
            destroy(entity)
        for publisher in [*self._publishers_by_topic.values(), self._tf_publisher]:
            if publisher is not None:
                self.destroy_lifecycle_publisher(publisher)
        self._entities, self._publishers_by_topic, self._tf_publisher = [], {}, None
        self._imu_subscription = None
        self.core = self.engine = None
        thaw()

    # --- callbacks ---------------------------------------------------------------------------------
    def _on_set_parameters(self, params) -> SetParametersResult:
        updates = {}
        for param in params:
            value = param.value
            if param.name in LIVE:
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                        or value < 0:
                    return SetParametersResult(successful=False,
                                               reason=f"{param.name} must be a non-negative number")
                updates[param.name] = float(value)
        for name, value in updates.items():
            self.params[name] = value
            if self.core is not None:
                setattr(self.core.thresholds, LIVE[name], value)
        return SetParametersResult(successful=True)

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _wants_particles(self) -> bool:
        return self._publishers_by_topic["gpf/particles"].get_subscription_count() > 0

    def _callback(self, stream: str):
        def on_message(msg) -> None:
            if self.active:
                if stream != "imu":
                    self._take_waiting_imu()
                self.core.handle(stream, msg, self._now_ns())
            elif stream in INITIALISING:
                self._keep(stream, msg)
            else:
                self.ignored[stream] += 1
        return on_message

    def _take_waiting_imu(self) -> None:
        """Handle the IMU samples already received, before another input: the executor takes one message
        per subscription per round, so of a burst of samples and the measurement they precede only the first
        sample would come before it, and each later one would make the engine re-apply the measurement. At
        most ``queue_depth`` samples (the subscription's queue), so that a flood of IMU cannot hold up the
        input waiting for them."""
        subscription = self._imu_subscription
        if subscription is None:
            return
        for _ in range(self.params["queue_depth"]):
            with subscription.handle:  # the executor's own way to take a message (rclpy.executors)
                taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
            if taken is None:
                return
            self.core.handle("imu", taken[0], self._now_ns())

    def _keep(self, kind: str, msg) -> None:
        """Keep ``kind`` (a stream of INITIALISING or ``reset``) until activation; it replaces (and
        counts as not processed) the one kept before."""
        replaced = self.pending
        if replaced is not None:
            self.ignored[replaced[0]] += 1
        self.pending = (kind, msg)
        self.get_logger().info(f"inactive: keeping the {_kind(kind)} received now; it is applied at activation"
                               + (f" (it replaces the {_kind(replaced[0])} kept before)" if replaced else ""))

    def _publish(self, topic: str, msg) -> None:
        if topic == "/diagnostics":
            msg.status[0].values.extend(KeyValue(key=k, value=v) for k, v in self._node_status())
        self._publishers_by_topic[topic].publish(msg)
        if topic == "odometry/filtered" and self._tf_publisher is not None:
            p = self.params
            self._tf_publisher.publish(TFMessage(transforms=[
                conv.odometry_transform(msg, p["tf_frame_id"], p["tf_child_frame_id"]),
                *self.core.frame_transforms(conv.stamp_to_ns(msg.header.stamp))]))

    def _node_status(self) -> list[tuple[str, str]]:
        """The node's own ``/diagnostics`` key/values: TF and messages not processed while inactive."""
        p = self.params
        if self._tf_publisher is not None:
            tf = (f"{p['tf_frame_id'] or p['world_frame']} -> {p['tf_child_frame_id'] or p['base_frame']} "
                  f"on {TF_TOPIC}")
        else:
            tf = f"not published: {TF_UNAVAILABLE}" if p["publish_tf"] else "not published: publish_tf is false"
        return [("tf", tf), ("messages ignored while inactive", str(sum(self.ignored.values())))]

    def _on_reset(self, request, response):
        response.success = True
        if not self.active:
            self._keep("reset", None)
            response.message = "inactive: the filter resets when the node activates"
            return response
        response.message = self.core.reset()
        self.get_logger().info(response.message)
        return response

    def _on_publish_timer(self) -> None:
        if self.active:
            self.core.publish_tick(self._now_ns())

    def _on_diagnostics_timer(self) -> None:
        if self.active:
            self.core.diagnostics_tick(self._now_ns(), time.monotonic() - self._started,
                                       self.get_fully_qualified_name())


def _kind(kind: str) -> str:
    return "~/reset request" if kind == "reset" else f"{kind} message"


def _counts(counter: Counter) -> str:
    return ", ".join(f"{stream} {n}" for stream, n in sorted(counter.items()))


def main(argv: list[str] | None = None) -> int:
    """Console script ``estimator``: returns 2 (after a FATAL log line) on invalid parameters at
    start-up, 0 when stopped by SIGINT or SIGTERM (:mod:`gpf_nav.ros.shutdown`) or by the lifecycle
    shutdown transition."""
    retain_freed_memory()
    limit_blas_threads()
    passive_openmp_waits()
    argv = sys.argv if argv is None else argv
    return shutdown.run("estimator", NODE_NAME, lambda: EstimatorNode(params_files=params_files(argv)), argv,
                        done=lambda node: node.finalized)


__all__ = ["EstimatorNode", "main", "FILTERS", "NODE_NAME"]

if __name__ == "__main__":
    sys.exit(main())
