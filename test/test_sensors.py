"""Sensors as objects: every filter updates with every sensor; the exact posterior of a linear sensor;
the model's own sensor is the default, bit for bit; sensor-bias states; a user's own sensor."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from examples import own_sensor
from gpf_nav.experiments.runner import make_filter
from gpf_nav.registry import label, short_names
from gpf_nav.filters import (BootstrapPF, EnsembleKF, ExtendedKF, GeometricProjectionPF, MultipleModelGPF,
                             SensorBiasFilter, UnscentedKF)
from gpf_nav.models import LinearGaussianModel, LunarDescentModel
from gpf_nav.models.lunar import MOON_RADIUS
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate
from gpf_nav.sensors import (AltitudeSensor, ModelSensor, PositionSensor, VelocitySensor, gauss_markov_bias,
                             random_constant_bias)
from gpf_nav.sensors.sensor import Padded

FILTER_NAMES = short_names()  # every filter of the experiments, by its short name
ORACLES = ("ekf-oracle", "ukf-oracle")


def _lunar_sensors(model):
    return [ModelSensor(model, "rae"), PositionSensor(50.0), VelocitySensor(0.5), AltitudeSensor(20.0)]


@pytest.mark.parametrize("name", [n for n in FILTER_NAMES if n not in ORACLES])
def test_every_filter_updates_with_every_sensor(name):
    """From a prior 1 km and 1 m/s off, one update with each sensor's noise-free measurement of the truth
    moves the estimate's predicted measurement towards it, and a NaN component is left out."""
    config = ScenarioConfig(duration=20.0)
    scenario = generate(config, 5)
    model = filter_model(config)
    truth = scenario.truth[1]
    for sensor in _lunar_sensors(model):
        flt = make_filter(label(name), model, 400, 3)
        flt.initialize(scenario.prior_mean, scenario.prior_cov)
        flt.predict(config.dt)
        y = sensor.measure(truth[None])[0]
        before = np.abs(sensor.residual(y, sensor.measure(np.asarray(flt.mean)[None])[0]))
        flt.update(y, sensor)
        mean = np.asarray(flt.mean)
        assert mean.shape == (6,) and np.isfinite(mean).all() and np.isfinite(flt.covariance).all()
        after = np.abs(sensor.residual(y, sensor.measure(mean[None])[0]))
        scale = np.sqrt(np.diag(sensor.noise()))
        assert np.all((after < 0.7 * before) | (after < 3.0 * scale)), (sensor.name, before, after)
        if sensor.dim > 1:  # a component not measured
            y[0] = np.nan
            flt.update(y, sensor)
            assert np.isfinite(np.asarray(flt.mean)).all()
        with pytest.raises(ValueError):
            flt.update(np.zeros(sensor.dim + 1), sensor)


def _cv_model() -> LinearGaussianModel:
    """3-D constant velocity, state [position, velocity], white acceleration; its own sensor measures x."""
    A = np.zeros((6, 6))
    A[:3, 3:] = np.eye(3)
    G = np.vstack([np.zeros((3, 3)), 0.3 * np.eye(3)])
    C = np.zeros((1, 6))
    C[0, 0] = 1.0
    return LinearGaussianModel(A, G, C, [[4.0]])


def _prior():
    rng = np.random.default_rng(0)
    L = np.tril(rng.normal(size=(6, 6))) * 0.5 + np.diag([2.0, 2.0, 2.0, 0.5, 0.5, 0.5])
    return rng.normal(size=6), L @ L.T


def _exact_position_update(model, mean, cov, y, R, dt):
    F, _, Q = model.discretise(dt)
    m, P = F @ mean, F @ cov @ F.T + Q
    H = np.hstack([np.eye(3), np.zeros((3, 3))])
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    return m + K @ (y - H @ m), P - K @ S @ K.T


KNOWN_ANSWER = {
    "EKF": lambda m, s: ExtendedKF(m, seed=s),
    "UKF": lambda m, s: UnscentedKF(m, seed=s),
    "EnKF": lambda m, s: EnsembleKF(m, 4000, seed=s),
    "SPF": lambda m, s: BootstrapPF(m, 4000, seed=s),
    "GPF": lambda m, s: GeometricProjectionPF(m, 4000, seed=s),
    "GPF-MM": lambda m, s: MultipleModelGPF(m, 4000, seed=s),
}


