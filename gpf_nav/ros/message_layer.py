"""The estimator node's work between a received message and the messages it publishes, without a node.

:class:`MessageLayer` builds the model, filter and :class:`gpf_nav.estimator.engine.EstimatorEngine` from the
node's parameters, applies the message-level checks of :mod:`gpf_nav.estimator.input_checks`, feeds the engine,
and hands every output message to a ``publish(topic, msg)`` callable. The node clock comes in as
``now_ns`` with each call. Two drivers:

* ``estimator_node`` (subscriptions, timers on the node clock, publishers);
* ``gpf-nav replay`` (:mod:`gpf_nav.bags.replay`): messages from a rosbag2 bag, the node clock being each
  message's recording time.

So both apply the same parameters, checks, counters and outputs. Every measurement stream of
:data:`gpf_nav.estimator.streams.STREAMS` takes one path: header (stamp, frame), the conversion of its
message type (:mod:`gpf_nav.ros.stream_messages`), the stream's checks, its sensor. Topic names are the
node's (relative: resolved in the node's namespace), in :attr:`MessageLayer.inputs` (for the shipped
streams :data:`INPUT_TOPICS`) and :data:`OUTPUT_TOPICS`.
"""
from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu
from std_msgs.msg import Float64

from gpf_nav.ros import conversions as conv
from gpf_nav.ros import diagnostics as diag
from gpf_nav.ros.processing_time import ProcessingTime
from gpf_nav.estimator import input_checks as val
from gpf_nav.estimator.engine import EngineConfig, EstimatorEngine
from gpf_nav.estimator.factory import make_filter, make_lunar_model
from gpf_nav.estimator.params import ParameterError, check_estimator_parameters, filter_options
from gpf_nav.estimator.sensor_setup import build_sensors, gates, with_biases
from gpf_nav.estimator.stations import MoonFrames, station_sensors
from gpf_nav.estimator.streams import STREAMS, Reading, Stream
from gpf_nav.estimator.warm_up import warm_up
from gpf_nav.filters.interface import CLOUD
from gpf_nav.integrity.consistency import WARN_FALSE_ALARM_RATE
from gpf_nav.ros.stream_messages import MESSAGE_TYPES
from gpf_nav.sensors.station import StationSensor
from gpf_nav.sim.scenario import ScenarioConfig, initial_state

LOG_THROTTLE = 5.0  # s (wall clock) between two log lines about the same refusal reason
TIME_JUMP_NS = 1_000_000_000
"""A node clock that goes back by more than this (ns) between two calls has jumped (a restarted simulator or bag)."""

CONTROL_TOPICS = {"imu": ("imu", Imu), "set_pose": ("set_pose", PoseWithCovarianceStamped),
                  "set_state": ("set_state", Odometry)}
"""topic -> (name used in the counters, message type) of the inputs that are not measurements."""


def input_topics(streams: list[Stream]) -> dict[str, tuple[str, type]]:
    """topic -> (stream name used in the counters, message type): the measurement streams, then
    :data:`CONTROL_TOPICS`."""
    return {**{s.topic: (s.name, MESSAGE_TYPES[s.message].cls) for s in streams}, **CONTROL_TOPICS}


INPUT_TOPICS = input_topics(STREAMS)
"""The inputs of the shipped stream table (:data:`gpf_nav.estimator.streams.STREAMS`)."""

OUTPUT_TOPICS = {"odometry/filtered": Odometry, "gpf/ess": Float64, "gpf/costate": Vector3Stamped,
                 "gpf/unmodelled_acceleration": Vector3Stamped, "gpf/particles": PoseArray,
                 "/diagnostics": DiagnosticArray}

_WARMED: set = set()
"""The filter configurations :meth:`MessageLayer.warm_up` ran in this process (its kernels are loaded)."""


