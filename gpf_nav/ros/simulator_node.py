"""``ros2 run gpf_nav simulator``: the lunar-descent scenario played out on ROS topics.

Generates the truth with the core scenario generator (or replays a CSV truth, parameter
``truth_csv``) and publishes, in simulated time, ``measurements/rae``, ``imu``, ``truth/odometry`` and
``/clock``; with ``publish_suite`` also the sensor suite of :mod:`gpf_nav.sim.sensor_suite` (``suite.*``):
``measurements/altitude``, ``measurements/velocity`` and ``measurements/position`` (TRN fixes published
``suite.trn_latency`` s after their stamp, the image capture); with ``station_names`` also
``measurements/rae`` from each surface station that sees the vehicle, named in ``header.frame_id``
(:mod:`gpf_nav.sim.surface_stations`). A wall-clock loop at ``clock_rate`` Hz advances simulated time by
``rate_factor`` times the elapsed wall time, publishes ``/clock`` and releases every event of
:mod:`gpf_nav.sim.playback` due by then, with the event's own stamp; so message contents never depend on timing: same seed, same
messages. By default simulated time starts at the wall-clock time (``start_time`` negative), so at
``rate_factor`` 1 an estimator on the wall clock accepts the stamps, and the mission's prior is handed
over on ``set_state`` (latched) when the trajectory starts. See ``docs/ros.md``.
"""
from __future__ import annotations

import sys
import time

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped, TwistWithCovarianceStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import Imu, Range

from gpf_nav.ros import conversions as conv
from gpf_nav.ros import shutdown
from gpf_nav.schema import ParameterError
from gpf_nav.ros.parameters import declare, params_files, warn_undeclared, warn_unmatched_params_files
from gpf_nav.sim.playback import NS, build_events
from gpf_nav.sim.simulator_params import check_simulator_parameters, simulator_specs

NODE_NAME = "lunar_simulator"


def scenario_from_parameters(p: dict):
    """``(ScenarioConfig, Scenario)`` from the simulator's parameters (generated or CSV replay)."""
    from gpf_nav.sim.scenario import ScenarioConfig, generate, load_csv
    fields = {k[len("scenario."):]: v for k, v in p.items() if k.startswith("scenario.")}
    if not fields.get("thrust"):
        fields["thrust"] = None
    config = ScenarioConfig.from_dict(fields)
    if p["truth_csv"]:
        return config, load_csv(p["truth_csv"], config, p["seed"])
    return config, generate(config, p["seed"])


EVENT_TOPICS = {"measurement": ("measurements/rae", Vector3Stamped),
                "station": ("measurements/rae", Vector3Stamped), "truth": ("truth/odometry", Odometry),
                "imu": ("imu", Imu), "altitude": ("measurements/altitude", Range),
                "velocity": ("measurements/velocity", TwistWithCovarianceStamped),
                "position": ("measurements/position", PoseWithCovarianceStamped)}
"""Event kind of :mod:`gpf_nav.sim.playback` -> (topic, message type); ``/clock`` besides."""
QOS_DEPTH = 1000
"""Depth of the simulator's reliable publishers (all topics, ``/clock`` too): a subscriber stalled for
seconds at a high ``rate_factor`` (a busy machine) receives every message late rather than losing some."""
HANDOVER_TOPIC = "set_state"
"""The topic of the mission's prior (:func:`handover_message`), latched: transient local, depth 1."""


def suite_from_parameters(scenario, p: dict):
    """The :class:`gpf_nav.sim.sensor_suite.SuiteData` of ``scenario`` (seed ``p["seed"]``), or None unless
    ``publish_suite``. ValueError for invalid ``suite.*`` values."""
    if not p["publish_suite"]:
        return None
    from gpf_nav.sim.sensor_suite import SuiteConfig, generate_suite
    config = SuiteConfig.from_dict({k[len("suite."):]: v for k, v in p.items() if k.startswith("suite.")})
    config.check_grid(scenario.config.dt)
    return generate_suite(scenario, config, p["seed"])


def stations_from_parameters(scenario, p: dict, start_stamp: float) -> dict | None:
    """``{name: (K, 3)}`` of :func:`gpf_nav.sim.surface_stations.surface_measurements` for the surface stations
    of ``p`` (checked by :func:`check_simulator_parameters`) with the trajectory starting at stamp
    ``start_stamp`` s, or None without any."""
    if not p["station_names"]:
        return None
    from gpf_nav.sim.surface_stations import surface_measurements
    table = np.reshape(p["station_lat_lon_height"], (-1, 3)).tolist()
    return surface_measurements(scenario, dict(zip(p["station_names"], table)), p["moon_epoch"], start_stamp,
                                p["seed"])


