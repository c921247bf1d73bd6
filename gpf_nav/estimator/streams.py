"""The estimator's measurement streams as data: one :class:`Stream` per input topic (topic, message type,
frame, checks, the sensor it feeds, gate, bias, its own parameters). No ROS here.

A message becomes one :class:`Reading` (its values in SI, and the covariance or limits it carries) by the
conversion of its message type (:mod:`gpf_nav.ros.stream_messages`); the stream checks the reading, makes
the measurement vector ``y`` and names the sensor the engine updates with, as robot_localization turns
every input into one ``Measurement``. Adding a stream is one entry of :data:`STREAMS` (with a
``sensor`` builder, usually a :mod:`gpf_nav.sensors` class); its parameters (``<name>_gate``,
``<bias>_bias_std``, ``<bias>_bias_time`` and its own) join the schema (:mod:`gpf_nav.estimator.params`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from gpf_nav.estimator import input_checks as val
from gpf_nav.schema import Spec
from gpf_nav.sensors import AltitudeSensor, ModelSensor, PositionSensor, Sensor, VelocitySensor


@dataclass(frozen=True)
class Reading:
    """What one message says, in SI: ``values`` ``(k,)``, and the ``covariance`` ``(k, k)`` or the
    ``limits`` (min, max) it carries."""
    values: np.ndarray
    covariance: np.ndarray | None = None
    limits: tuple[float, float] | None = None

    def describe(self) -> str:
        """The reading as a refusal's log line gives it."""
        text = f"value {self.values.tolist()}"
        if self.limits is not None:
            text += f" with limits [{self.limits[0]}, {self.limits[1]}]"
        if self.covariance is not None:
            text += f", covariance {self.covariance.reshape(-1).tolist()}"
        return text


def check_rae(r: Reading) -> tuple[bool, str]:
    """Range, azimuth, elevation (:func:`gpf_nav.estimator.input_checks.check_rae`; NaN: not measured)."""
    return val.check_rae(*r.values)[:2]


def check_range(r: Reading) -> tuple[bool, str]:
    """A distance within the message's limits (:func:`gpf_nav.estimator.input_checks.check_range`)."""
    return val.check_range(r.values[0], *r.limits)


def check_fix(r: Reading) -> tuple[bool, str]:
    """Finite values and a symmetric positive definite covariance."""
    ok, reason = val.check_finite(*r.values)
    return val.check_covariance(r.covariance) if ok else (ok, reason)


@dataclass(frozen=True)
class BiasStates:
    """Optional bias states of a stream's sensor: parameters ``<name>_bias_std`` (0: none) and
    ``<name>_bias_time`` (0: a random constant), on the sensor components whose ``mask`` entry is 1."""
    name: str
    mask: tuple[float, ...]
    unit: str
    what: str   # "a range bias (rae and range)": the parameter's description


@dataclass(frozen=True)
class Stream:
    """One input stream of measurements.

    Attributes:
        name: the name in the counters, ``/diagnostics`` and parameter names.
        topic: the subscribed topic (relative: in the node's namespace).
        message: the ROS message type, ``package/Type`` (its conversion is in :mod:`gpf_nav.ros`).
        frame: the parameter holding the required ``header.frame_id`` ('' in it: any frame).
        check: ``check(reading) -> (ok, reason)``, reasons of :mod:`gpf_nav.estimator.input_checks`.
        sensor: ``sensor(params, model, bias) -> Sensor``; None: the stream feeds the sensor of the
            stream named ``feeds``.
        feeds: see ``sensor``.
        model_measurement: its sensor is the model's own measurement (the engine's ``sensor`` None: the
            integrity monitor watches it).
        components: the measured components of the sensor's ``y`` (the others NaN); None: all.
        noise_from_message: the sensor's noise is each message's covariance.
        gate_dof: > 0: an innovation gate (parameter ``<name>_gate``) of this many degrees of freedom.
        bias: optional bias states of its sensor.
        parameters: its own parameters (frame, noise, ...).
        station: a message names its station in ``header.frame_id``: ``frame``'s station (the model's own
            measurement) or a station of the tables (:mod:`gpf_nav.estimator.stations`), whose sensor it feeds.
        moon_frames: a message may also be in moon_fixed_frame or site_frame (a position, turned into
            world_frame; :class:`gpf_nav.estimator.stations.MoonFrames`).
    """
    name: str
    topic: str
    message: str
    frame: str
    check: Callable[[Reading], tuple[bool, str]]
    sensor: Callable[[dict, object, object], Sensor] | None = None
    feeds: str = ""
    model_measurement: bool = False
    components: tuple[int, ...] | None = None
    noise_from_message: bool = False
    gate_dof: int = 0
    bias: BiasStates | None = None
    parameters: tuple[Spec, ...] = ()
    station: bool = False
    moon_frames: bool = False

    def measurement(self, reading: Reading, dim: int) -> np.ndarray:
        """``y`` ``(dim,)`` of the sensor (of measurement dimension ``dim``) from a checked reading."""
        values = np.asarray(reading.values, dtype=float)
        if self.components is None:
            return values
        y = np.full(dim, np.nan)
        y[list(self.components)] = values
        return y


