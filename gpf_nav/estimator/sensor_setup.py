"""The estimator's sensors from the stream table (:data:`gpf_nav.estimator.streams.STREAMS`) and the node
parameters: one sensor per stream that has its own (the others feed another stream's), with its optional
bias states, and the innovation gates. No ROS here.

A stream's bias states (``<bias>_bias_std`` > 0 [the stream's unit] declares them) are a random constant
(``<bias>_bias_time`` 0) or a first-order Gauss-Markov state of correlation time ``<bias>_bias_time`` s,
on the sensor components its mask selects: the range bias is on the range component of the model's own
measurement (the ``rae`` sensor, also what ``measurements/range`` feeds). With any bias declared the
filter is a :class:`gpf_nav.filters.SensorBiasFilter`.
"""
from __future__ import annotations

from typing import Callable

from gpf_nav.estimator.streams import BiasStates, Stream
from gpf_nav.filters import SensorBiasFilter
from gpf_nav.sensors import Bias, Sensor, gauss_markov_bias, random_constant_bias


def _bias(p: dict, states: BiasStates | None) -> Bias | None:
    """The bias states the parameters ``p`` declare (None when ``<name>_bias_std`` is 0 or there are none)."""
    if states is None or p[f"{states.name}_bias_std"] <= 0.0:
        return None
    stds = [p[f"{states.name}_bias_std"] * c for c in states.mask]
    time = p[f"{states.name}_bias_time"]
    return random_constant_bias(stds) if time <= 0.0 else gauss_markov_bias(stds, [time] * len(stds))


def build_sensors(p: dict, model, streams: list[Stream]) -> dict[str, Sensor]:
    """``{stream name: sensor}`` of every stream of ``streams``: its own sensor, or the one of the stream it
    feeds (``rae`` is the model's own measurement; position and velocity take each message's covariance)."""
    own = {s.name: s.sensor(p, model, _bias(p, s.bias)) for s in streams if s.sensor is not None}
    return {s.name: own[s.feeds or s.name] for s in streams}


def with_biases(build: Callable[[object], object], model, sensors: dict[str, Sensor]) -> Callable[[], object]:
    """A factory of the filter: ``build(model)``, in a :class:`SensorBiasFilter` when a sensor has a bias."""
    biased = list({id(s): s for s in sensors.values() if s.bias is not None}.values())
    if not biased:
        return lambda: build(model)
    return lambda: SensorBiasFilter(build, model, biased)


def gates(p: dict, streams: list[Stream]) -> dict[str, float]:
    """Innovation-gate probability per stream that has a gate (0: off)."""
    return {s.name: p[f"{s.name}_gate"] for s in streams if s.gate_dof}
