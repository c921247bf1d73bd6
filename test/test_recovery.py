"""Recovery: the particle filters never emit a non-finite estimate, and re-initialise when they must."""
import numpy as np
import pytest

from gpf_nav.filters import BootstrapPF, GeometricProjectionPF
from linear_reference import constant_velocity_model

MEAN, COV = np.array([0.0, 1.0]), np.diag([4.0, 1.0])


class PoisonedModel(type(constant_velocity_model())):
    """Constant velocity model whose transition turns particles with position above a bound into NaN."""

    bound = np.inf

    def transition(self, x, dt, t=0.0, u=None):
        out = np.array(super().transition(x, dt, t, u))
        out[out[:, 0] > self.bound] = np.nan
        return out


def poisoned(bound):
    base = constant_velocity_model()
    model = PoisonedModel(base.A, base.G, base.C, base.R)
    model.bound = bound
    return model


@pytest.mark.parametrize("cls", [BootstrapPF, GeometricProjectionPF])
def test_some_non_finite_particles_get_zero_weight(cls):
    # without compensation, so that the particles' first component is the poisoned model's own
    options = {"unmodelled_acceleration_std": 0.0} if cls is GeometricProjectionPF else {}
    f = cls(poisoned(1.0), n_particles=400, seed=0, **options)
    f.initialize(MEAN, COV)
    f.predict(1.0)
    assert np.all(np.isfinite(f.mean)) and np.all(np.isfinite(f.covariance))
    assert 0 < np.count_nonzero(f.weights == 0.0) < 400  # the poisoned ones, and only those
    assert np.all(f.particles[f.weights > 0, 0] <= 1.0)
    f.update(np.array([0.5]))
    assert np.all(np.isfinite(f.mean)) and f.recoveries == 0


@pytest.mark.parametrize("cls", [BootstrapPF, GeometricProjectionPF])
def test_all_particles_non_finite_reinitialises(cls):
    f = cls(poisoned(-1e9), n_particles=100, seed=0)
    f.initialize(MEAN, COV)
    f.predict(1.0)
    assert f.recoveries == 1 and "non-finite" in f.last_recovery_reason
    assert np.all(np.isfinite(f.mean)) and np.all(np.isfinite(f.covariance))
    assert np.allclose(f.mean, MEAN, atol=2.0)


PAPER_GPF = {"metric": "euclidean", "weighting": "likelihood", "unmodelled_acceleration_std": 0.0}


@pytest.mark.parametrize("cls, options", [(BootstrapPF, {}), (GeometricProjectionPF, PAPER_GPF)])
def test_impossible_measurement_reinitialises_from_last_good(cls, options):
    f = cls(constant_velocity_model(), n_particles=100, seed=0, **options)
    f.initialize(MEAN, COV)
    f.predict(1.0)
    f.update(np.array([1e300]))  # squared residual overflows (the paper's GPF even projects onto it)
    assert f.recoveries == 1
    assert "weight" in f.last_recovery_reason or "non-finite" in f.last_recovery_reason
    assert np.all(np.isfinite(f.mean)) and np.all(np.isfinite(f.covariance))
    assert np.trace(f.covariance) > np.trace(COV)  # inflated


def test_default_gpf_gates_an_impossible_measurement_and_keeps_its_estimate():
    f = GeometricProjectionPF(constant_velocity_model(), n_particles=100, seed=0)
    f.initialize(MEAN, COV)
    f.predict(1.0)
    before = f.mean.copy()
    f.update(np.array([1e300]))
    assert f.gated == 1 and f.recoveries == 0
    assert np.all(np.isfinite(f.mean)) and np.all(np.isfinite(f.covariance))
    assert np.allclose(f.mean, before, atol=0.5)


def test_ess_collapse_reinitialises_after_the_set_number_of_updates():
    f = BootstrapPF(constant_velocity_model(meas_std=1e-3), n_particles=50, seed=0, collapse_steps=3)
    f.initialize(MEAN, COV)
    for k in range(3):
        f.predict(1.0)
        f.update(np.array([k + 1.0]))
    assert f.recoveries == 1 and "ESS" in f.last_recovery_reason


def test_collapse_recovery_off_by_default():
    f = BootstrapPF(constant_velocity_model(meas_std=1e-3), n_particles=50, seed=0)
    f.initialize(MEAN, COV)
    for k in range(5):
        f.predict(1.0)
        f.update(np.array([k + 1.0]))
    assert f.recoveries == 0


@pytest.mark.parametrize("name", ["ExtendedKF", "UnscentedKF", "EnsembleKF"])
def test_gaussian_filters_reinitialise_from_last_good_on_non_finite_prediction(name):
    import gpf_nav.filters as filters
    f = getattr(filters, name)(poisoned(-1e9), seed=0)
    f.initialize(MEAN, COV)
    f.predict(1.0)
    assert f.recoveries == 1
    assert np.all(np.isfinite(f.mean)) and np.all(np.isfinite(f.covariance))
    f.update(np.array([0.3]))
    assert np.all(np.isfinite(f.mean))