def events_from_parameters(scenario, p: dict, start_stamp: float) -> list:
    """The playback events of ``scenario`` (its sensor suite and surface stations) for simulator parameters
    ``p``, the trajectory starting at stamp ``start_stamp`` s."""
    return build_events(scenario, p["imu_rate"], p["imu_noise_std"], p["truth_rate"], p["seed"],
                        suite_from_parameters(scenario, p), stations_from_parameters(scenario, p, start_stamp))


def _covariance6(std: float) -> np.ndarray:
    out = np.zeros((6, 6))
    out[:3, :3] = np.eye(3) * std ** 2
    return out.reshape(36)


def event_message(event, stamp_ns: int, p: dict) -> tuple[str, object]:
    """``(topic, message)`` of a playback event going out at ``stamp_ns`` (stamped ``event.delay_ns``
    earlier), with the frames of parameters ``p``."""
    stamp_ns -= event.delay_ns
    if event.kind == "altitude":
        # the instrument's limit: twice the altitude it is switched on below
        msg = Range(radiation_type=Range.INFRARED, min_range=0.0,
                    max_range=2.0 * float(p["suite.altimeter_max_altitude"]), range=float(event.data[0]))
        msg.header.stamp, msg.header.frame_id = conv.ns_to_stamp(stamp_ns), p["altimeter_frame"]
        return "measurements/altitude", msg
    if event.kind == "velocity":
        msg = TwistWithCovarianceStamped()
        msg.header.stamp, msg.header.frame_id = conv.ns_to_stamp(stamp_ns), p["world_frame"]
        lin = msg.twist.twist.linear
        lin.x, lin.y, lin.z = event.data
        msg.twist.covariance = _covariance6(p["suite.velocimeter_noise_std"])
        return "measurements/velocity", msg
    if event.kind == "position":
        msg = PoseWithCovarianceStamped()
        msg.header.stamp, msg.header.frame_id = conv.ns_to_stamp(stamp_ns), p["world_frame"]
        pos = msg.pose.pose.position
        pos.x, pos.y, pos.z = event.data
        msg.pose.pose.orientation.w = 1.0
        msg.pose.covariance = _covariance6(p["suite.trn_noise_std"])
        return "measurements/position", msg
    if event.kind == "measurement":
        return "measurements/rae", conv.vector3_stamped(event.data, stamp_ns, p["measurement_frame"])
    if event.kind == "station":
        return "measurements/rae", conv.vector3_stamped(event.data, stamp_ns, event.frame)
    if event.kind == "truth":
        return "truth/odometry", conv.odometry_msg(np.array(event.data), np.zeros((6, 6)), stamp_ns,
                                                   p["world_frame"], p["base_frame"])
    msg = Imu()
    msg.header.stamp = conv.ns_to_stamp(stamp_ns)
    msg.header.frame_id = p["imu_frame"]
    msg.orientation.w = 1.0  # body axes aligned with the world's (exactly known)
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = event.data
    var = p["imu_noise_std"] ** 2
    msg.linear_acceleration_covariance = [var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, var]
    msg.angular_velocity_covariance[0] = -1.0  # not provided
    return "imu", msg


def handover_message(scenario, stamp_ns: int, p: dict) -> Odometry:
    """The scenario's prior (mean, covariance) as handed over on ``set_state`` at ``stamp_ns``."""
    return conv.odometry_msg(scenario.prior_mean, scenario.prior_cov, stamp_ns, p["world_frame"], p["base_frame"])


