"""Stations on the rotating Moon and in inertial space (gpf_nav.sensors.station): known answers, the
Jacobian against finite differences, the lunar model's measurement, and filters on a pass over a station."""
import math

import numpy as np
import pytest

from gpf_nav import registry
from gpf_nav.models.frames import MoonRotation, surface_position
from gpf_nav.models.gravity import MOON_ROTATION_RATE
from gpf_nav.models.lunar import MOON_RADIUS, LunarDescentModel
from gpf_nav.sensors.station import StationSensor

MOON = MoonRotation(epoch=0.0)
RANGE_STD, ANGLE_STD = 30.0, math.radians(0.03)


def surface(lat_deg=0.0, lon_deg=0.0, height=0.0, moon=MOON):
    return StationSensor.surface(math.radians(lat_deg), math.radians(lon_deg), height, moon, RANGE_STD, ANGLE_STD,
                                 name="beacon")


def state(position, velocity=(0.0, 0.0, 0.0)):
    return np.array([[*position, *velocity]], dtype=float)


def test_topocentric_angles_known_answers():
    s = surface()  # at (R, 0, 0) at the epoch: north is +z, east +y, up +x
    R = MOON_RADIUS
    cases = {(R, 0.0, 1e3): (1e3, 0.0, 0.0),                # north on the horizon
             (R, 1e3, 0.0): (1e3, math.pi / 2, 0.0),        # east
             (R, -1e3, 0.0): (1e3, -math.pi / 2, 0.0),      # west
             (R + 1e3, 0.0, 0.0): (1e3, 0.0, math.pi / 2),  # overhead
             (R + 1e3, 1e3, 1e3): (math.sqrt(3) * 1e3, math.pi / 4, math.atan(1 / math.sqrt(2)))}
    for position, expected in cases.items():
        np.testing.assert_allclose(s.measure(state(position), 0.0)[0], expected, atol=1e-12)
    south = s.measure(state((R, 0.0, -1e3)), 0.0)[0, 1]
    assert abs(abs(south) - math.pi) < 1e-12


def test_the_station_turns_with_the_moon():
    s = surface(lon_deg=90.0)
    t = (math.pi / 2) / MOON_ROTATION_RATE  # a quarter turn: the station is on the inertial -x axis
    overhead = state((-(MOON_RADIUS + 5e3), 0.0, 0.0))
    np.testing.assert_allclose(s.measure(overhead, t)[0, [0, 2]], [5e3, math.pi / 2], atol=1e-7)  # (azimuth: any)
    # a point fixed in inertial space is seen to move: the measurement depends on t
    x = state(MOON.to_inertial(surface_position(0.0, math.pi / 2, 1e5), t=0.0))
    before, after = s.measure(x, 0.0)[0], s.measure(x, 600.0)[0]
    np.testing.assert_allclose(before[[0, 2]], [1e5, math.pi / 2], atol=1e-6)
    turn, r = MOON_ROTATION_RATE * 600.0, MOON_RADIUS + 1e5  # the station moved 2.8 km from under it
    assert before[2] - after[2] == pytest.approx(math.atan2(r * math.sin(turn), r * math.cos(turn) - MOON_RADIUS),
                                                 rel=1e-9)
    assert s.visible(x, 0.0)[0] and not s.visible(state((-MOON_RADIUS - 1e5, 0.0, 0.0)), 0.0)[0]


