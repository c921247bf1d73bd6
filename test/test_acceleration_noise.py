"""The added white acceleration: its process noise against exact discretisations, everything else the base's."""
import numpy as np
import pytest

from gpf_nav.filters.multiple_model import NOMINAL_ACCELERATION_NOISE, MultipleModelGPF
from gpf_nav.models import LinearGaussianModel, LunarDescentModel
from gpf_nav.models.acceleration_noise import WhiteAccelerationNoise


def _constant_velocity(density_squared: float) -> LinearGaussianModel:
    """Planar constant velocity ``[px, py, vx, vy]`` driven by white acceleration of spectral density
    ``density_squared`` (m^2/s^3), positions measured."""
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    G = np.vstack([np.zeros((2, 2)), np.sqrt(density_squared) * np.eye(2)])
    model = LinearGaussianModel(A, G, np.eye(2, 4), np.eye(2))
    model.position_index, model.velocity_index = (0, 1), (2, 3)
    return model


@pytest.mark.parametrize("dt", [0.5, 2.0, 30.0])
def test_the_added_noise_is_the_exact_discretisation_of_the_summed_density(dt):
    """White acceleration of density q0 plus q is white acceleration of density q0 + q: Van Loan's exact
    Q of the summed model."""
    added = WhiteAccelerationNoise(_constant_velocity(2e-4), 3e-3)
    np.testing.assert_allclose(added.process_noise(dt), _constant_velocity(2e-4 + 3e-3).process_noise(dt),
                               rtol=1e-9, atol=1e-15)


def test_the_lunar_model_with_added_noise_is_the_lunar_model_of_the_higher_density():
    base = LunarDescentModel(accel_noise_density=1e-3)
    added = WhiteAccelerationNoise(base, 1e-5)
    wider = LunarDescentModel(accel_noise_density=float(np.sqrt(1e-6 + 1e-5)))
    for dt in (2.0, -2.0, 10.0):
        np.testing.assert_allclose(added.process_noise(dt), wider.process_noise(dt), rtol=1e-12)
    assert not added.process_noise(2.0).flags.writeable


def test_a_model_without_positions_gets_the_noise_on_every_state():
    base = LinearGaussianModel(-np.eye(2), np.eye(2), np.eye(2), np.eye(2))
    added = WhiteAccelerationNoise(base, 0.5)
    np.testing.assert_allclose(added.process_noise(4.0), base.process_noise(4.0) + 0.5 * 4.0 * np.eye(2))


def test_everything_but_the_process_noise_is_the_base_models():
    base = LunarDescentModel(station=(1.2e6, -3.0e5, 9.0e5))
    added = WhiteAccelerationNoise(base, 1e-5)
    rng = np.random.default_rng(0)
    x = np.hstack([rng.normal(0.0, 1e3, (5, 3)) + [1.84e6, 0.0, 0.0], rng.normal(0.0, 1.0, (5, 3)) + [0.0, 1.6e3, 0.0]])
    for name, args in (("drift", (x, 3.0)), ("transition", (x, 2.0, 3.0)), ("transition_jacobian", (x, 2.0, 3.0)),
                       ("measure", (x, 3.0)), ("measurement_jacobian", (x, 3.0))):
        np.testing.assert_array_equal(getattr(added, name)(*args), getattr(base, name)(*args))
    y = base.measure(x[:1])[0] + [10.0, 3.1, -0.01]
    np.testing.assert_array_equal(added.measurement_residual(y, x), base.measurement_residual(y, x))
    np.testing.assert_array_equal(added.measurement_noise(), base.measurement_noise())
    assert (added.state_dim, added.measurement_dim, added.base_state_dim) == (6, 3, 6)
    assert added.position_index == base.position_index and added.velocity_index == base.velocity_index
    assert added.time_varying_noise == base.time_varying_noise


def test_negative_or_non_finite_intensity_is_refused():
    for q in (-1e-6, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="intensity"):
            WhiteAccelerationNoise(LunarDescentModel(), q)
        with pytest.raises(ValueError, match="nominal_acceleration_noise"):
            MultipleModelGPF(LunarDescentModel(), 10, nominal_acceleration_noise=q)


def test_the_multiple_models_nominal_member_runs_on_the_added_noise():
    model = LunarDescentModel()
    mm = MultipleModelGPF(model, 10, seed=0)
    assert isinstance(mm.nominal.model, WhiteAccelerationNoise) and mm.nominal.model.base is model
    assert mm.nominal.model.intensity == NOMINAL_ACCELERATION_NOISE
    assert all(member.model.base is model for member in mm.scaled)  # (the compensated members' own model)
    assert MultipleModelGPF(model, 10, seed=0, nominal_acceleration_noise=0.0).nominal.model is model
