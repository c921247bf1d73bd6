"""Input streams as data (issue 25): a new measurement stream is one entry of
:data:`gpf_nav.estimator.streams.STREAMS` plus its sensor class. Here a velocimeter on a topic of its own
(``measurements/doppler``, ``geometry_msgs/Vector3Stamped``, a :class:`gpf_nav.sensors.VelocitySensor` with
a noise parameter of its own) is added by one entry: the real estimator node declares its parameters,
subscribes to it over DDS, counts and fuses its messages (the estimated velocity goes where the sensor
says), refuses a bad one by the stream's check, and the generated parameter table lists it."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest

from domains import fresh_domain
from gpf_nav.estimator import input_checks
from gpf_nav.estimator.params import BY_NAME, ESTIMATOR
from gpf_nav.estimator.streams import STREAMS, Reading, Stream, stream_parameters
from gpf_nav.schema import Spec
from gpf_nav.sensors import VelocitySensor
from gpf_nav.sim.scenario import ScenarioConfig, generate

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import Vector3Stamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402

from gpf_nav.ros import conversions as conv  # noqa: E402
from gpf_nav.ros.estimator_node import EstimatorNode  # noqa: E402

S = 1_000_000_000
OFFSET = np.array([1.5, 0.0, 0.0])  # m/s: what the velocimeter says beyond the truth


def _finite(reading: Reading) -> tuple[bool, str]:
    return input_checks.check_finite(*reading.values)


DOPPLER = Stream(
    "doppler", "measurements/doppler", "geometry_msgs/Vector3Stamped", "world_frame", _finite,
    sensor=lambda p, model, bias: VelocitySensor(p["doppler_noise_std"], bias=bias,
                                                 index=tuple(model.velocity_index)),
    gate_dof=3,
    parameters=(Spec("doppler_noise_std", 0.05, "Velocimeter noise standard deviation per axis.", "m/s", "> 0"),))


@pytest.fixture
def doppler():
    """:data:`DOPPLER` added to the stream table (and so its parameters to the schema), for one test."""
    specs = stream_parameters([DOPPLER])
    STREAMS.append(DOPPLER)
    ESTIMATOR.extend(specs)
    BY_NAME.update({s.name: s for s in specs})
    yield DOPPLER
    STREAMS.remove(DOPPLER)
    for spec in specs:
        ESTIMATOR.remove(spec)
        del BY_NAME[spec.name]


def _until(executor, condition, timeout: float = 120.0) -> bool:
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return condition()


def test_a_new_stream_is_one_entry_and_is_fused_end_to_end(doppler):
    from gpf_nav.tools.parameter_docs import generated_files
    assert "| `doppler_noise_std` |" in generated_files()["docs/parameters.md"]
    assert "| `doppler_gate` |" in generated_files()["docs/parameters.md"]

    scenario = generate(ScenarioConfig(duration=20.0, epsilon=0.0), 1)
    t0 = 100 * S
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    context = rclpy.Context()
    rclpy.init(args=[], context=context, domain_id=fresh_domain())
    executor = SingleThreadedExecutor(context=context)
    try:
        node = EstimatorNode(context=context, parameter_overrides=[
            Parameter("initial_state", value=[float(v) for v in scenario.truth[0]]),
            Parameter("initial_std", value=[100.0, 100.0, 100.0, 1.0, 1.0, 1.0]),
            Parameter("initial_stamp", value=t0 / S), Parameter("n_particles", value=200),
            Parameter("publish_rate", value=0.0), Parameter("doppler_noise_std", value=0.02)])
        probe = rclpy.create_node("gpf_doppler_probe", context=context)
        executor.add_node(node)
        executor.add_node(probe)
        assert node.get_parameter("doppler_gate").value == 0.9999  # the stream's parameters are declared
        publisher = probe.create_publisher(Vector3Stamped, doppler.topic, qos_profile_sensor_data)
        assert _until(executor, lambda: publisher.get_subscription_count() > 0), "the node never subscribed"

        sent = 5
        for k in range(1, sent + 1):
            stamp = t0 + int(round((scenario.times[k] - scenario.times[0]) * S))
            publisher.publish(conv.vector3_stamped(scenario.truth[k, 3:] + OFFSET, stamp, "moon_inertial"))
        bad = conv.vector3_stamped([float("nan"), 0.0, 0.0], t0 + 11 * S, "moon_inertial")
        publisher.publish(bad)
        counters = node.engine.counters
        assert _until(executor, lambda: counters.accepted["doppler"] == sent
                      and counters.rejected_by_stream[("doppler", "non_finite")] == 1), \
            (counters.accepted, counters.rejected_by_stream)
        velocity = node.engine.mean[list(node.core.model.velocity_index)]
        error = velocity - scenario.truth[sent, 3:]
        assert np.allclose(error, OFFSET, atol=0.2), error  # where the velocimeter says, not the truth
    finally:
        rclpy.try_shutdown(context=context)