def _model_sensor(p: dict, model, bias) -> Sensor:
    return ModelSensor(model, "rae", bias=bias)


def _position(p: dict, model, bias) -> Sensor:
    return PositionSensor(1.0, bias=bias, index=tuple(model.position_index))


def _velocity(p: dict, model, bias) -> Sensor:
    return VelocitySensor(1.0, bias=bias, index=tuple(model.velocity_index))


def _altitude(p: dict, model, bias) -> Sensor:
    return AltitudeSensor(p["altitude_noise_std"], p["reference_radius"], bias=bias,
                          position_index=tuple(model.position_index))


STREAMS = [
    Stream("rae", "measurements/rae", "geometry_msgs/Vector3Stamped", "measurement_frame", check_rae,
           sensor=_model_sensor, model_measurement=True, station=True,
           bias=BiasStates("range", (1.0, 0.0, 0.0), "m", "a range bias (rae and range)")),
    Stream("range", "measurements/range", "sensor_msgs/Range", "measurement_frame", check_range, feeds="rae",
           model_measurement=True, components=(0,), station=True),
    Stream("position", "measurements/position", "geometry_msgs/PoseWithCovarianceStamped", "world_frame", check_fix,
           sensor=_position, noise_from_message=True, gate_dof=3, moon_frames=True,
           bias=BiasStates("position", (1.0, 1.0, 1.0), "m", "a bias per axis of measurements/position")),
    Stream("velocity", "measurements/velocity", "geometry_msgs/TwistWithCovarianceStamped", "world_frame", check_fix,
           sensor=_velocity, noise_from_message=True, gate_dof=3,
           bias=BiasStates("velocity", (1.0, 1.0, 1.0), "m/s", "a bias per axis of measurements/velocity")),
    Stream("altitude", "measurements/altitude", "sensor_msgs/Range", "altitude_frame", check_range,
           sensor=_altitude, gate_dof=1,
           bias=BiasStates("altitude", (1.0,), "m", "a bias of measurements/altitude"),
           parameters=(
               Spec("altitude_frame", "base_link", "Required header.frame_id of measurements/altitude ('' = any)."),
               Spec("altitude_noise_std", 20.0, "Altitude (measurements/altitude) noise standard deviation.", "m", "> 0"),
               Spec("reference_radius", 1737.4e3, "Radius of the sphere measurements/altitude is measured above (the Moon's mean radius).", "m", ">= 0"))),
]
"""Every measurement stream of the estimator, in subscription order."""


def stream_parameters(streams: list[Stream]) -> list[Spec]:
    """The parameters the streams bring: their own, their gates, their sensors' bias states."""
    specs = [spec for s in streams for spec in s.parameters]
    specs += [Spec(f"{s.name}_gate", 0.9999, f"Innovation gate of {s.topic}: chi-square probability "
                   f"({s.gate_dof} dof); 0: no gate.", bounds="[0, 1)") for s in streams if s.gate_dof]
    for s in streams:
        if s.bias is not None:
            b = s.bias
            specs += [Spec(f"{b.name}_bias_std", 0.0, f"Estimate {b.what} of this prior std; 0: none.", b.unit, ">= 0"),
                      Spec(f"{b.name}_bias_time", 0.0, f"Correlation time of the {b.name} bias (first-order "
                           "Gauss-Markov); 0: a random constant.", "s", ">= 0")]
    return specs
