"""Likelihood tempering of the GPF (progressive correction): a large prior against a precise measurement
keeps the cloud alive, and a tempered update is still the exact posterior of a linear-Gaussian model."""
import numpy as np
import pytest

from gpf_nav.filters import GeometricProjectionPF, MultipleModelGPF
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

from linear_reference import constant_velocity_model, kalman, simulate


def _first_update(tempering_ess, seed):
    config = ScenarioConfig(duration=20.0, prior_position_std=20e3, prior_velocity_std=20.0)
    scenario = generate(config, seed)
    f = GeometricProjectionPF(filter_model(config), 500, seed=seed, tempering_ess=tempering_ess)
    f.initialize(scenario.prior_mean, scenario.prior_cov)
    f.predict(config.dt, scenario.specific_force[0])
    f.update(scenario.measurements[0])
    error = np.linalg.norm(f.mean[:3] - scenario.truth[0, :3])
    return f, error


@pytest.mark.parametrize("seed", [3, 4])
def test_a_large_prior_is_tempered_instead_of_collapsing(seed):
    """Prior 20 km / 20 m/s, range/az/el to 30 m: the one-stage update leaves a few effective particles;
    the tempered one several stages with at least a tenth of the particles effective, and an estimate at
    least as close to the truth."""
    plain, plain_error = _first_update(0.0, seed)
    tempered, tempered_error = _first_update(0.1, seed)
    assert plain.tempering_stages == 1 and plain.ess < 0.05, plain.ess
    assert tempered.tempering_stages > 1 and tempered.tempered_updates == 1
    assert tempered.ess >= 0.1, tempered.ess
    assert tempered_error < max(plain_error, 3e3), (tempered_error, plain_error)
    assert np.isfinite(tempered.last_log_likelihood)
    np.linalg.cholesky(tempered.covariance)


def test_tempered_updates_are_the_exact_linear_gaussian_posterior():
    """Forced to temper almost every update (tempering_ess 0.999) on a wide prior and a precise sensor,
    the GPF's mean and covariance stay those of the Kalman filter (Monte Carlo tolerance)."""
    model = constant_velocity_model(accel_std=0.5, meas_std=0.1)
    mean, cov, dt = np.zeros(2), np.diag([100.0 ** 2, 10.0 ** 2]), 1.0
    ys = simulate(model, [30.0, -2.0], 8, dt, seed=5)
    exact = kalman(model, mean, cov, ys, dt)
    f = GeometricProjectionPF(model, 4000, seed=1, unmodelled_acceleration_std=0.0, tempering_ess=0.999)
    f.initialize(mean, cov)
    stages = []
    for y, (m, P) in zip(ys, exact):
        f.predict(dt)
        f.update(y)
        stages.append(f.tempering_stages)
        std = np.sqrt(np.diag(P))
        assert np.all(np.abs(f.mean - m) < 0.15 * std), (f.mean - m) / std
        assert np.all(np.abs(np.diag(f.covariance) / np.diag(P) - 1.0) < 0.25), np.diag(f.covariance) / np.diag(P)
    assert max(stages) > 1, stages


def test_tempering_is_off_for_the_paper_metrics_and_on_by_default():
    model = constant_velocity_model()
    assert GeometricProjectionPF(model).tempering_ess == 0.1
    assert GeometricProjectionPF(model, metric="euclidean").tempering_ess == 0.0
    with pytest.raises(ValueError, match="tempering_ess needs metric 'cloud'"):
        GeometricProjectionPF(model, metric="euclidean", tempering_ess=0.1)
    with pytest.raises(ValueError, match="tempering_ess"):
        GeometricProjectionPF(model, tempering_ess=1.0)
    imm = MultipleModelGPF(model, 100, seed=0)
    gpfs = [m for m in imm.members if isinstance(m, GeometricProjectionPF)]  # (the narrow EKFs do not temper)
    assert len(gpfs) == 2 and all(m.tempering_ess == 0.1 for m in gpfs) and imm.tempered_updates == 0