def test_jacobian_against_finite_differences():
    rng = np.random.default_rng(3)
    s = surface(35.0, -120.0, 1500.0)
    t = 4321.0
    station = MOON.to_inertial(s.position, t=t)
    x = np.concatenate([station + rng.normal(size=(6, 3)) * 2e5, rng.normal(size=(6, 3)) * 1e3], axis=1)
    h, H = s.measure_and_jacobian(x, t)
    np.testing.assert_array_equal(h, s.measure(x, t))
    np.testing.assert_array_equal(H, s.jacobian(x, t))
    assert np.all(H[:, :, 3:] == 0.0)
    step = 1.0
    for j in range(3):
        dx = np.zeros(6)
        dx[j] = step
        numeric = s.residual(s.measure(x + dx, t), s.measure(x - dx, t)) / (2 * step)
        np.testing.assert_allclose(H[:, :, j], numeric, rtol=1e-6, atol=1e-12)
    # rows orthogonal (the GPF's projection may rely on it)
    for k in range(len(x)):
        G = H[k, :, :3] @ H[k, :, :3].T
        np.testing.assert_allclose(G - np.diag(np.diag(G)), 0.0, atol=1e-12 * np.abs(G).max())


def test_angle_residuals_wrap():
    s = surface()
    r = s.residual(np.array([0.0, math.pi - 0.01, 0.0]), np.array([0.0, -math.pi + 0.01, 0.0]))
    assert r[1] == pytest.approx(-0.02)


def test_centre_station_reproduces_the_lunar_model():
    rng = np.random.default_rng(5)
    model = LunarDescentModel()
    s = StationSensor.inertial((0.0, 0.0, 0.0), RANGE_STD, ANGLE_STD)
    x = np.concatenate([rng.normal(size=(20, 3)) * 2e6, rng.normal(size=(20, 3)) * 1e3], axis=1)
    for t in (0.0, 1e4):  # an inertial station does not depend on t
        np.testing.assert_allclose(s.measure(x, t), model.measure(x), rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(s.jacobian(x, t), model.measurement_jacobian(x), rtol=1e-12, atol=1e-20)
        np.testing.assert_allclose(s.jacobian(x[:1], t), model.measurement_jacobian(x[:1]), rtol=1e-12, atol=1e-20)
    np.testing.assert_array_equal(s.noise(), model.measurement_noise())
    np.testing.assert_array_equal(s.angular, model.angular)


def pass_over(station: StationSensor, steps: int, dt: float, seed: int):
    """A 100 km circular orbit from over (0, 0) at the epoch, towards a station ahead: the start, the truth and noisy
    measurements at each step."""
    model = LunarDescentModel(accel_noise_density=0.0)
    r = MOON_RADIUS + 1e5
    speed = math.sqrt(model.gm / r)
    x = state((r, 0.0, 0.0), (0.0, speed * math.cos(0.3), speed * math.sin(0.3)))
    x0 = x[0].copy()
    rng = np.random.default_rng(seed)
    truth, ys = [], []
    for k in range(1, steps + 1):
        x = model.transition(x, dt, (k - 1) * dt)
        y = station.measure(x, k * dt)[0] + rng.normal(size=3) * np.sqrt(np.diag(station.noise()))
        assert station.visible(x, k * dt)[0]
        truth.append(x[0].copy())
        ys.append(y)
    return x0, np.array(truth), np.array(ys)


@pytest.mark.parametrize("name, n", [("ekf", 1), ("gpf", 100)])
def test_a_filter_converges_on_a_pass_over_a_surface_station(name, n):
    station = surface(5.0, 10.0)
    dt, steps = 10.0, 30
    x0, truth, ys = pass_over(station, steps, dt, seed=11)
    model = LunarDescentModel()
    f = registry.make(name, model, n_particles=n, seed=2)
    rng = np.random.default_rng(12)
    std = np.array([2e3, 2e3, 2e3, 2.0, 2.0, 2.0])
    f.initialize(x0 + rng.normal(size=6) * std, np.diag(std ** 2), 0.0)
    for y in ys:
        f.predict(dt)
        f.update(y, station)
    error = f.mean[:6] - truth[-1]
    P = f.covariance[:6, :6]
    assert np.linalg.norm(error[:3]) < 300.0, error
    assert error @ np.linalg.solve(P, error) < 30.0  # 6 dof: consistent, not overconfident