@pytest.mark.parametrize("name", KNOWN_ANSWER)
def test_position_sensor_against_the_exact_posterior(name):
    """Linear-Gaussian model, a correlated prior, one prediction and one position fix: the Kalman filters
    give the exact posterior; the ensemble and particle filters come close (over two seeds)."""
    model = _cv_model()
    mean, cov = _prior()
    R = np.array([[1.5, 0.3, 0.0], [0.3, 1.0, 0.2], [0.0, 0.2, 2.0]])
    sensor = PositionSensor(R)
    y = np.array([1.0, -2.0, 0.5])
    exact_mean, exact_cov = _exact_position_update(model, mean, cov, y, R, 1.0)
    std = np.sqrt(np.diag(exact_cov))
    for seed in (1, 2):
        flt = KNOWN_ANSWER[name](model, seed)
        flt.initialize(mean, cov)
        flt.predict(1.0)
        flt.update(y, sensor)
        got_mean, got_cov = np.asarray(flt.mean), np.asarray(flt.covariance)
        if name in ("EKF", "UKF"):
            np.testing.assert_allclose(got_mean, exact_mean, rtol=0, atol=1e-9)
            np.testing.assert_allclose(got_cov, exact_cov, rtol=0, atol=1e-9)
            continue
        assert np.all(np.abs(got_mean - exact_mean) < 0.12 * std), (got_mean - exact_mean) / std
        ratio = np.diag(got_cov) / np.diag(exact_cov)
        assert np.all(np.abs(ratio - 1.0) < 0.15), ratio


@pytest.mark.parametrize("name", ["spf", "ekf", "ukf", "enkf", "gpf-paper", "gpf-printed", "gpf-exact",
                                  "gpf-qmetric", "gpf", "ekf-comp", "gpf-single"])
def test_the_models_own_sensor_is_the_default_bit_for_bit(name):
    """``update(y, ModelSensor(model))`` gives exactly ``update(y)``."""
    config = ScenarioConfig(duration=40.0, case="partial")
    scenario = generate(config, 2)
    model = filter_model(config)
    runs = []
    for sensor in (None, ModelSensor(model, "rae")):
        flt = make_filter(label(name), model, 200, 4)
        flt.initialize(scenario.prior_mean, scenario.prior_cov)
        trace = []
        for k in range(len(scenario.times)):
            flt.predict(config.dt, scenario.specific_force[k])
            flt.update(scenario.measurements[k], sensor)
            trace.append(np.concatenate([np.ravel(flt.mean), np.ravel(flt.covariance)]))
        runs.append(np.array(trace))
    assert np.array_equal(runs[0], runs[1])


def test_a_padded_sensor_takes_the_wrapped_sensors_own_residual_of_the_users_state():
    """A compensated filter's update with a user's sensor computes what the sensor computes for the user's
    state (its one-pass residual, not the model's measurement and residual in turn)."""
    model = LunarDescentModel(station=(1.7e6, 1e3, 2e3))
    calls = []

    class Counted(ModelSensor):
        def measurement_residual(self, y, x, t=0.0, reverse=False):
            calls.append(x.shape)
            return super().measurement_residual(y, x, t, reverse)

    x = np.random.default_rng(3).standard_normal((50, 9)) * 1e3 + [1.8e6, 0, 0, 0, 1.6e3, 0, 0, 0, 0]
    y = np.array([1.0e5, 0.1, 0.2])
    got = Padded(Counted(model, "rae"), 6, 9).measurement_residual(y, x, 0.0, True)
    assert calls == [(50, 6)]
    np.testing.assert_array_equal(got, model.measurement_residual(y, np.ascontiguousarray(x[:, :6]), 0.0, True))


