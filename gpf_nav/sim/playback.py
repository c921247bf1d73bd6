"""The simulator's event schedule, without ROS: which message goes out at which simulated time.

:func:`build_events` turns a :class:`gpf_nav.sim.scenario.Scenario` into a time-ordered list of
:class:`Event` (times in integer nanoseconds from the trajectory start):

* ``measurement`` at every ``scenario.times[k]`` whose vector is not entirely NaN (a dropout is a lost
  message; a partially NaN vector goes out with its NaNs: "not measured");
* ``truth`` at the start, every measurement time and every ``1 / truth_rate`` s, the state between
  truth samples by cubic Hermite interpolation of positions and velocities;
* ``imu`` every ``1 / imu_rate`` s: the specific force held over the scenario step that contains the
  time, plus white noise of ``imu_noise_std`` per axis from a stream seeded by ``seed``;
* ``station`` at every ``scenario.times[k]`` at which a surface station (its name the event's ``frame``)
  sees the vehicle (:func:`gpf_nav.sim.surface_stations.surface_measurements`), one event per station;
* with a sensor suite (:func:`gpf_nav.sim.sensor_suite.generate_suite`): ``altitude`` and ``velocity`` at
  the times they measure, and ``position`` (a TRN fix) released at its arrival time, ``delay_ns`` after
  its capture, which is its stamp.

At equal times the order is measurement, station (in the table's order), altitude, velocity, position, truth, imu, so an estimator that applies the latest IMU sample
stamped strictly before a measurement uses the force of the step that measurement closes.
Same inputs and seed, same events.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NS = 1_000_000_000
_ORDER = {"measurement": 0, "station": 1, "altitude": 2, "velocity": 3, "position": 4, "truth": 5, "imu": 6}


@dataclass(frozen=True)
class Event:
    t_ns: int                 # from the trajectory start, when the message goes out
    kind: str                 # measurement | station | truth | imu | altitude | velocity | position
    data: tuple[float, ...]   # (range, az, el) | (x, y, z, vx, vy, vz) | (ax, ay, az) | (h,) | (vx, vy, vz) | (x, y, z)
    delay_ns: int = 0         # the message is stamped this long before it goes out (TRN latency)
    frame: str = ""           # station: the station's name (the message's header.frame_id)


def _grid(span_ns: int, rate: float) -> np.ndarray:
    if rate <= 0.0:
        return np.zeros(0, dtype=np.int64)
    period = int(round(NS / rate))
    return np.arange(0, span_ns + 1, period, dtype=np.int64)


def hermite_state(t0: float, x0: np.ndarray, t1: float, x1: np.ndarray, t: float) -> np.ndarray:
    """State ``(6,)`` at ``t`` in ``[t0, t1]`` from the cubic Hermite spline of positions/velocities."""
    h = t1 - t0
    s = (t - t0) / h
    p0, v0, p1, v1 = x0[:3], x0[3:] * h, x1[:3], x1[3:] * h
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
    pos = h00 * p0 + h10 * v0 + h01 * p1 + h11 * v1
    vel = (d00 * p0 + d10 * v0 + d01 * p1 + d11 * v1) / h
    return np.concatenate([pos, vel])


def build_events(scenario, imu_rate: float, imu_noise_std: float, truth_rate: float,
                 seed: int, suite=None, stations: dict[str, np.ndarray] | None = None) -> list[Event]:
    """The time-ordered events of ``scenario``, of ``suite`` (a :class:`gpf_nav.sim.sensor_suite.SuiteData`
    of it, or None) and of ``stations`` (``{name: (K, 3)}`` of
    :func:`gpf_nav.sim.surface_stations.surface_measurements`, or None) (see the module docstring)."""
    t_truth = np.concatenate([[scenario.start_time], scenario.times]) - scenario.start_time
    t_truth_ns = np.round(t_truth * NS).astype(np.int64)
    span_ns = int(t_truth_ns[-1])
    events: list[Event] = []
    for k, t in enumerate(t_truth_ns[1:]):
        y = scenario.measurements[k]
        if np.any(np.isfinite(y)):
            events.append(Event(int(t), "measurement", tuple(float(v) for v in y)))
    truth_times = np.union1d(t_truth_ns, _grid(span_ns, truth_rate))
    idx = np.clip(np.searchsorted(t_truth_ns, truth_times, side="right") - 1, 0, len(t_truth_ns) - 2)
    for t, k in zip(truth_times.tolist(), idx.tolist()):
        if t == t_truth_ns[k]:
            state = scenario.truth[k]
        elif t == t_truth_ns[k + 1]:
            state = scenario.truth[k + 1]
        else:
            state = hermite_state(t_truth[k], scenario.truth[k], t_truth[k + 1], scenario.truth[k + 1],
                                  t * 1e-9)
        events.append(Event(int(t), "truth", tuple(float(v) for v in state)))
    imu_times = _grid(span_ns, imu_rate)
    noise = np.random.default_rng(np.random.SeedSequence([int(seed), 0x1A0])).standard_normal(
        (len(imu_times), 3)) * imu_noise_std
    step = np.clip(np.searchsorted(t_truth_ns, imu_times, side="right") - 1, 0,
                   len(scenario.specific_force) - 1)
    for t, k, w in zip(imu_times.tolist(), step.tolist(), noise):
        force = scenario.specific_force[k] + w
        events.append(Event(int(t), "imu", tuple(float(v) for v in force)))
    if suite is not None:
        events += suite_events(scenario, suite)
    for name, values in (stations or {}).items():
        for k in np.flatnonzero(np.all(np.isfinite(values), axis=1)).tolist():
            events.append(Event(int(t_truth_ns[k + 1]), "station", tuple(float(v) for v in values[k]), frame=name))
    events.sort(key=lambda e: (e.t_ns, _ORDER[e.kind]))
    return events


def suite_events(scenario, suite) -> list[Event]:
    """``altitude``, ``velocity`` and ``position`` events of ``suite`` (rows with a measurement only)."""
    t_ns = np.round((scenario.times - scenario.start_time) * NS).astype(np.int64)
    events = []
    for kind, values in (("altitude", suite.altitude), ("velocity", suite.velocity), ("position", suite.position)):
        for k in np.flatnonzero(np.all(np.isfinite(values), axis=1)).tolist():
            delay = 0
            if kind == "position":
                delay = int(round((suite.position_arrival[k] - scenario.times[k]) * NS))
            events.append(Event(int(t_ns[k]) + delay, kind, tuple(float(v) for v in values[k]), delay))
    return events
