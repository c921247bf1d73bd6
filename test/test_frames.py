"""The rotating Moon's frames (gpf_nav.models.frames): known answers and round trips."""
import math

import numpy as np
import pytest

from gpf_nav.models.frames import MoonRotation, Site, enu_axes, surface_position
from gpf_nav.models.gravity import MOON_ROTATION_RATE, harmonic_field
from gpf_nav.models.lunar import MOON_RADIUS, MU_MOON

MOON = MoonRotation(epoch=100.0)
RNG = np.random.default_rng(7)


def test_rate_is_the_gravity_fields():
    assert MOON.rate == MOON_ROTATION_RATE
    assert MOON.angle(100.0) == 0.0
    assert MOON.angle(100.0 + 3600.0) == pytest.approx(MOON_ROTATION_RATE * 3600.0)


def test_equator_at_longitude_90_deg():
    r = surface_position(0.0, math.pi / 2, 1000.0)
    np.testing.assert_allclose(r, [0.0, MOON_RADIUS + 1000.0, 0.0], atol=1e-6)
    # a quarter turn after the epoch, that point is on the inertial -x axis
    t = 100.0 + (math.pi / 2) / MOON_ROTATION_RATE
    np.testing.assert_allclose(MOON.to_inertial(r, t=t), [-(MOON_RADIUS + 1000.0), 0.0, 0.0], atol=1e-3)
    np.testing.assert_allclose(enu_axes(0.0, math.pi / 2), [[-1, 0, 0], [0, 0, 1], [0, 1, 0]], atol=1e-15)


def test_surface_point_moves_at_omega_cross_r():
    r_fixed = surface_position(0.3, -1.2)
    t = 5e4
    r, v = MOON.to_inertial(r_fixed, np.zeros(3), t)
    np.testing.assert_allclose(v, np.cross([0.0, 0.0, MOON_ROTATION_RATE], r), rtol=1e-14)
    assert np.linalg.norm(v) == pytest.approx(MOON_ROTATION_RATE * MOON_RADIUS * math.cos(0.3))
    # and it stands still in the Moon-fixed frame
    _, v_fixed = MOON.to_fixed(r, v, t)
    np.testing.assert_allclose(v_fixed, 0.0, atol=1e-12)


def test_moon_fixed_matches_the_gravity_fields_rotation():
    field = harmonic_field(MU_MOON, 4, epoch=100.0)
    r = RNG.normal(size=(3, 4)) * 2e6
    t = 7.3e4
    c, s = math.cos(field.rotation_rate * (t - field.epoch)), math.sin(field.rotation_rate * (t - field.epoch))
    body = np.stack([c * r[0] + s * r[1], -s * r[0] + c * r[1], r[2]])
    np.testing.assert_allclose(MOON.to_fixed(r.T, t=t), body.T, rtol=1e-13)


def test_round_trips():
    r, v = RNG.normal(size=(5, 3)) * 2e6, RNG.normal(size=(5, 3)) * 1e3
    t = -2.5e5
    back = MOON.to_inertial(*MOON.to_fixed(r, v, t), t)
    np.testing.assert_allclose(back[0], r, rtol=1e-13)
    np.testing.assert_allclose(back[1], v, rtol=1e-12, atol=1e-9)
    site = Site(math.radians(-45.0), math.radians(170.0), -2500.0)
    back = site.to_inertial(MOON, *site.from_inertial(MOON, r, v, t), t)
    np.testing.assert_allclose(back[0], r, rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(back[1], v, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(site.to_inertial(MOON, site.from_inertial(MOON, r, t=t), t=t), r, atol=1e-6)


def test_site_frame():
    site = Site(math.radians(30.0), math.radians(60.0), 100.0)
    np.testing.assert_allclose(site.axes @ site.axes.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(np.cross(site.axes[0], site.axes[1]), site.axes[2], atol=1e-15)  # right-handed
    t = 3e4
    # the site's origin is at the site frame's zero, and 1 km above it is up = +z
    origin, R = site.inertial_pose(MOON, t)
    np.testing.assert_allclose(site.from_inertial(MOON, origin, t=t), 0.0, atol=1e-6)
    above = MOON.to_inertial(surface_position(site.latitude, site.longitude, 1100.0), t=t)
    np.testing.assert_allclose(site.from_inertial(MOON, above, t=t), [0.0, 0.0, 1000.0], atol=1e-6)
    np.testing.assert_allclose(origin + R @ [1.0, 2.0, 3.0], site.to_inertial(MOON, [1.0, 2.0, 3.0], t=t), atol=1e-6)
    # north points to the pole: a point further north has a positive north coordinate
    north = MOON.to_inertial(surface_position(site.latitude + 1e-3, site.longitude, 100.0), t=t)
    e, n, u = site.from_inertial(MOON, north, t=t)
    assert n > 0 and abs(e) < 1e-6 * n


def test_a_site_refuses_a_latitude_past_the_pole():
    with pytest.raises(ValueError, match="latitude"):
        Site(2.0, 0.0)
