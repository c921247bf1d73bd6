"""``ros2 run gpf_nav estimator``: the GPF (or a baseline filter) as a ROS 2 navigation node.

A thin adapter around :class:`gpf_nav.ros.engine.EstimatorEngine`: message checks
(:mod:`gpf_nav.ros.validation`), conversions (:mod:`gpf_nav.ros.conversions`), publishing and
diagnostics. Topics, parameters, frames and the bad-input rules are documented in ``docs/ros.md``.
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np
import rclpy
import rclpy.exceptions
import rclpy.logging
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Range
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from diagnostic_msgs.msg import DiagnosticArray

from gpf_nav.allocator import retain_freed_memory
from gpf_nav.blas import limit_blas_threads
from gpf_nav.ros import conversions as conv
from gpf_nav.ros import diagnostics as diag
from gpf_nav.ros import shutdown
from gpf_nav.ros import validation as val
from gpf_nav.ros.engine import EngineConfig, EstimatorEngine
from gpf_nav.ros.factory import FILTERS, make_filter, make_lunar_model
from gpf_nav.ros.params import ESTIMATOR, ParameterError, declare

NODE_NAME = "gpf_estimator"
LOG_THROTTLE = 5.0  # s between two log lines about the same refusal reason


def check_estimator_parameters(p: dict) -> list[str]:
    """Errors in the non-filter parameters (the filter's are checked by ``make_filter``)."""
    errors = []
    positive = ("max_future", "imu_timeout", "max_extrapolation", "diagnostics_period",
                "sensor_timeout", "quaternion_tolerance")
    for key in positive:
        if not (math.isfinite(p[key]) and p[key] > 0):
            errors.append(f"parameter '{key}' = {p[key]!r} must be positive")
    for key in ("publish_rate", "max_measurement_rate", "reinit_hold"):
        if not (math.isfinite(p[key]) and p[key] >= 0):
            errors.append(f"parameter '{key}' = {p[key]!r} must be >= 0")
    if p["init_window"] < 2:
        errors.append(f"parameter 'init_window' = {p['init_window']} must be >= 2")
    if p["queue_depth"] < 1:
        errors.append(f"parameter 'queue_depth' = {p['queue_depth']} must be >= 1")
    if p["max_published_particles"] < 0:
        errors.append(f"parameter 'max_published_particles' = {p['max_published_particles']} must be >= 0")
    if not (math.isfinite(p["ess_warn_threshold"]) and 0 <= p["ess_warn_threshold"] <= 1):
        errors.append(f"parameter 'ess_warn_threshold' = {p['ess_warn_threshold']!r} must lie in [0, 1]")
    if not p["costate_warn_threshold"] > 0:
        errors.append(f"parameter 'costate_warn_threshold' = {p['costate_warn_threshold']!r} must be positive")
    if p["initial_state"] is not None and (len(p["initial_state"]) != 6
                                           or not all(math.isfinite(v) for v in p["initial_state"])):
        errors.append(f"parameter 'initial_state' = {p['initial_state']!r} must be 6 finite numbers "
                      "[x, y, z, vx, vy, vz] (m, m/s)")
    if len(p["initial_std"]) != 6 or not all(math.isfinite(v) and v > 0 for v in p["initial_std"]):
        errors.append(f"parameter 'initial_std' = {p['initial_std']!r} must be 6 positive numbers")
    if not math.isfinite(p["initial_stamp"]):
        errors.append(f"parameter 'initial_stamp' = {p['initial_stamp']!r} must be finite")
    if not p["world_frame"]:
        errors.append("parameter 'world_frame' must not be empty")
    errors.extend(check_monitor_parameters(p))
    return errors


def check_monitor_parameters(p: dict) -> list[str]:
    """Errors in the ``monitor_*`` parameters (checked even when the monitor is disabled)."""
    errors = []
    if p["monitor_window"] < 1:
        errors.append(f"parameter 'monitor_window' = {p['monitor_window']} must be >= 1")
    if p["monitor_gap"] < 0:
        errors.append(f"parameter 'monitor_gap' = {p['monitor_gap']} must be >= 0")
    if not 2 <= p["monitor_min_reference"] <= p["monitor_reference"]:
        errors.append(f"parameters 'monitor_min_reference' = {p['monitor_min_reference']} and 'monitor_reference' "
                      f"= {p['monitor_reference']} must satisfy 2 <= monitor_min_reference <= monitor_reference")
    alpha, warn = p["monitor_false_alarm_rate"], p["monitor_warn_false_alarm_rate"]
    if not (math.isfinite(alpha) and 0.0 < alpha < 1.0):
        errors.append(f"parameter 'monitor_false_alarm_rate' = {alpha!r} must lie in (0, 1)")
    elif not (math.isfinite(warn) and alpha <= warn < 1.0):
        errors.append(f"parameter 'monitor_warn_false_alarm_rate' = {warn!r} must lie in "
                      f"[monitor_false_alarm_rate, 1) = [{alpha!r}, 1)")
    quarantine = p["monitor_quarantine_rate"]
    if not math.isfinite(quarantine) or (quarantine >= 0.0 and math.isfinite(alpha) and quarantine > alpha):
        errors.append(f"parameter 'monitor_quarantine_rate' = {quarantine!r} must be negative (default) or "
                      "lie in [0, monitor_false_alarm_rate]")
    if not math.isfinite(p["monitor_hold"]):
        errors.append(f"parameter 'monitor_hold' = {p['monitor_hold']!r} must be finite (negative: latched)")
    return errors


def monitor_options(p: dict) -> dict | None:
    """``CostateMonitor`` keyword arguments from the node parameters (None when disabled)."""
    if not p["monitor_enabled"]:
        return None
    return dict(window=p["monitor_window"], reference=p["monitor_reference"],
                min_reference=p["monitor_min_reference"], gap=p["monitor_gap"],
                false_alarm_rate=p["monitor_false_alarm_rate"],
                warn_false_alarm_rate=p["monitor_warn_false_alarm_rate"],
                quarantine_rate=None if p["monitor_quarantine_rate"] < 0 else p["monitor_quarantine_rate"])


class EstimatorNode(Node):
    """The ``gpf_estimator`` node. Raises :class:`ParameterError` on invalid parameters."""

    def __init__(self, name: str = NODE_NAME, **kwargs):
        super().__init__(name, **kwargs)
        p = self.params = declare(self, ESTIMATOR)
        errors = check_estimator_parameters(p)
        try:
            self.model = make_lunar_model(mu=p["mu"], station=p["station"],
                                          range_noise_std=p["range_noise_std"],
                                          angle_noise_std=p["angle_noise_std"],
                                          accel_noise_density=p["accel_noise_density"],
                                          max_step=p["max_step"])
        except ValueError as err:
            errors.append(str(err))
            self.model = None
        if self.model is not None:
            try:
                make_filter(p["filter"], self.model, **self._filter_options())
            except ValueError as err:
                errors.append(str(err))
        if errors:
            raise ParameterError("invalid parameters: " + "; ".join(errors))

        self.filter_name = p["filter"]
        config = EngineConfig(
            max_future=p["max_future"], imu_timeout=p["imu_timeout"], init_window=p["init_window"],
            initial_state=None if p["initial_state"] is None else np.array(p["initial_state"]),
            initial_std=np.array(p["initial_std"]), initial_stamp=p["initial_stamp"],
            max_measurement_rate=p["max_measurement_rate"], max_extrapolation=p["max_extrapolation"],
            reinit_hold=p["reinit_hold"], monitor=monitor_options(p), monitor_hold=p["monitor_hold"])
        self.engine = EstimatorEngine(lambda: make_filter(p["filter"], self.model, **self._filter_options()),
                                      self.model, config)
        self.thresholds = diag.Thresholds(ess_warn=p["ess_warn_threshold"],
                                          costate_warn=p["costate_warn_threshold"],
                                          sensor_timeout=p["sensor_timeout"])
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._last_log: dict[str, float] = {}
        self._integrity_level = "OK"
        self._last_published_ns: int | None = None
        self._last_now_ns = 0
        self._started = time.monotonic()

        sensor_qos = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                                depth=p["queue_depth"], durability=DurabilityPolicy.VOLATILE)
        reliable = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                              depth=10)
        self.create_subscription(Vector3Stamped, "measurements/rae", self._guard("rae", self._on_rae), sensor_qos)
        self.create_subscription(Range, "measurements/range", self._guard("range", self._on_range), sensor_qos)
        self.create_subscription(Imu, "imu", self._guard("imu", self._on_imu), sensor_qos)
        self.create_subscription(PoseWithCovarianceStamped, "set_pose", self._guard("set_pose", self._on_set_pose),
                                 reliable)
        handover = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=1,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)  # a late joiner gets the last one
        self.create_subscription(Odometry, "set_state", self._guard("set_state", self._on_set_state), handover)
        self.odom_pub = self.create_publisher(Odometry, "odometry/filtered", reliable)
        self.ess_pub = self.create_publisher(Float64, "gpf/ess", reliable)
        self.costate_pub = self.create_publisher(Vector3Stamped, "gpf/costate", reliable)
        self.acceleration_pub = self.create_publisher(Vector3Stamped, "gpf/unmodelled_acceleration", reliable)
        self.particles_pub = self.create_publisher(PoseArray, "gpf/particles", reliable)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", reliable)
        self.create_service(Trigger, "~/reset", self._on_reset)
        if p["publish_rate"] > 0:
            self.create_timer(1.0 / p["publish_rate"], self._on_publish_timer)
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["diagnostics_period"], self._on_diagnostics_timer, clock=self._steady)
        self.get_logger().info(
            f"{self.filter_name} estimator up: N={p['n_particles']}, world_frame={p['world_frame']}, "
            f"initialisation from "
            + ("parameters" if p["initial_state"] is not None else
               f"set_state, set_pose or the first {p['init_window']} measurements"))

    # --- parameters ------------------------------------------------------------------------------------
    def _filter_options(self) -> dict:
        p = self.params
        return dict(n_particles=p["n_particles"], seed=p["seed"], reference=p["reference"],
                    weighting=p["weighting"], metric=p["metric"], regularization=p["regularization"],
                    unmodelled_acceleration_std=p["unmodelled_acceleration_std"],
                    unmodelled_acceleration_time=p["unmodelled_acceleration_time"],
                    kernel_bandwidth=p["kernel_bandwidth"], collapse_steps=p["collapse_steps"],
                    resampling=p["resampling"], ess_threshold=p["ess_threshold"],
                    compute_costate=p["compute_costate"], ukf_alpha=p["ukf_alpha"],
                    ukf_beta=p["ukf_beta"], ukf_kappa=p["ukf_kappa"])

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
            setattr(self.thresholds, attr, value)
        return SetParametersResult(successful=True)

    # --- helpers ---------------------------------------------------------------------------------------
    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _refuse(self, stream: str, reason: str, detail: str, counted: bool = False) -> None:
        """Count (unless the engine did) and log, at most once per LOG_THROTTLE s per reason."""
        c = self.engine.counters
        n = c.rejected[reason] if counted else c.reject(stream, reason)
        now = time.monotonic()
        if now - self._last_log.get(reason, -math.inf) >= LOG_THROTTLE:
            self._last_log[reason] = now
            self.get_logger().warning(f"dropped {stream} message: {reason}: {detail} ({n} so far)")

    def _guard(self, stream: str, callback):
        """``callback`` with a last-resort net: an unexpected exception is counted and logged, never
        propagated into the executor (which would stop the node)."""
        def guarded(msg):
            try:
                callback(msg)
            except Exception as err:  # noqa: BLE001
                self._refuse(stream, "internal_error", f"{type(err).__name__}: {err}")
        return guarded

    def _check_header(self, stream: str, header, frame: str) -> int | None:
        """Stamp in ns, or None after refusing the message."""
        ok, reason = val.check_stamp(header.stamp.sec, header.stamp.nanosec)
        if not ok:
            self._refuse(stream, reason, f"stamp sec={header.stamp.sec} nanosec={header.stamp.nanosec}")
            return None
        ok, reason = val.check_frame(header.frame_id, frame)
        if not ok:
            self._refuse(stream, reason, f"frame_id '{header.frame_id}', expected '{frame}'")
            return None
        return conv.stamp_to_ns(header.stamp)

    def _timing_detail(self, stamp_ns: int) -> str:
        last = self.engine.last_measurement_ns
        now = self._now_ns()
        return (f"stamp {stamp_ns * 1e-9:.3f} s, last processed "
                f"{'none' if last is None else f'{last * 1e-9:.3f} s'}, node clock {now * 1e-9:.3f} s")

    # --- inputs ----------------------------------------------------------------------------------------
    def _on_rae(self, msg: Vector3Stamped) -> None:
        stamp = self._check_header("rae", msg.header, self.params["measurement_frame"])
        if stamp is None:
            return
        ok, reason, values = val.check_rae(*conv.rae_values(msg))
        if not ok:
            self._refuse("rae", reason, f"(range, azimuth, elevation) = {values}")
            return
        self._measurement("rae", stamp, np.array(values))

    def _on_range(self, msg: Range) -> None:
        stamp = self._check_header("range", msg.header, self.params["measurement_frame"])
        if stamp is None:
            return
        ok, reason = val.check_range(msg.range, msg.min_range, msg.max_range)
        if not ok:
            self._refuse("range", reason, f"range {msg.range} with limits [{msg.min_range}, {msg.max_range}]")
            return
        self._measurement("range", stamp, np.array([float(msg.range), np.nan, np.nan]))

    def _measurement(self, stream: str, stamp: int, y: np.ndarray) -> None:
        ok, reason = self.engine.measurement(stamp, y, self._now_ns(), stream)
        if not ok:
            if reason == "filter_error":
                self.get_logger().error(f"filter re-initialised from the last good estimate: "
                                        f"{self.engine.last_reinit_reason}")
            self._refuse(stream, reason, self._timing_detail(stamp), counted=True)
            return
        if reason == "buffered":
            return
        self._publish(stamp, self.engine.mean, self.engine.cov, update=True)
        self._log_integrity(stamp)

    def _log_integrity(self, stamp: int) -> None:
        """A WARN log line when the monitor goes to FAULT (at most once per LOG_THROTTLE s)."""
        monitor = self.engine.monitor
        level = monitor.level if monitor is not None else "OK"
        previous, self._integrity_level = self._integrity_level, level
        if level != "FAULT" or previous == "FAULT":
            return
        now = time.monotonic()
        if now - self._last_log.get("_integrity", -math.inf) >= LOG_THROTTLE:
            self._last_log["_integrity"] = now
            s = monitor.status
            self.get_logger().warning(
                f"integrity FAULT at {stamp * 1e-9:.3f} s: the mean co-state is biased (T^2 {s.statistic:.4g} > "
                f"{s.threshold:.4g}, p = {s.p_value:.2g}): the model, the sensors or the filter disagree with the data")

    def _on_imu(self, msg: Imu) -> None:
        stamp = self._check_header("imu", msg.header, self.params["imu_frame"])
        if stamp is None:
            return
        if float(msg.linear_acceleration_covariance[0]) == -1.0:
            self._refuse("imu", "not_provided", "linear_acceleration_covariance[0] == -1")
            return
        a = msg.linear_acceleration
        ok, reason = val.check_finite(a.x, a.y, a.z)
        if ok and conv.imu_has_orientation(msg):
            q = msg.orientation
            ok, reason = val.check_quaternion(q.x, q.y, q.z, q.w, self.params["quaternion_tolerance"])
        if not ok:
            q = msg.orientation
            self._refuse("imu", reason, f"linear_acceleration ({a.x}, {a.y}, {a.z}), "
                                        f"orientation ({q.x}, {q.y}, {q.z}, {q.w})")
            return
        ok, reason = self.engine.imu(stamp, conv.imu_specific_force(msg), self._now_ns())
        if not ok:
            self._refuse("imu", reason, self._timing_detail(stamp), counted=True)

    def _on_set_pose(self, msg: PoseWithCovarianceStamped) -> None:
        stamp = self._check_header("set_pose", msg.header, self.params["world_frame"])
        if stamp is None:
            return
        if stamp == 0:
            stamp = self._now_ns()
        pos = msg.pose.pose.position
        cov = conv.position_covariance(msg.pose.covariance)
        ok, reason = val.check_finite(pos.x, pos.y, pos.z, *cov.reshape(-1))
        if not ok:
            self._refuse("set_pose", reason, f"position ({pos.x}, {pos.y}, {pos.z}) or covariance")
            return
        ok, reason = self.engine.set_pose(stamp, np.array([pos.x, pos.y, pos.z]), _positive_definite(cov),
                                          self._now_ns())
        self._initialized_from("set_pose", stamp, ok, reason)

    def _on_set_state(self, msg: Odometry) -> None:
        stamp = self._check_header("set_state", msg.header, self.params["world_frame"])
        if stamp is None:
            return
        if stamp == 0:
            stamp = self._now_ns()
        state = conv.odometry_state(msg)
        pos_cov = conv.position_covariance(msg.pose.covariance)
        vel_cov = conv.position_covariance(msg.twist.covariance)  # the linear block, as for the pose
        ok, reason = val.check_finite(*state, *pos_cov.reshape(-1), *vel_cov.reshape(-1))
        if not ok:
            self._refuse("set_state", reason, f"state {state.tolist()} or covariance")
            return
        m = self.model
        p, v = list(m.position_index), list(m.velocity_index)
        mean = np.zeros(m.state_dim)
        mean[p], mean[v] = state[:3], state[3:]
        cov = np.diag(np.asarray(self.params["initial_std"]) ** 2)
        for index, block in ((p, _positive_definite(pos_cov)), (v, _positive_definite(vel_cov))):
            if block is not None:
                cov[np.ix_(index, index)] = block
        ok, reason = self.engine.set_state(stamp, mean, cov, self._now_ns())
        self._initialized_from("set_state", stamp, ok, reason)

    def _initialized_from(self, stream: str, stamp: int, ok: bool, reason: str) -> None:
        if not ok:
            self._refuse(stream, reason, self._timing_detail(stamp), counted=True)
            return
        self.get_logger().info(f"initialised from {stream} at {stamp * 1e-9:.3f} s")
        self._publish(stamp, self.engine.mean, self.engine.cov, update=False)

    def _on_reset(self, request, response):
        self.engine.reset()
        self._last_published_ns = None
        response.success = True
        response.message = ("filter reset; it re-initialises from " +
                             (self.engine.init_source or "set_pose or the next measurements"))
        self.get_logger().info(response.message)
        return response

    # --- outputs ---------------------------------------------------------------------------------------
    def _publish(self, stamp: int, mean: np.ndarray, cov: np.ndarray, update: bool) -> None:
        if mean is None or not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            return
        p = self.params
        self.odom_pub.publish(conv.odometry_msg(mean, cov, stamp, p["world_frame"], p["base_frame"],
                                                self.model.position_index, self.model.velocity_index))
        self._last_published_ns = stamp if self._last_published_ns is None else max(stamp, self._last_published_ns)
        if not update:
            return
        f = self.engine.filter
        stats = self.engine.filter_stats()
        if "ess" in stats and math.isfinite(stats["ess"]):
            self.ess_pub.publish(Float64(data=stats["ess"]))
        if "unmodelled_acceleration" in stats:
            self.acceleration_pub.publish(conv.vector3_stamped(stats["unmodelled_acceleration"], stamp,
                                                               p["world_frame"]))
        if self.engine.has_costate:
            lam = np.asarray(f.costate_mean, dtype=float)
            if np.all(np.isfinite(lam)):
                self.costate_pub.publish(conv.vector3_stamped(lam, stamp, p["measurement_frame"] or p["world_frame"]))
        k = p["max_published_particles"]
        if k > 0 and hasattr(f, "particles") and self.particles_pub.get_subscription_count() > 0:
            particles = np.asarray(f.particles)
            weights = getattr(f, "weights", None)
            if weights is None:
                weights = np.full(particles.shape[0], 1.0 / particles.shape[0])
            chosen = particles[conv.decimate(particles, np.asarray(weights), k)][:, list(self.model.position_index)]
            chosen = chosen[np.all(np.isfinite(chosen), axis=1)]
            self.particles_pub.publish(conv.pose_array_msg(chosen, stamp, p["world_frame"]))

    def _on_publish_timer(self) -> None:
        now = self._now_ns()
        if not now:
            return
        if now < self._last_now_ns - 1_000_000_000:
            self.get_logger().warning(f"node clock jumped back from {self._last_now_ns * 1e-9:.3f} s to "
                                      f"{now * 1e-9:.3f} s: resetting the filter")
            self.engine.reset()
            self._last_published_ns = None
        self._last_now_ns = now
        if not self.engine.initialized:
            return
        if self._last_published_ns is not None and now <= self._last_published_ns:
            return
        est = self.engine.extrapolate(now)
        if est is not None:
            self._publish(now, est[0], est[1], update=False)

    def _on_diagnostics_timer(self) -> None:
        now = self._now_ns()
        level, message, values = diag.filter_status(self.engine, now, self.thresholds, self.filter_name,
                                                    uptime=time.monotonic() - self._started)
        self.diag_pub.publish(diag.to_msg(level, message, values, conv.ns_to_stamp(now),
                                          hardware_id=self.get_fully_qualified_name()))
        if not self.engine.initialized:
            t = time.monotonic()
            if t - self._last_log.get("_not_initialized", -math.inf) >= LOG_THROTTLE:
                self._last_log["_not_initialized"] = t
                self.get_logger().warning(f"filter not initialised: no odometry yet; {self.engine.waiting_for()}")


def _positive_definite(cov: np.ndarray) -> np.ndarray | None:
    """``cov`` if it is positive definite, else None (not given, or unusable: ``initial_std`` applies)."""
    if not np.any(cov) or np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() <= 0.0:
        return None
    return cov


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
