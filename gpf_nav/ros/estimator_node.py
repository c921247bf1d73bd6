"""``ros2 run gpf_nav estimator``: the GPF (or a baseline filter) as a ROS 2 navigation node.

A thin adapter around :class:`gpf_nav.ros.estimator_core.EstimatorCore` (message checks, the
engine, output messages; shared with ``gpf-nav replay``): subscriptions, publishers, timers on the
node clock, the ``~/reset`` service and the live parameters. Topics, parameters, frames and the
bad-input rules are documented in ``docs/ros.md``.
"""
from __future__ import annotations

import math
import sys
import time

import rclpy
import rclpy.exceptions
import rclpy.logging
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from gpf_nav.allocator import retain_freed_memory
from gpf_nav.blas import limit_blas_threads
from gpf_nav.ros import shutdown
from gpf_nav.ros.estimator_core import INPUT_TOPICS, OUTPUT_TOPICS, EstimatorCore
from gpf_nav.estimator.factory import FILTERS
from gpf_nav.estimator.params import ESTIMATOR, ParameterError
from gpf_nav.ros.parameters import declare

NODE_NAME = "gpf_estimator"


class EstimatorNode(Node):
    """The ``gpf_estimator`` node. Raises :class:`ParameterError` on invalid parameters."""

    def __init__(self, name: str = NODE_NAME, **kwargs):
        super().__init__(name, **kwargs)
        p = self.params = declare(self, ESTIMATOR)
        self.core = EstimatorCore(p, self._publish, self.get_logger(),
                                  wants_particles=lambda: self._publishers_by_topic["gpf/particles"]
                                  .get_subscription_count() > 0)
        self.engine = self.core.engine
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._started = time.monotonic()

        sensor_qos = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                                depth=p["queue_depth"], durability=DurabilityPolicy.VOLATILE)
        reliable = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                              depth=10)
        handover = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=1,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)  # a late joiner gets the last one
        qos = {"set_pose": reliable, "set_state": handover}
        for topic, (stream, msg_type) in INPUT_TOPICS.items():
            self.create_subscription(msg_type, topic, self._callback(stream), qos.get(stream, sensor_qos))
        self._publishers_by_topic = {topic: self.create_publisher(msg_type, topic, reliable)
                                     for topic, msg_type in OUTPUT_TOPICS.items()}
        self.create_service(Trigger, "~/reset", self._on_reset)
        if p["publish_rate"] > 0:
            self.create_timer(1.0 / p["publish_rate"], lambda: self.core.publish_tick(self._now_ns()))
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["diagnostics_period"], self._on_diagnostics_timer, clock=self._steady)
        self.get_logger().info(self.core.describe())

    def _on_set_parameters(self, params) -> SetParametersResult:
        updates = {}
        for param in params:
            value = param.value
            if param.name in ("ess_warn_threshold", "costate_warn_threshold", "sensor_timeout"):
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                        or value < 0:
                    return SetParametersResult(successful=False,
                                               reason=f"{param.name} must be a non-negative number")
                updates[param.name] = float(value)
        for name, value in updates.items():
            self.params[name] = value
            attr = {"ess_warn_threshold": "ess_warn", "costate_warn_threshold": "costate_warn",
                    "sensor_timeout": "sensor_timeout"}[name]
            setattr(self.core.thresholds, attr, value)
        return SetParametersResult(successful=True)

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _callback(self, stream: str):
        return lambda msg: self.core.handle(stream, msg, self._now_ns())

    def _publish(self, topic: str, msg) -> None:
        self._publishers_by_topic[topic].publish(msg)

    def _on_reset(self, request, response):
        response.success = True
        response.message = self.core.reset()
        self.get_logger().info(response.message)
        return response

    def _on_diagnostics_timer(self) -> None:
        self.core.diagnostics_tick(self._now_ns(), time.monotonic() - self._started,
                                   self.get_fully_qualified_name())


def main(argv: list[str] | None = None) -> int:
    """Console script ``estimator``: returns 2 (after a FATAL log line) on invalid parameters, 0 when
    stopped by SIGINT or SIGTERM (:mod:`gpf_nav.ros.shutdown`)."""
    retain_freed_memory()
    limit_blas_threads()
    stop = shutdown.init_without_signal_handlers(sys.argv if argv is None else argv)
    try:
        node = EstimatorNode()
    except (ParameterError, rclpy.exceptions.InvalidParameterTypeException,
            rclpy.exceptions.InvalidParameterValueException) as err:
        rclpy.logging.get_logger(NODE_NAME).fatal(f"refusing to start: {err}")
        rclpy.try_shutdown()
        return 2
    try:
        shutdown.spin_until(node, stop)
    finally:
        shutdown.close(node)
    return 0


__all__ = ["EstimatorNode", "main", "FILTERS", "NODE_NAME"]

if __name__ == "__main__":
    sys.exit(main())
