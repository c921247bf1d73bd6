"""The gravity field (gpf_nav.models.gravity): the compiled recursion against the potential's gradient and
the textbook J2 acceleration, the Moon's rotation, the lunar model's and the truth's flows with a field."""
import dataclasses

import numpy as np
import pytest

from gpf_nav.models.gravity import DE430_ZONAL, FIELD_RADIUS, FIELDS, MOON_ROTATION_RATE, make_field
from gpf_nav.models.lunar import MU_MOON, LunarDescentModel
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate, truth_model


def _positions(count, seed=0, radius=1.8e6):
    r = np.random.default_rng(seed).standard_normal((3, count))
    return r * radius / np.linalg.norm(r, axis=0)


@pytest.mark.parametrize("name", ["j2", "zonal", "degree4"])
def test_the_acceleration_is_the_gradient_of_the_potential(name):
    """The Cunningham recursion against central differences of the sum over Legendre functions."""
    field = make_field(name, MU_MOON, epoch=-500.0)
    r, t = _positions(20, seed=1), 1234.0
    gradient = np.stack([(field.potential(r + e[:, None], t) - field.potential(r - e[:, None], t)) / 2.0
                         for e in np.eye(3)])
    a = field.acceleration(r, t)
    np.testing.assert_allclose(a, gradient, rtol=0, atol=1e-8 * np.abs(a).max())
    assert 1e-4 < np.linalg.norm(a, axis=0).min() and np.linalg.norm(a, axis=0).max() < 2e-3


def test_j2_is_the_textbook_acceleration():
    r = _positions(10, seed=2)
    x, y, z = r
    norm = np.linalg.norm(r, axis=0)
    k = -1.5 * DE430_ZONAL[2] * MU_MOON * FIELD_RADIUS ** 2 / norm ** 5
    s = 5.0 * z ** 2 / norm ** 2
    expected = np.stack([k * x * (1.0 - s), k * y * (1.0 - s), k * z * (3.0 - s)])
    np.testing.assert_allclose(make_field("j2", MU_MOON).acceleration(r), expected, rtol=1e-12)


def test_a_tesseral_field_turns_with_the_moon_and_a_zonal_one_does_not():
    r, t = _positions(5, seed=3), 3.0e4
    angle = MOON_ROTATION_RATE * t
    c, s = np.cos(angle), np.sin(angle)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    degree4 = make_field("degree4", MU_MOON)
    np.testing.assert_allclose(degree4.acceleration(turn @ r, t), turn @ degree4.acceleration(r, 0.0),
                               rtol=1e-10, atol=1e-16)
    assert not np.allclose(degree4.acceleration(r, t), degree4.acceleration(r, 0.0), rtol=1e-3)
    zonal = make_field("zonal", MU_MOON)
    assert zonal.zonal and not degree4.zonal
    np.testing.assert_array_equal(zonal.acceleration(r, t), zonal.acceleration(r, 0.0))


def test_fields_are_named_and_checked():
    assert make_field("point", MU_MOON) is None
    assert [make_field(n, MU_MOON).degree for n in FIELDS[1:]] == [2, 4, 4]
    with pytest.raises(ValueError, match="unknown gravity field"):
        make_field("degree9", MU_MOON)
    with pytest.raises(ValueError, match="truth_gravity"):
        ScenarioConfig(truth_gravity="j3")


def test_the_model_with_a_field_flows_as_the_truth_integrates():
    """The model's leapfrog with the field against the scenario's RK4 truth (no noise): the two integrators
    agree to metres over 600 s, while the field itself moves the state by tens of metres; without a field
    the model keeps its compiled flow."""
    config = ScenarioConfig(epsilon=0.0, truth_gravity="degree4", filter_gravity="degree4", duration=600.0,
                            truth_accel_noise_density=0.0)
    truth = generate(config, 0).truth
    model = filter_model(config)
    point = LunarDescentModel()
    x = truth[:1].copy()
    x_point = x.copy()
    for k in range(config.steps):
        x = model.transition(x, config.dt, k * config.dt)
        x_point = point.transition(x_point, config.dt, k * config.dt)
    assert np.linalg.norm(x[0, :3] - truth[-1, :3]) < 2.0
    assert np.linalg.norm(x_point[0, :3] - truth[-1, :3]) > 20.0
    chain = model.transition_chain(truth[0], np.full(3, 2.0), np.array([0.0, 2.0, 4.0]), [None] * 3)
    step = truth[:1]
    for k in range(3):
        step = model.transition(step, 2.0, 2.0 * k)
        np.testing.assert_array_equal(chain[k + 1], step[0])
    drift = model.drift(truth[:1], 100.0)[0, 3:] - point.drift(truth[:1])[0, 3:]
    np.testing.assert_allclose(drift, model.gravity.acceleration(truth[0, :3, None], 100.0)[:, 0], rtol=1e-9)


def test_the_truth_gravity_moves_the_truth_and_the_filter_gravity_the_model_only():
    base = ScenarioConfig(epsilon=0.0)
    j2 = dataclasses.replace(base, truth_gravity="j2")
    moved = np.linalg.norm(generate(j2, 4).truth[-1, :3] - generate(base, 4).truth[-1, :3])
    assert 100.0 < moved < 1e4  # 4.6e-4 m/s^2 over 2400 s
    assert truth_model(j2).gravity.name == "j2" and filter_model(j2).gravity is None
    modelled = dataclasses.replace(base, filter_gravity="zonal")
    np.testing.assert_array_equal(generate(modelled, 4).truth, generate(base, 4).truth)
    assert filter_model(modelled).gravity.name == "zonal"
