"""Stations and Moon frames through the estimator's :class:`MessageLayer` and real ROS messages (no DDS):
rae and range from two surface stations named in header.frame_id are fused; an unknown name is refused,
counted and logged once; position fixes in moon_fixed and the site frame; the frames' TF transforms."""
import math

import numpy as np
import pytest

pytest.importorskip("rclpy")

from sensor_msgs.msg import Range  # noqa: E402

from gpf_nav.estimator.params import ESTIMATOR, ParameterError, parameters_from_files  # noqa: E402
from gpf_nav.models.frames import MoonRotation, Site  # noqa: E402
from gpf_nav.ros import conversions as conv  # noqa: E402
from gpf_nav.ros import diagnostics as diag  # noqa: E402
from gpf_nav.ros.message_layer import MessageLayer  # noqa: E402
from gpf_nav.sensors.station import StationSensor  # noqa: E402
from gpf_nav.sim.scenario import ScenarioConfig, generate  # noqa: E402
from test_estimator_sensors import _Log, position_msg  # noqa: E402

S = 1_000_000_000
T0 = 1000 * S
BEACONS = {"north_beacon": (math.radians(4.0), math.radians(6.0), 300.0),
           "south_beacon": (math.radians(-2.0), math.radians(10.0), -1200.0)}
SITE = (math.radians(3.0), math.radians(9.0), 0.0)
STATION_PARAMETERS = [f"station_names:={list(BEACONS)}",
                      f"station_lat_lon_height:={[v for b in BEACONS.values() for v in b]}",
                      f"moon_epoch:={T0 / S}", f"site_latitude:={SITE[0]}", f"site_longitude:={SITE[1]}"]


def _core(scenario, *assignments):
    p = parameters_from_files(ESTIMATOR, "gpf_estimator", [], [
        "filter:=gpf", "n_particles:=200", f"initial_state:={[float(v) for v in scenario.prior_mean]}",
        f"initial_std:={[float(v) for v in np.sqrt(np.diag(scenario.prior_cov))]}",
        f"initial_stamp:={T0 * 1e-9}", *STATION_PARAMETERS, *assignments])
    out, log = [], _Log()
    return MessageLayer(p, lambda topic, msg: out.append((topic, msg)), log), out, log