def test_altitude_jacobian_and_sensor_checks():
    sensor = AltitudeSensor(10.0)
    assert sensor.reference_radius == pytest.approx(1737.4e3)
    x = np.array([[MOON_RADIUS + 15e3, 2e3, -1e3, 1.0, 2.0, 3.0], [1.8e6, 1e5, 2e5, 0.0, 0.0, 0.0]])
    h, H = sensor.measure_and_jacobian(x)
    np.testing.assert_allclose(h[:, 0], np.linalg.norm(x[:, :3], axis=1) - MOON_RADIUS)
    step = 1.0
    numeric = np.stack([(sensor.measure(x + step * e) - sensor.measure(x - step * e))[:, 0] / (2 * step)
                        for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(H[:, 0], numeric, atol=1e-7)
    assert VelocitySensor(0.1).measure(x).tolist() == x[:, 3:].tolist()
    fix = PositionSensor(3.0)
    np.testing.assert_allclose(fix.with_noise(np.diag([1.0, 4.0, 9.0])).noise(), np.diag([1.0, 4.0, 9.0]))
    assert fix.noise()[0, 0] == 9.0  # with_noise returns a copy
    for bad in (0.0, -1.0, np.nan, [[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]], np.eye(2)):
        with pytest.raises(ValueError):
            PositionSensor(bad)


# --- bias states ---------------------------------------------------------------------------------------
BIAS_FILTERS = {
    "EKF": lambda m: ExtendedKF(m, seed=0),
    "UKF": lambda m: UnscentedKF(m, seed=0),
    "EnKF": lambda m: EnsembleKF(m, 500, seed=0),
    "GPF": lambda m: GeometricProjectionPF(m, 500, seed=0),
    "GPF-MM": lambda m: MultipleModelGPF(m, 500, seed=0),
    "SPF": lambda m: BootstrapPF(m, 2000, seed=0),
}
KINDS = {"constant": random_constant_bias([5.0, 5.0, 5.0]),
         "gauss-markov": gauss_markov_bias([5.0, 5.0, 5.0], 1e5),
         "gauss-markov 200 s": gauss_markov_bias([5.0, 5.0, 5.0], 200.0)}


@pytest.mark.parametrize("name, kind", [(n, k) for n in BIAS_FILTERS for k in KINDS
                                        if (n == "SPF") == (k == "gauss-markov 200 s")])
def test_every_filter_estimates_a_sensor_bias(name, kind):
    """A position fix biased by [4, -3, 0] m and an unbiased one of the same quality: the filter learns
    the bias (within 3 sigma of the truth, sigma under 1 m) and its position is not pulled by it.

    The bootstrap PF never renews its particles' bias values (its proposal is the prior transition):
    it is given a Gauss-Markov bias whose noise does (docs/filters.md)."""
    model = _cv_model()
    bias = KINDS[kind]
    biased = PositionSensor(1.0, name="trn", bias=bias)
    plain = PositionSensor(1.0)
    flt = SensorBiasFilter(BIAS_FILTERS[name], model, [biased, plain])
    true_bias = np.array([4.0, -3.0, 0.0])
    rng = np.random.default_rng(1)
    F, _, Q = model.discretise(1.0)
    x = np.zeros(6)
    flt.initialize(x + rng.normal(size=6), np.eye(6))
    for _ in range(40):
        x = F @ x + rng.multivariate_normal(np.zeros(6), Q)
        flt.predict(1.0)
        flt.update(x[:3] + true_bias + rng.normal(size=3), biased)
        flt.update(x[:3] + rng.normal(size=3), plain)
    b, s = flt.sensor_bias("trn")
    assert flt.mean.shape == (6,) and flt.covariance.shape == (6, 6)
    assert np.all(s < 1.0) and np.all(s > 0.0), s
    assert np.all(np.abs(b - true_bias) < 3.0 * s + 0.1), (b, s)
    assert np.linalg.norm(flt.mean[:3] - x[:3]) < 2.0
    with pytest.raises(KeyError):
        flt.sensor_bias("position")


def test_a_bias_on_the_models_own_sensor():
    """The lunar model's range biased by +60 m (2 sigma), with the model's own sensor declared biased:
    an EKF and the default GPF learn the bias from position fixes."""
    config = ScenarioConfig(duration=200.0)
    scenario = generate(config, 3)
    model = filter_model(config)
    rae = ModelSensor(model, "rae", bias=random_constant_bias([60.0, 0.0, 0.0]))
    fix = PositionSensor(20.0)
    rng = np.random.default_rng(2)
    for build in (lambda m: ExtendedKF(m, seed=0), lambda m: GeometricProjectionPF(m, 300, seed=0)):
        flt = SensorBiasFilter(build, model, [rae])
        flt.initialize(scenario.prior_mean, scenario.prior_cov)
        for k in range(len(scenario.times)):
            flt.predict(config.dt)
            y = scenario.measurements[k] + np.array([60.0, 0.0, 0.0])
            flt.update(y)
            flt.update(scenario.truth[k + 1, :3] + 20.0 * rng.standard_normal(3), fix)
        b, s = flt.sensor_bias("rae")
        assert s[1] == s[2] == 0.0 and 0.0 < s[0] < 30.0
        assert abs(b[0] - 60.0) < 3.0 * s[0], (b, s)


def test_a_users_own_sensor_example():
    """docs/examples/own_sensor.py: a beacon range of 5 m fused with rae improves the position."""
    with_beacon, without = own_sensor.run("gpf", steps=40)
    assert with_beacon < 0.5 * without
    assert math.isfinite(with_beacon)


def test_a_constant_range_bias_of_two_sigma_estimated_on_the_descent():
    """The paper's descent with a +2 sigma (60 m) range bias, two paired runs of the default GPF: ignored,
    the bias makes the filter inconsistent (NEES far above 6); estimated as a constant of prior std
    3 sigma on the model's own sensor, the mean NEES of the six states lies in [2, 15] and the position
    RMSE is within 1.2 times that of the unbiased run."""
    from gpf_nav.experiments.runner import run_filter, run_seeds

    base = ScenarioConfig()
    biased = dataclasses.replace(base, measurement_bias_sigma=(2.0, 0.0, 0.0))
    model = filter_model(base)
    name = label("gpf")
    rae = ModelSensor(model, "rae", bias=random_constant_bias([3.0 * base.range_noise_std, 0.0, 0.0]))
    for run in range(2):
        scenario_seed, filter_seed = run_seeds(0, run)
        unbiased = run_filter(make_filter(name, model, 500, filter_seed), generate(base, scenario_seed))
        ignored = run_filter(make_filter(name, model, 500, filter_seed), generate(biased, scenario_seed))
        flt = SensorBiasFilter(lambda m: make_filter(name, m, 500, filter_seed), model, [rae])
        estimated = run_filter(flt, generate(biased, scenario_seed))
        assert ignored["nees"] > 50.0
        assert 2.0 <= estimated["nees"] <= 15.0, estimated["nees"]
        assert estimated["position_rmse"] <= 1.2 * unbiased["position_rmse"]
        bias, sigma = flt.sensor_bias("rae")
        assert abs(bias[0] - 60.0) < 3.0 * sigma[0]


def test_bias_declarations_are_checked():
    from gpf_nav.sensors import Bias, SensorBiasModel

    model = _cv_model()
    with pytest.raises(ValueError, match="non-negative"):
        random_constant_bias([-1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="correlation times"):
        gauss_markov_bias(1.0, 0.0)
    with pytest.raises(ValueError, match="two biased sensors"):
        SensorBiasModel(model, [PositionSensor(1.0, bias=random_constant_bias(1.0 * np.ones(3))),
                                PositionSensor(2.0, bias=random_constant_bias(1.0 * np.ones(3)))])
    with pytest.raises(ValueError, match="bias has 1 components, the sensor 3"):
        SensorBiasModel(model, [PositionSensor(1.0, bias=random_constant_bias(1.0))])
    augmented = SensorBiasModel(model, [PositionSensor(1.0, bias=Bias((0.0, 2.0, 0.0), (50.0,))),
                                        VelocitySensor(0.1)])
    assert augmented.state_dim == 7 and list(augmented.blocks) == ["position"]
    # the Gauss-Markov state's transition and noise over 10 s keep its stationary variance 4
    decay = augmented.transition_jacobian(np.zeros((1, 7)), 10.0)[0, 6, 6]
    assert decay == pytest.approx(math.exp(-10.0 / 50.0))
    assert decay ** 2 * 4.0 + augmented.process_noise(10.0)[6, 6] == pytest.approx(4.0)
    with pytest.raises(ValueError, match="has 1 components, its bias states 3"):
        augmented.lift(AltitudeSensor(1.0, name="position"))


def test_innovation_distance_of_a_fix():
    from gpf_nav.sensors import innovation_distance

    mean, cov = _prior()
    R = np.diag([1.0, 2.0, 3.0])
    y = mean[:3] + np.array([1.0, -2.0, 0.5])
    r = y - mean[:3]
    d2, k = innovation_distance(PositionSensor(np.sqrt(np.diag(R))), y, mean, cov)
    assert k == 3 and d2 == pytest.approx(r @ np.linalg.solve(cov[:3, :3] + R, r))
    y[1] = np.nan
    d2, k = innovation_distance(PositionSensor(np.sqrt(np.diag(R))), y, mean, cov)
    keep = [0, 2]
    S = (cov[:3, :3] + R)[np.ix_(keep, keep)]
    assert k == 2 and d2 == pytest.approx(r[keep] @ np.linalg.solve(S, r[keep]))
    assert innovation_distance(PositionSensor(1.0), np.full(3, np.nan), mean, cov) == (0.0, 0)