class SimulatorNode(Node):
    """The ``lunar_simulator`` node. Raises :class:`ParameterError` on invalid parameters.

    Attributes:
        finished: True once the trajectory has ended and ``loop`` is false.
        trajectory_ns: trajectory time reached by the release loop in the current lap [ns] (0 before
            the start).
        published: messages published per kind (``measurement``, ``station`` (surface stations), ``imu``,
            ``truth``, ``clock``, ``handover``, ``altitude``, ``velocity``, ``position``).
    """

    def __init__(self, name: str = NODE_NAME, params_files=(), **kwargs):
        super().__init__(name, **kwargs)
        p = self.params = declare(self, simulator_specs())
        warn_undeclared(self)
        warn_unmatched_params_files(self, params_files)
        errors = check_simulator_parameters(p)
        if p["publish_clock"] and p["start_time"] >= 0.0:
            self._epoch_ns = int(round(p["start_time"] * 1e9))
        else:  # the wall-clock time when the trajectory starts
            self._epoch_ns = Clock(clock_type=ClockType.SYSTEM_TIME).now().nanoseconds + int(p["start_delay"] * NS)
        if not errors:
            try:
                self.config, self.scenario = scenario_from_parameters(p)
                self.events = events_from_parameters(self.scenario, p, self._epoch_ns * 1e-9)
            except (ValueError, OSError) as err:
                errors.append(f"scenario: {err}")
        if errors:
            raise ParameterError("invalid parameters: " + "; ".join(errors))
        self.span_ns = max(e.t_ns for e in self.events)
        self.period_ns = int(round(float(np.median(np.diff(self.scenario.times))) * NS)) \
            if len(self.scenario.times) > 1 else NS
        self.finished = False
        self.trajectory_ns = 0
        self.published = {"measurement": 0, "station": 0, "imu": 0, "truth": 0, "clock": 0, "handover": 0,
                           "altitude": 0, "velocity": 0, "position": 0}
        self._index = 0
        self._lap_offset_ns = 0
        self._handover_due = p["hand_over_prior"]
        self._wall_start = time.monotonic() + p["start_delay"]

        qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         depth=QOS_DEPTH)
        kinds = {"measurement", "truth", "imu"} | {e.kind for e in self.events}
        self._publishers_by_topic = {topic: self.create_publisher(msg_type, topic, qos)
                                     for topic, msg_type in {EVENT_TOPICS[kind] for kind in kinds}}
        self.clock_pub = self.create_publisher(ClockMsg, "/clock", qos) if p["publish_clock"] else None
        latched = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=1,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)  # an estimator started later gets it
        self.handover_pub = self.create_publisher(Odometry, HANDOVER_TOPIC, latched)
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(1.0 / p["clock_rate"], self._tick, clock=self._steady)
        n_meas = sum(e.kind == "measurement" for e in self.events)
        mean = self.scenario.prior_mean
        self.get_logger().info(
            f"lunar descent: {n_meas} measurements over {self.span_ns * 1e-9:.0f} s "
            f"(case {self.config.case}, seed {p['seed']}), rate_factor {p['rate_factor']:g}, "
            f"start at {self._epoch_ns * 1e-9:.3f} s; prior mean "
            f"[{', '.join(f'{v:.6g}' for v in mean)}]")

    def stamp_ns(self, t_ns: int) -> int:
        """ROS time of trajectory time ``t_ns`` in the current lap."""
        return self._epoch_ns + self._lap_offset_ns + t_ns

    def _tick(self) -> None:
        if self.finished:
            return
        now = time.monotonic()
        target = int((now - self._wall_start) * self.params["rate_factor"] * NS) - self._lap_offset_ns
        target = min(target, self.span_ns)
        if self.clock_pub is not None:
            self.clock_pub.publish(ClockMsg(clock=conv.ns_to_stamp(self.stamp_ns(max(target, 0)))))
            self.published["clock"] += 1
        if target < 0:
            return
        if self._handover_due:
            self._hand_over()
        self.trajectory_ns = target
        while self._index < len(self.events) and self.events[self._index].t_ns <= target:
            self._emit(self.events[self._index])
            self._index += 1
        if self._index >= len(self.events):
            self._end_of_trajectory()

    def _hand_over(self) -> None:
        """The scenario's prior, at the start of the current lap, on ``set_state``."""
        self.handover_pub.publish(handover_message(self.scenario, self.stamp_ns(0), self.params))
        self.published["handover"] += 1
        self._handover_due = False

    def _emit(self, event) -> None:
        topic, msg = event_message(event, self.stamp_ns(event.t_ns), self.params)
        self._publishers_by_topic[topic].publish(msg)
        self.published[event.kind] += 1

    def _end_of_trajectory(self) -> None:
        end = self.stamp_ns(self.span_ns)
        if self.params["loop"]:
            then = "the prior is handed over again" if self.params["hand_over_prior"] else "reset the estimator"
            self.get_logger().info(f"trajectory ended at {end * 1e-9:.3f} s; looping (the vehicle jumps back "
                                   f"to the start: {then})")
            self._lap_offset_ns += self.span_ns + self.period_ns
            self._index = 0
            self._handover_due = self.params["hand_over_prior"]
            return
        self.finished = True
        self.get_logger().info(f"trajectory ended at {end * 1e-9:.3f} s after {self.published['measurement']} "
                               "measurements; exiting (set loop: true to repeat)")


def main(argv: list[str] | None = None) -> int:
    """Console script ``simulator``: exits 0 at the end of the trajectory (unless ``loop``) and when
    stopped by SIGINT or SIGTERM (:mod:`gpf_nav.ros.shutdown`), 2 on invalid parameters."""
    argv = sys.argv if argv is None else argv
    return shutdown.run("simulator", NODE_NAME, lambda: SimulatorNode(params_files=params_files(argv)), argv,
                        done=lambda node: node.finished, linger=1.0)  # (reliable subscribers get the last messages)


if __name__ == "__main__":
    sys.exit(main())
