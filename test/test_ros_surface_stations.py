"""Surface stations between real rclpy nodes over DDS (private ROS_DOMAIN_ID, localhost, time by /clock):
the simulator and the estimator given the same two beacons on the rotating Moon; one sees the vehicle
all along, the other sets below its horizon part way (no message then). The estimator, handed the prior
on set_state, tracks the truth in the site frame (position error in the site frame, its covariance
turned there, plus the velocity's, NEES over the second half of the run) and the node's transform chain
world -> moon_fixed -> site gives the site-frame position of :mod:`gpf_nav.models.frames`; a rae message
from a station it does not know is refused and counted as ``unknown_station`` in /diagnostics."""
import math

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import Vector3Stamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from gpf_nav.models.frames import MoonRotation, Site  # noqa: E402
from gpf_nav.ros import conversions as conv  # noqa: E402
from gpf_nav.ros.estimator_node import EstimatorNode  # noqa: E402
from gpf_nav.ros.simulator_node import SimulatorNode  # noqa: E402
from gpf_nav.sim.scenario import ScenarioConfig, generate  # noqa: E402
from gpf_nav.sim.simulator_params import check_simulator_parameters, simulator_specs  # noqa: E402
from gpf_nav.sim.surface_stations import surface_measurements  # noqa: E402
from test_ros_sensors import Ros, _status  # noqa: E402

S = 1_000_000_000
START, SECONDS = 1000.0, 240.0
BEACONS = {"north_beacon": (math.radians(4.0), math.radians(6.0), 300.0),
           "west_beacon": (math.radians(-2.0), math.radians(-14.0), -1200.0)}
SITE = (math.radians(3.0), math.radians(9.0), 0.0)


@pytest.fixture
def ros():
    r = Ros()
    yield r
    r.close()


def _station_parameters() -> list:
    """The station tables and moon epoch both nodes are given."""
    return [Parameter("station_names", value=list(BEACONS)),
            Parameter("station_lat_lon_height", value=[v for b in BEACONS.values() for v in b]),
            Parameter("moon_epoch", value=START)]


def test_visibility_of_the_two_beacons_offline():
    """The scenario the DDS test flies: north_beacon sees every measurement, west_beacon the first ones only."""
    scenario = generate(ScenarioConfig(duration=SECONDS), 0)
    seen = {name: np.isfinite(y[:, 0]) for name, y in surface_measurements(scenario, BEACONS, START, START, 0).items()}
    assert seen["north_beacon"].all()
    assert 20 < seen["west_beacon"].sum() < len(scenario.times) and seen["west_beacon"][0]
    assert not seen["west_beacon"][seen["west_beacon"].sum():].any()  # one pass: set, never back


def test_surface_stations_reproducible_and_independent_of_each_other():
    """Same seed, same arrays; a station's data do not change when another joins the table."""
    scenario = generate(ScenarioConfig(duration=60.0), 3)
    both = surface_measurements(scenario, BEACONS, START, START, 3)
    again = surface_measurements(scenario, BEACONS, START, START, 3)
    alone = surface_measurements(scenario, {"north_beacon": BEACONS["north_beacon"]}, START, START, 3)
    assert all(np.array_equal(both[n], again[n], equal_nan=True) for n in BEACONS)
    assert np.array_equal(both["north_beacon"], alone["north_beacon"])
    other = surface_measurements(scenario, BEACONS, START, START, 4)
    assert not np.array_equal(both["north_beacon"], other["north_beacon"])


@pytest.mark.parametrize("changes, text", [
    ({"station_lat_lon_height": [0.1, 0.2]}, "has 2 numbers"),
    ({"station_lat_lon_height": [2.0, 0.2, 0.0, 0.0, 0.0, 0.0]}, "latitude must lie in"),
    ({"station_names": ["a", "a"]}, "station name(s) a given more than once"),
    ({"station_names": ["station", "b"]}, "station name(s) station given more than once or equal"),
    ({"loop": True}, "drawn for the first lap only"),
])
def test_station_parameters_are_checked(changes, text):
    p = {spec.name: spec.default for spec in simulator_specs()}
    p.update({"station_names": ["a", "b"], "station_lat_lon_height": [0.0] * 6, **changes})
    assert any(text in e for e in check_simulator_parameters(p)), check_simulator_parameters(p)


def _chain_position(est, stamp_ns: int, r: np.ndarray) -> np.ndarray:
    """World position ``r`` in the site frame through the node's own TF transforms at ``stamp_ns``."""
    for transform in est.core.frame_transforms(stamp_ns):
        t, q = transform.transform.translation, transform.transform.rotation
        r = conv.quaternion_matrix(q.x, q.y, q.z, q.w).T @ (r - np.array([t.x, t.y, t.z]))
    return r


