"""Several predicts before one update sample the true process of a nonlinear model (the growth model).

predict(dt1), predict(dt2), update(y) must be the same as predict(dt1), update(NaN), predict(dt2),
update(y): the noise of the first interval goes through the second interval's nonlinear flow.
"""
import numpy as np
import pytest
from scipy import stats

from examples import growth_model
from gpf_nav.filters import BootstrapPF, GeometricProjectionPF

MODEL = growth_model.GrowthModel()
X0, NEAR_POINT = np.array([0.1]), np.array([[1e-8]])
Y = np.array([5.0])  # x^2 / 20 = 5: x near +-10
PARTICLE_FILTERS = {
    "bootstrap": lambda seed, n: BootstrapPF(MODEL, n, seed=seed),
    "GPF": lambda seed, n: GeometricProjectionPF(MODEL, n, seed=seed),
    "GPF corrected": lambda seed, n: GeometricProjectionPF(MODEL, n, weighting="corrected",
                                                            metric="process_noise", regularization=1.0,
                                                            seed=seed),
}


def true_process(n: int, seed: int) -> np.ndarray:
    """Plain Monte Carlo of x_2 ``(n,)`` from the near-point prior: two steps, noise in each."""
    rng = np.random.default_rng(seed)
    sd = np.sqrt(growth_model.PROCESS_VARIANCE)
    x = X0 + np.sqrt(NEAR_POINT[0, 0]) * rng.standard_normal((n, 1))
    for k in range(2):
        x = MODEL.transition(x, 1.0, float(k)) + sd * rng.standard_normal((n, 1))
    return x[:, 0]


@pytest.mark.parametrize("name", sorted(PARTICLE_FILTERS))
@pytest.mark.parametrize("y", [np.array([np.nan]), Y])
def test_two_predicts_then_update_equal_predict_update_nan_predict_update(name, y):
    a, b = PARTICLE_FILTERS[name](3, 500), PARTICLE_FILTERS[name](3, 500)
    for f in (a, b):
        f.initialize(X0, np.array([[4.0]]))
    a.predict(1.0)
    a.predict(1.0)
    a.update(y)
    b.predict(1.0)
    b.update(np.array([np.nan]))
    b.predict(1.0)
    b.update(y)
    np.testing.assert_allclose(a.particles, b.particles, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(a.weights, b.weights, rtol=1e-9)


@pytest.mark.parametrize("name", sorted(PARTICLE_FILTERS))
def test_two_predicts_sample_the_true_two_step_process(name):
    """Kolmogorov-Smirnov against plain Monte Carlo; the old behaviour (noise-free flow over both
    intervals, then the noise of the total interval) is rejected by the same test."""
    n = 4000
    f = PARTICLE_FILTERS[name](11, n)
    f.initialize(X0, NEAR_POINT)
    f.predict(1.0)
    f.predict(1.0)
    f.update(np.array([np.nan]))
    reference = true_process(n, seed=12)
    assert stats.ks_2samp(f.particles[:, 0], reference).pvalue > 0.01
    assert np.var(f.particles[:, 0]) == pytest.approx(np.var(reference), rel=0.1)
    rng = np.random.default_rng(13)
    flow = MODEL.transition(MODEL.transition(X0[None], 1.0, 0.0), 1.0, 1.0)[0, 0]
    old = flow + np.sqrt(2.0 * growth_model.PROCESS_VARIANCE) * rng.standard_normal(n)
    assert stats.ks_2samp(old, reference).pvalue < 1e-6


@pytest.mark.parametrize("name, mean_tolerance", [("bootstrap", 0.05), ("GPF corrected", 0.1)])
def test_posterior_after_two_predicts_and_an_update(name, mean_tolerance):
    """Weighted moments against importance sampling of the true process (400 000 draws). The GPF's
    proposal shifts only the last interval's noise, so its corrected weights stay exact; they are
    heavy-tailed here (log-normal, ESS ~ 0.13), hence the wider tolerance on its mean. (The paper's
    likelihood weights are not exact and are left out.)"""
    reference = true_process(400000, seed=21)
    w = np.exp(-0.5 * (Y[0] - reference ** 2 / 20.0) ** 2 / growth_model.MEASUREMENT_VARIANCE)
    w /= w.sum()
    ref_mean, ref_square = w @ reference, w @ reference ** 2
    f = PARTICLE_FILTERS[name](22, 20000)
    f.initialize(X0, NEAR_POINT)
    f.predict(1.0)
    f.predict(1.0)
    f.update(Y)
    x = f.particles[:, 0]
    assert f.weights @ x == pytest.approx(ref_mean, abs=mean_tolerance * np.sqrt(ref_square))
    assert f.weights @ x ** 2 == pytest.approx(ref_square, rel=0.03)
