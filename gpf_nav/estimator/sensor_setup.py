"""The estimator's sensors from the node parameters: position, velocity and altitude fixes beside the
model's own measurement (rae, range), their innovation gates and optional bias states. No ROS here.

Each of ``range``, ``position``, ``velocity`` and ``altitude`` may estimate a bias per component:
``<name>_bias_std`` > 0 [m or m/s] declares it, as a random constant (``<name>_bias_time`` 0) or a
first-order Gauss-Markov state of correlation time ``<name>_bias_time`` s. The range bias is a bias
state on the range component of the model's own measurement (the ``rae`` sensor: also what
``measurements/range`` feeds). With any bias declared the filter is a
:class:`gpf_nav.filters.SensorBiasFilter`.
"""
from __future__ import annotations

from typing import Callable

from gpf_nav.filters import SensorBiasFilter
from gpf_nav.sensors import (AltitudeSensor, Bias, ModelSensor, PositionSensor, Sensor, VelocitySensor,
                             gauss_markov_bias, random_constant_bias)

SENSOR_STREAMS = ("position", "velocity", "altitude")
"""Streams measured by a sensor object of their own (the model's own measurement: rae, range)."""
BIASES = ("range", "position", "velocity", "altitude")
"""Prefixes of the ``<name>_bias_std`` / ``<name>_bias_time`` parameters."""


def _bias(std: float, time: float, components: list[float]) -> Bias | None:
    """A bias of std ``std`` on the components whose entry is 1 (None when ``std`` is 0)."""
    if std <= 0.0:
        return None
    stds = [std * c for c in components]
    return random_constant_bias(stds) if time <= 0.0 else gauss_markov_bias(stds, [time] * len(stds))


def build_sensors(p: dict, model) -> dict[str, Sensor]:
    """``{"rae", "position", "velocity", "altitude"}`` sensors of the parameters ``p`` on ``model``
    (``rae`` is the model's own measurement; position and velocity take each message's covariance)."""
    position = tuple(model.position_index)
    velocity = tuple(model.velocity_index)
    return {
        "rae": ModelSensor(model, "rae", bias=_bias(p["range_bias_std"], p["range_bias_time"], [1.0, 0.0, 0.0])),
        "position": PositionSensor(1.0, bias=_bias(p["position_bias_std"], p["position_bias_time"], [1.0] * 3),
                                   index=position),
        "velocity": VelocitySensor(1.0, bias=_bias(p["velocity_bias_std"], p["velocity_bias_time"], [1.0] * 3),
                                   index=velocity),
        "altitude": AltitudeSensor(p["altitude_noise_std"], p["reference_radius"],
                                   bias=_bias(p["altitude_bias_std"], p["altitude_bias_time"], [1.0]),
                                   position_index=position),
    }


def with_biases(build: Callable[[object], object], model, sensors: dict[str, Sensor]) -> Callable[[], object]:
    """A factory of the filter: ``build(model)``, in a :class:`SensorBiasFilter` when a sensor has a bias."""
    biased = [s for s in sensors.values() if s.bias is not None]
    if not biased:
        return lambda: build(model)
    return lambda: SensorBiasFilter(build, model, biased)


def gates(p: dict) -> dict[str, float]:
    """Innovation-gate probability per sensor stream (0: off)."""
    return {stream: p[f"{stream}_gate"] for stream in SENSOR_STREAMS}