def monitor_options(p: dict) -> dict | None:
    """``CostateMonitor`` keyword arguments from the node parameters (None when disabled)."""
    if not p["monitor_enabled"]:
        return None
    return dict(window=p["monitor_window"], reference=p["monitor_reference"],
                min_reference=p["monitor_min_reference"], gap=p["monitor_gap"],
                false_alarm_rate=p["monitor_false_alarm_rate"],
                warn_false_alarm_rate=p["monitor_warn_false_alarm_rate"],
                quarantine_rate=None if p["monitor_quarantine_rate"] < 0 else p["monitor_quarantine_rate"])


def consistency_options(p: dict) -> dict | None:
    """``ConsistencyMonitor`` keyword arguments from the node parameters (None when disabled); its WARN
    level is not reported, so its rate only has to be valid."""
    if not p["consistency_enabled"]:
        return None
    rate = p["consistency_false_alarm_rate"]
    return dict(window=p["consistency_window"], false_alarm_rate=rate,
                warn_false_alarm_rate=max(rate, WARN_FALSE_ALARM_RATE))


class MessageLayer:
    """The estimator's message handling. Raises :class:`ParameterError` on invalid parameters.

    Args:
        params: the estimator's parameter values (``gpf_nav.estimator.params.ESTIMATOR`` names).
        publish: ``publish(topic, msg)``, topic one of :data:`OUTPUT_TOPICS`.
        logger: anything with ``info``, ``warning`` and ``error`` methods taking one string.
        monotonic: steady clock [s] of the engine (rate limit, ERROR and alarm holds).
        wants_particles: True when ``gpf/particles`` has a reader (it costs a decimation per update).
    """

    def __init__(self, params: dict, publish: Callable[[str, object], None], logger,
                 monotonic: Callable[[], float] = time.monotonic,
                 wants_particles: Callable[[], bool] = lambda: False):
        p = self.params = params
        self.streams = {s.name: s for s in STREAMS}
        self.inputs = input_topics(STREAMS)
        errors = check_estimator_parameters(p)
        if errors:
            raise ParameterError("invalid parameters: " + "; ".join(errors))
        try:
            self.model = make_lunar_model(mu=p["mu"], station=p["station"],
                                          range_noise_std=p["range_noise_std"],
                                          angle_noise_std=p["angle_noise_std"],
                                          accel_noise_density=p["accel_noise_density"],
                                          max_step=p["max_step"], gravity_field=p["gravity_field"],
                                          gravity_epoch=p["moon_epoch"])
            self.sensors = build_sensors(p, self.model, STREAMS)
            self.stations = station_sensors(p, self.model)
            self.frames = MoonFrames.from_parameters(p)
            factory = with_biases(lambda m: make_filter(p["filter"], m, **filter_options(p)), self.model,
                                  self.sensors)
            factory()
        except ValueError as err:
            raise ParameterError(f"invalid parameters: {err}") from None
        self.filter_name = p["filter"]
        config = EngineConfig(
            max_future=p["max_future"], imu_timeout=p["imu_timeout"], init_window=p["init_window"],
            initial_state=None if p["initial_state"] is None else np.array(p["initial_state"]),
            initial_std=np.array(p["initial_std"]), initial_stamp=p["initial_stamp"],
            max_measurement_rate=p["max_measurement_rate"], max_extrapolation=p["max_extrapolation"],
            reinit_hold=p["reinit_hold"], monitor=monitor_options(p), monitor_hold=p["monitor_hold"],
            consistency=consistency_options(p),
            history_length=p["history_length"], reapply_budget=p["reapply_budget"], gates=gates(p, STREAMS),
            gate_limit=p["gate_limit"], fault_action=p["integrity_fault_action"],
            fault_updates=p["integrity_fault_updates"])
        self.engine = EstimatorEngine(factory, self.model, config, monotonic=monotonic)
        self.thresholds = diag.Thresholds(ess_warn=p["ess_warn_threshold"],
                                          costate_warn=p["costate_warn_threshold"],
                                          sensor_timeout=p["sensor_timeout"])
        self.publish = publish
        self.logger = logger
        self.wants_particles = wants_particles
        self._handlers = {"imu": self._on_imu, "set_pose": self._on_set_pose, "set_state": self._on_set_state}
        self._last_log: dict[str, float] = {}
        self._unknown_stations: set[str] = set()
        self._integrity_level = "OK"
        self._last_published_ns: int | None = None
        self._last_now_ns = 0
        self.processing = ProcessingTime()   # wall time per measurement message, per diagnostics period
        self.time_jumps = 0                   # backward jumps of the node clock seen

    def describe(self) -> str:
        """One line: filter, N (particles or ensemble members, when it has them), world frame and where the
        initial state comes from."""
        p = self.params
        size = f"N={p['n_particles']}, " if CLOUD in self.engine.filter.capabilities else ""
        return (f"{self.filter_name} estimator up: {size}world_frame={p['world_frame']}, "
                f"initialisation from " + ("parameters" if p["initial_state"] is not None else
                                           f"set_state, set_pose or the first {p['init_window']} "
                                           "measurements"))

    def warm_up(self) -> tuple[bool, str]:
        """Load (or compile) the filter's kernels before the first message (:mod:`gpf_nav.estimator.warm_up`),
        from the ``initial_state`` parameter or the Section 7 start; once per process and filter
        configuration. False and why when it failed (the first update then waits for the kernels), and
        one line saying what happened."""
        p = self.params
        key = (self.filter_name, tuple(sorted((name, tuple(value) if isinstance(value, list) else value)
                                              for name, value in filter_options(p).items())))
        if key in _WARMED:
            return True, "warm-up: this filter configuration already ran in this process"
        state = initial_state(ScenarioConfig()) if p["initial_state"] is None else np.array(p["initial_state"])
        seconds, error = warm_up(self.engine, state)
        if error:
            return False, f"warm-up failed after {seconds:.1f} s ({error}): the first update may wait for the kernels"
        _WARMED.add(key)
        return True, f"warm-up: the filter's kernels ready in {seconds:.1f} s"

    # --- inputs ----------------------------------------------------------------------------------------
    def handle(self, stream: str, msg, now_ns: int) -> None:
        """Process one message of ``stream`` (a name of :attr:`inputs`)
        received at node time ``now_ns``. An unexpected exception is counted (``internal_error``) and
        logged, never raised."""
        self._watch_clock(now_ns)
        try:
            if stream in self.streams:
                started = self.processing.start()
                self._on_measurement(self.streams[stream], msg, now_ns)
                self.processing.stop(started)
            else:
                self._handlers[stream](msg, now_ns)
        except Exception as err:  # noqa: BLE001 - the last-resort net: the estimator goes on
            self._refuse(stream, "internal_error", f"{type(err).__name__}: {err}")

    def reset(self) -> str:
        """Back to the start-up state (the ``~/reset`` service); returns what it re-initialises from."""
        self.engine.reset()
        self._last_published_ns = None
        return "filter reset; it re-initialises from " + (self.engine.init_source or
                                                          "set_pose or the next measurements")

    def _throttled(self, key: str) -> bool:
        now = time.monotonic()
        if now - self._last_log.get(key, -math.inf) < LOG_THROTTLE:
            return False
        self._last_log[key] = now
        return True

    def _refuse(self, stream: str, reason: str, detail: str, counted: bool = False) -> None:
        """Count (unless the engine did) and log, at most once per LOG_THROTTLE s per reason."""
        c = self.engine.counters
        n = c.rejected[reason] if counted else c.reject(stream, reason)
        if self._throttled(reason):
            self.logger.warning(f"dropped {stream} message: {reason}: {detail} ({n} so far)")

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

    def _timing_detail(self, stamp_ns: int, now_ns: int) -> str:
        last = self.engine.last_measurement_ns
        return (f"stamp {stamp_ns * 1e-9:.3f} s, last processed "
                f"{'none' if last is None else f'{last * 1e-9:.3f} s'}, node clock {now_ns * 1e-9:.3f} s")

    def _on_measurement(self, stream: Stream, msg, now_ns: int) -> None:
        """A message of a measurement stream: header, conversion, the stream's checks, its sensor (a
        station stream's: the station its frame names; a position in a Moon frame: turned into world_frame)."""
        frame = self.params[stream.frame]
        header = msg.header
        stamp = self._check_header(stream.name, header, "" if stream.station or stream.moon_frames else frame)
        if stamp is None:
            return
        station = None
        if stream.station:
            known, station = self._station(stream.name, header.frame_id, frame)
            if not known:
                return
        elif stream.moon_frames and header.frame_id not in self.frames.names:
            self._refuse(stream.name, "wrong_frame", f"frame_id '{header.frame_id}', expected one of "
                                                     f"{', '.join(self.frames.names)}")
            return
        reading = MESSAGE_TYPES[stream.message].reading(msg)
        ok, reason = stream.check(reading)
        if not ok:
            self._refuse(stream.name, reason, reading.describe())
            return
        if stream.moon_frames and header.frame_id != self.frames.world:
            reading = Reading(*self.frames.position_to_world(header.frame_id, reading.values, reading.covariance,
                                                             stamp * 1e-9))
        sensor = station or self.sensors[stream.name]
        y = stream.measurement(reading, sensor.dim)
        if stream.noise_from_message:
            sensor = sensor.with_noise(reading.covariance)
        model_measurement = stream.model_measurement and station is None
        self._measurement(stream.name, stamp, y, now_ns, None if model_measurement else sensor)

    def _station(self, stream: str, frame_id: str, default: str) -> tuple[bool, StationSensor | None]:
        """``(known, sensor)`` of the station ``frame_id`` names: a station of the tables, or None for
        ``default``'s (the model's own measurement; ``default`` '' takes any other name). An unknown name
        is refused (``unknown_station``, or ``wrong_frame`` with no station table), logged once per name."""
        if frame_id in self.stations:
            return True, self.stations[frame_id]
        if not default or frame_id == default:
            return True, None
        if not self.stations:
            self._refuse(stream, "wrong_frame", f"frame_id '{frame_id}', expected '{default}'")
            return False, None
        n = self.engine.counters.reject(stream, "unknown_station")
        if frame_id not in self._unknown_stations:
            self._unknown_stations.add(frame_id)
            self.logger.warning(f"dropped {stream} message: unknown_station: frame_id '{frame_id}' names no "
                                f"station (measurement_frame '{default}', stations "
                                f"{', '.join(sorted(self.stations))}) ({n} so far)")
        return False, None

    def _measurement(self, stream: str, stamp: int, y: np.ndarray, now_ns: int, sensor=None) -> None:
        engine = self.engine
        was_initialized, fault_reinits = engine.initialized, engine.fault_reinit_count
        ok, reason = engine.measurement(stamp, y, now_ns, stream, sensor)
        if engine.fault_reinit_count > fault_reinits:
            self.logger.warning(f"{engine.last_reinit_reason} at {stamp * 1e-9:.3f} s "
                                f"({engine.fault_reinit_count} so far; integrity_fault_action)")
        elif ok and not reason and not was_initialized:
            self.logger.info(f"initialised from {engine.init_source} at {engine.t_ns * 1e-9:.3f} s")
        if not ok:
            if reason == "filter_error":
                self.logger.error(f"filter re-initialised from the last good estimate: "
                                  f"{self.engine.last_reinit_reason}")
            self._refuse(stream, reason, self._timing_detail(stamp, now_ns), counted=True)
            return
        if reason == "buffered":
            return
        self._publish(self.engine.t_ns, self.engine.mean, self.engine.cov, update=True)  # late: t_ns > stamp
        self._log_integrity(stamp)

    def _log_integrity(self, stamp: int) -> None:
        """A WARN log line when the monitor goes to FAULT (at most once per LOG_THROTTLE s)."""
        monitor = self.engine.monitor
        level = monitor.level if monitor is not None else "OK"
        previous, self._integrity_level = self._integrity_level, level
        if level != "FAULT" or previous == "FAULT" or not self._throttled("_integrity"):
            return
        s = monitor.status
        self.logger.warning(
            f"integrity FAULT at {stamp * 1e-9:.3f} s: the mean co-state is biased (T^2 {s.statistic:.4g} > "
            f"{s.threshold:.4g}, p = {s.p_value:.2g}): the model, the sensors or the filter disagree with the data")

    def _on_imu(self, msg: Imu, now_ns: int) -> None:
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
        ok, reason = self.engine.imu(stamp, conv.imu_specific_force(msg), now_ns)
        if not ok:
            self._refuse("imu", reason, self._timing_detail(stamp, now_ns), counted=True)

    def _on_set_pose(self, msg: PoseWithCovarianceStamped, now_ns: int) -> None:
        stamp = self._check_header("set_pose", msg.header, self.params["world_frame"])
        if stamp is None:
            return
        if stamp == 0:
            stamp = now_ns
        pos = msg.pose.pose.position
        cov = conv.position_covariance(msg.pose.covariance)
        ok, reason = val.check_finite(pos.x, pos.y, pos.z, *cov.reshape(-1))
        if not ok:
            self._refuse("set_pose", reason, f"position ({pos.x}, {pos.y}, {pos.z}) or covariance")
            return
        ok, reason = self.engine.set_pose(stamp, np.array([pos.x, pos.y, pos.z]), _positive_definite(cov), now_ns)
        self._initialized_from("set_pose", stamp, ok, reason, now_ns)

    def _on_set_state(self, msg: Odometry, now_ns: int) -> None:
        stamp = self._check_header("set_state", msg.header, self.params["world_frame"])
        if stamp is None:
            return
        if stamp == 0:
            stamp = now_ns
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
        ok, reason = self.engine.set_state(stamp, mean, cov, now_ns)
        self._initialized_from("set_state", stamp, ok, reason, now_ns)

    def _initialized_from(self, stream: str, stamp: int, ok: bool, reason: str, now_ns: int) -> None:
        if not ok:
            self._refuse(stream, reason, self._timing_detail(stamp, now_ns), counted=True)
            return
        self.logger.info(f"initialised from {stream} at {stamp * 1e-9:.3f} s")
        # at the filter's time: later than stamp when measurements buffered before it were then applied
        self._publish(self.engine.t_ns, self.engine.mean, self.engine.cov, update=False)

    # --- outputs ---------------------------------------------------------------------------------------
    def _publish(self, stamp: int, mean: np.ndarray, cov: np.ndarray, update: bool) -> None:
        if mean is None or not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            return
        p = self.params
        self.publish("odometry/filtered", conv.odometry_msg(mean, cov, stamp, p["world_frame"], p["base_frame"],
                                                            self.model.position_index, self.model.velocity_index))
        self._last_published_ns = stamp if self._last_published_ns is None else max(stamp, self._last_published_ns)
        if not update:
            return
        f = self.engine.filter
        stats = self.engine.filter_stats()
        if "ess" in stats and math.isfinite(stats["ess"]):
            self.publish("gpf/ess", Float64(data=stats["ess"]))
        if "unmodelled_acceleration" in stats:
            self.publish("gpf/unmodelled_acceleration",
                         conv.vector3_stamped(stats["unmodelled_acceleration"], stamp, p["world_frame"]))
        if self.engine.has_costate:
            lam = np.asarray(f.costate_mean, dtype=float)
            if np.all(np.isfinite(lam)):
                self.publish("gpf/costate",
                             conv.vector3_stamped(lam, stamp, p["measurement_frame"] or p["world_frame"]))
        k = p["max_published_particles"]
        if k > 0 and CLOUD in f.capabilities and self.wants_particles():
            particles = np.asarray(f.particles)
            weights = f.weights
            if weights is None:
                weights = np.full(particles.shape[0], 1.0 / particles.shape[0])
            chosen = particles[conv.decimate(particles, np.asarray(weights), k)][:, list(self.model.position_index)]
            chosen = chosen[np.all(np.isfinite(chosen), axis=1)]
            self.publish("gpf/particles", conv.pose_array_msg(chosen, stamp, p["world_frame"]))

    def frame_transforms(self, stamp_ns: int) -> list:
        """``geometry_msgs/TransformStamped`` of world_frame -> moon_fixed_frame -> site_frame at ``stamp_ns``
        (:meth:`gpf_nav.estimator.stations.MoonFrames.transforms`), published on TF with each odometry."""
        return [conv.transform_msg(parent, child, stamp_ns, translation, R)
                for parent, child, translation, R in self.frames.transforms(stamp_ns * 1e-9)]

    def publish_tick(self, now_ns: int) -> None:
        """The ``publish_rate`` timer: predicted odometry at ``now_ns`` (and a reset if the clock jumped back)."""
        if not now_ns:
            return
        self._watch_clock(now_ns)
        if not self.engine.initialized:
            return
        if self._last_published_ns is not None and now_ns <= self._last_published_ns:
            return
        est = self.engine.extrapolate(now_ns)
        if est is not None:
            self._publish(now_ns, est[0], est[1], update=False)

    def _watch_clock(self, now_ns: int) -> None:
        """Reset the filter (``reset_on_time_jump``) when the node clock went back by more than
        :data:`TIME_JUMP_NS` since the last call; every input and timer tick calls this, so a jump is seen
        at the first of them after it, whatever ``publish_rate``. Counted in ``time_jumps``."""
        if not now_ns:  # a simulated clock that has not ticked yet
            return
        last, self._last_now_ns = self._last_now_ns, now_ns
        if now_ns >= last - TIME_JUMP_NS:
            return
        self.time_jumps += 1
        jump = f"node clock jumped back from {last * 1e-9:.3f} s to {now_ns * 1e-9:.3f} s"
        if not self.params["reset_on_time_jump"]:
            self.logger.warning(f"{jump} ({self.time_jumps} so far); reset_on_time_jump is false: the filter "
                                "keeps its state and refuses the stamps before it")
            return
        self.engine.reset()
        self._last_published_ns = None
        self.logger.warning(f"{jump}: filter reset ({self.time_jumps} so far); it re-initialises from "
                            + (self.engine.init_source or "set_state, set_pose or the next measurements"))

    def diagnostics_tick(self, now_ns: int, uptime: float, hardware_id: str) -> tuple[int, str]:
        """The ``diagnostics_period`` timer: publish ``/diagnostics``; returns ``(level, message)``."""
        self._watch_clock(now_ns)
        level, message, values = diag.filter_status(self.engine, now_ns, self.thresholds, self.filter_name,
                                                    uptime=uptime)
        values.append(("node clock jumps back", str(self.time_jumps)))
        values += self.processing.period_values()
        self.publish("/diagnostics", diag.to_msg(level, message, values, conv.ns_to_stamp(now_ns),
                                                 hardware_id=hardware_id))
        if not self.engine.initialized and self._throttled("_not_initialized"):
            self.logger.warning(f"filter not initialised: no odometry yet; {self.engine.waiting_for()}")
        if self.engine.imu_silent(now_ns) and self._throttled("_imu_silent"):
            self.logger.warning(f"no IMU sample for {self.engine.imu_age(now_ns):.1f} s (imu_timeout "
                                f"{self.engine.config.imu_timeout:g} s): predicting without input")
        return level, message


def _positive_definite(cov: np.ndarray) -> np.ndarray | None:
    """``cov`` if it is positive definite, else None (not given, or unusable: ``initial_std`` applies)."""
    if not np.any(cov) or np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() <= 0.0:
        return None
    return cov