def _beacon_messages(scenario, seed=1):
    """(stamp, stream, msg): each beacon's rae at even steps, its range only at odd ones."""
    rng = np.random.default_rng(seed)
    moon = MoonRotation(T0 / S)
    sensors = [StationSensor.surface(*b, moon, scenario.config.range_noise_std, scenario.config.angle_noise_std,
                                     name=name) for name, b in BEACONS.items()]
    out = []
    for k, t in enumerate(scenario.times):
        stamp = T0 + int(round(t * S))
        s = sensors[k % 2]
        x = scenario.truth[k + 1:k + 2]  # truth[0] is the start, before the first measurement
        y = s.measure(x, stamp / S)[0] + rng.normal(size=3) * np.sqrt(np.diag(s.noise()))
        assert s.visible(x, stamp / S)[0]
        if (k // 2) % 2 == 0:
            out.append((stamp, "rae", conv.vector3_stamped(y, stamp, s.name)))
        else:
            msg = Range(range=float(y[0]), min_range=0.0, max_range=1e7)
            msg.header.stamp, msg.header.frame_id = conv.ns_to_stamp(stamp), s.name
            out.append((stamp, "range", msg))
    return out


def _scenario():
    return generate(ScenarioConfig(duration=200.0, epsilon=0.0), 4)


def test_two_surface_beacons_are_fused_and_an_unknown_one_refused_once():
    scenario = _scenario()
    core, out, log = _core(scenario)
    messages = _beacon_messages(scenario)
    for stamp, stream, msg in messages:
        core.handle(stream, msg, stamp)
    for stamp in (T0 + 201 * S, T0 + 202 * S):
        core.handle("rae", conv.vector3_stamped([2e5, 0.1, 0.2], stamp, "east_beacon"), stamp)
    _, _, kv = diag.filter_status(core.engine, T0 + 202 * S, core.thresholds, core.filter_name)
    kv = dict(kv)
    assert int(kv["accepted rae"]) + int(kv["accepted range"]) == len(messages)
    assert kv["rejected unknown_station"] == "2" and kv["rejected rae unknown_station"] == "2"
    unknown = [line for level, line in log.lines if "unknown_station" in line]
    assert len(unknown) == 1 and "'east_beacon'" in unknown[0] and "north_beacon, south_beacon" in unknown[0]
    error = core.engine.mean[:6] - scenario.truth[-1]
    P = core.engine.cov[:6, :6]
    assert np.linalg.norm(error[:3]) < 300.0, error
    assert error @ np.linalg.solve(P, error) < 30.0


def test_position_fixes_in_the_moon_frames_equal_the_world_fix():
    scenario = _scenario()
    site = Site(*SITE)
    moon = MoonRotation(T0 / S)
    cov = np.diag([900.0, 400.0, 2500.0])
    runs = {}
    for frame in ("moon_inertial", "moon_fixed", "map"):
        core, _, _ = _core(scenario)
        for k in range(0, 40, 5):
            stamp = T0 + int(round(scenario.times[k] * S))
            r, t = scenario.truth[k + 1, :3], stamp / S
            origin, R = {"moon_inertial": (np.zeros(3), np.eye(3)),
                         "moon_fixed": (np.zeros(3), moon.fixed_to_inertial_matrix(t)),
                         "map": site.inertial_pose(moon, t)}[frame]
            core.handle("position", position_msg(stamp, R.T @ (r - origin), R.T @ cov @ R, frame), stamp)
        runs[frame] = core.engine.mean
    np.testing.assert_allclose(runs["moon_fixed"], runs["moon_inertial"], rtol=1e-9, atol=1e-5)
    np.testing.assert_allclose(runs["map"], runs["moon_inertial"], rtol=1e-9, atol=1e-5)
    core, _, _ = _core(scenario)
    core.handle("position", position_msg(T0 + S, scenario.truth[0, :3], cov, "odom"), T0 + S)
    assert core.engine.counters.rejected["wrong_frame"] == 1


def test_the_frame_transforms_are_the_sites():
    scenario = _scenario()
    core, _, _ = _core(scenario)
    stamp = T0 + 7200 * S
    fixed, site_tf = core.frame_transforms(stamp)
    assert (fixed.header.frame_id, fixed.child_frame_id) == ("moon_inertial", "moon_fixed")
    assert (site_tf.header.frame_id, site_tf.child_frame_id) == ("moon_fixed", "map")

    def matrix(tf):
        q, t = tf.transform.rotation, tf.transform.translation
        return conv.quaternion_matrix(q.x, q.y, q.z, q.w), np.array([t.x, t.y, t.z])

    (R1, t1), (R2, t2) = matrix(fixed), matrix(site_tf)
    r_site = np.array([1e3, -2e3, 5e3])
    r_world = R1 @ (R2 @ r_site + t2) + t1
    np.testing.assert_allclose(Site(*SITE).to_inertial(MoonRotation(T0 / S), r_site, t=stamp / S), r_world,
                               rtol=1e-12, atol=1e-6)


@pytest.mark.parametrize("assignments, text", [
    (["station_lat_lon_height:=[0.1, 0.2]"], "has 2 numbers"),
    (["station_names:=[station, a]", "station_lat_lon_height:=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]"], "also name"),
    (["station_names:=[a, a]", "station_lat_lon_height:=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]"], "more than once"),
    (["station_names:=[a]", "station_lat_lon_height:=[2.0, 0.0, 0.0]"], "latitude"),
])
def test_station_tables_are_checked(assignments, text):
    p = parameters_from_files(ESTIMATOR, "gpf_estimator", [], assignments)
    with pytest.raises(ParameterError, match=text):
        MessageLayer(p, lambda topic, msg: None, _Log())