def test_two_surface_beacons_simulated_and_tracked_in_the_site_frame(ros):
    odom = ros.record(Odometry, "odometry/filtered")
    truth = ros.record(Odometry, "truth/odometry")
    rae = ros.record(Vector3Stamped, "measurements/rae")
    diagnostics = ros.record(DiagnosticArray, "/diagnostics")
    est = ros.add(EstimatorNode(context=ros.context, parameter_overrides=[
        Parameter("use_sim_time", value=True), Parameter("n_particles", value=300),
        Parameter("publish_rate", value=0.0), Parameter("diagnostics_period", value=0.5),
        Parameter("queue_depth", value=1000), Parameter("site_latitude", value=SITE[0]),
        Parameter("site_longitude", value=SITE[1]), Parameter("site_height", value=SITE[2]),
        *_station_parameters()]))
    sim = ros.add(SimulatorNode(context=ros.context, parameter_overrides=[
        Parameter("rate_factor", value=20.0), Parameter("scenario.duration", value=SECONDS),
        Parameter("start_time", value=START), Parameter("start_delay", value=1.5),
        Parameter("truth_rate", value=0.0), Parameter("imu_rate", value=0.0), *_station_parameters()]))
    assert ros.spin_until(lambda: sim.finished, 400.0), "the simulator did not finish"
    counters = est.engine.counters

    def processed():  # every rae the simulator sent (centre and surface stations) accepted or refused
        refused = sum(n for (stream, _), n in counters.rejected_by_stream.items() if stream == "rae")
        return counters.accepted["rae"] + refused >= sim.published["measurement"] + sim.published["station"]

    assert ros.spin_until(processed, 300.0), (counters.accepted, counters.rejected_by_stream, sim.published)
    # the simulator sent what the offline scenario predicts, each message named by its station
    expected = surface_measurements(sim.scenario, BEACONS, START, START, 0)
    assert sim.published["station"] == sum(int(np.isfinite(y[:, 0]).sum()) for y in expected.values())
    assert ros.spin_until(lambda: len(rae) >= sim.published["measurement"] + sim.published["station"], 60.0)
    by_name = {name: [m for m in rae if m.header.frame_id == name] for name in BEACONS}
    for name, y in expected.items():
        seen = np.flatnonzero(np.isfinite(y[:, 0]))
        assert [conv.stamp_to_ns(m.header.stamp) for m in by_name[name]] == [
            int(round((START + sim.scenario.times[k]) * S)) for k in seen]
        assert np.allclose([[m.vector.x, m.vector.y, m.vector.z] for m in by_name[name]], y[seen])
    assert not any(m.vector.z <= 0.0 for ms in by_name.values() for m in ms)  # nothing from below the horizon
    assert counters.accepted["rae"] == sim.published["measurement"] + sim.published["station"]

    # a station the estimator does not know: refused, counted in /diagnostics
    end_ns = int((START + SECONDS) * S)
    publisher = ros.node.create_publisher(Vector3Stamped, "measurements/rae", 10)
    assert ros.spin_until(lambda: publisher.get_subscription_count() > 0, 30.0)
    publisher.publish(conv.vector3_stamped([2e5, 0.1, 0.2], end_ns, "east_beacon"))
    assert ros.spin_until(lambda: (_status(diagnostics) or {}).get("rejected unknown_station") == "1", 60.0)
    assert _status(diagnostics)["rejected rae unknown_station"] == "1"

    # the estimate against the truth in the site frame over the run's second half
    assert ros.spin_until(lambda: {conv.stamp_to_ns(m.header.stamp) for m in odom}
                          >= {conv.stamp_to_ns(m.header.stamp) for m in truth} - {int(START * S)}, 60.0)
    moon, site = MoonRotation(START), Site(*SITE)
    truth_at = {conv.stamp_to_ns(m.header.stamp): conv.odometry_state(m) for m in truth}
    last = {conv.stamp_to_ns(m.header.stamp): m for m in odom}  # after every update at that stamp
    nees = []
    for stamp, m in last.items():
        if stamp not in truth_at or stamp <= (START + SECONDS / 2) * S:
            continue
        t, estimate, true = stamp / S, conv.odometry_state(m), truth_at[stamp]
        r_site = site.from_inertial(moon, estimate[:3], t=t)
        assert np.allclose(_chain_position(est, stamp, estimate[:3]), r_site, atol=1e-3)
        _, R = site.inertial_pose(moon, t)
        p_cov = R.T @ np.reshape(m.pose.covariance, (6, 6))[:3, :3] @ R
        v_cov = np.reshape(m.twist.covariance, (6, 6))[:3, :3]
        e_pos = r_site - site.from_inertial(moon, true[:3], t=t)
        e_vel = estimate[3:] - true[3:]
        nees.append(e_pos @ np.linalg.solve(p_cov, e_pos) + e_vel @ np.linalg.solve(v_cov, e_vel))
    assert len(nees) >= 55, len(nees)
    print(f"mean NEES over the second half: {np.mean(nees):.2f} ({len(nees)} estimates)")
    assert 1.5 <= np.mean(nees) <= 15.0, np.mean(nees)
    assert est.engine.reinit_count == 0
