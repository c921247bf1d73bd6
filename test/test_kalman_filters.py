"""Tests of the EKF, UKF and EnKF against an independent textbook Kalman filter and on angle wrapping."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from gpf_nav.filters.ensemble import EnsembleKF
from gpf_nav.filters.kalman import ExtendedKF, UnscentedKF
from gpf_nav.models.linear import LinearGaussianModel
from gpf_nav.models.lunar import MOON_RADIUS, LunarDescentModel

N_STEPS = 50


def constant_velocity_model() -> LinearGaussianModel:
    """2-D constant velocity, state ``[px, py, vx, vy]``, positions measured with correlated noise."""
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    G = np.zeros((4, 2))
    G[2, 0], G[3, 1] = 0.3, 0.5
    C = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    R = np.array([[0.25, 0.1], [0.1, 0.64]])
    return LinearGaussianModel(A, G, C, R)


PRIOR_MEAN = np.array([1.0, -2.0, 0.5, 0.3])
PRIOR_COV = np.diag([4.0, 9.0, 1.0, 0.25])


def simulate(model: LinearGaussianModel, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """``N_STEPS`` steps of ``(dt, y)`` with varying ``dt``, partial (one NaN) and missing (all NaN) y."""
    rng = np.random.default_rng(seed)
    x = rng.multivariate_normal(PRIOR_MEAN, PRIOR_COV)
    dts = rng.choice([0.1, 0.5, 1.0], size=N_STEPS)
    ys = np.empty((N_STEPS, model.measurement_dim))
    for k, dt in enumerate(dts):
        F, _, Q = model.discretise(dt)
        x = F @ x + rng.multivariate_normal(np.zeros(4), Q)
        ys[k] = model.C @ x + rng.multivariate_normal(np.zeros(2), model.R)
        if k % 3 == 1:
            ys[k, 0] = np.nan
        if k % 7 == 2:
            ys[k, 1] = np.nan
        if k % 11 == 5:
            ys[k] = np.nan
    assert np.isnan(ys).any(axis=1).sum() > 10 and np.isnan(ys).all(axis=1).any()
    return dts, ys


def reference_kalman(model: LinearGaussianModel, mean, cov, dts, ys):
    """Textbook Kalman filter written from scratch; yields ``(mean, cov, log-likelihood)`` per step."""
    x, P = np.array(mean, float), np.array(cov, float)
    for dt, y in zip(dts, ys):
        F, _, Q = model.discretise(dt)
        x = F @ x
        P = F @ P @ F.T + Q
        seen = np.isfinite(y)
        log_lik = 0.0
        if seen.any():
            H = model.C[seen]
            R = model.R[np.ix_(seen, seen)]
            S = H @ P @ H.T + R
            K = np.linalg.solve(S, H @ P).T
            innovation = y[seen] - H @ x
            log_lik = multivariate_normal(np.zeros(seen.sum()), S).logpdf(innovation)
            x = x + K @ innovation
            P = (np.eye(4) - K @ H) @ P
            P = 0.5 * (P + P.T)
        yield x, P, log_lik


def run(filt, dts, ys):
    """Yield ``(mean, covariance, last_log_likelihood)`` after each predict + update."""
    for dt, y in zip(dts, ys):
        filt.predict(dt)
        filt.update(y)
        yield filt.mean.copy(), filt.covariance.copy(), filt.last_log_likelihood


def rel_err(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize("make", [
    lambda m: ExtendedKF(m),
    lambda m: UnscentedKF(m),  # alpha = 1e-3: central weight ~ -2.7e5
    lambda m: UnscentedKF(m, alpha=0.7, beta=2.0, kappa=1.0),
], ids=["ekf", "ukf-default", "ukf-wide"])
@pytest.mark.parametrize("prior_cov", [PRIOR_COV, np.diag([4.0, 1e-20, 1.0, 1e-20])],
                         ids=["regular", "near-singular"])
def test_gaussian_filters_equal_textbook_kalman_on_linear_model(make, prior_cov):
    model = constant_velocity_model()
    dts, ys = simulate(model)
    filt = make(model)
    filt.initialize(PRIOR_MEAN, prior_cov)
    steps = zip(run(filt, dts, ys), reference_kalman(model, PRIOR_MEAN, prior_cov, dts, ys))
    for k, ((m, P, ll), (m_ref, P_ref, ll_ref)) in enumerate(steps):
        assert rel_err(m, m_ref) < 1e-8, k
        assert rel_err(P, P_ref) < 1e-8, k
        assert ll == pytest.approx(ll_ref, rel=1e-8, abs=1e-10), k
        assert np.array_equal(P, P.T)
    assert filt.time == pytest.approx(dts.sum())


def test_ensemble_kf_matches_textbook_kalman_within_sampling_error():
    """EnKF with N = 20000 members against the exact Kalman filter, within sampling error.

    Mean: the EnKF error ``e = m_EnKF - m_KF`` follows the Kalman error recursion driven by the sampling
    noise of the prior draw (``P0/N``), the process-noise draws (``Q/N``) and the observation
    perturbations (``R/N``), which alone give ``cov(e) = P_KF / N``, plus the gain's sampling error times
    the innovation, of the same order. So ``z = e_i / sqrt(P_KF,ii / N)`` has a standard deviation
    ~ sqrt(2): 1.4-1.6 measured over 12 seeds at N = 20000 (40 at N = 2000). The bound |z| < 8 is
    > 5 of those standard deviations, so the 200 correlated checks fail by chance with probability
    ~ 1e-5, yet it is 6 % of the posterior standard deviation, far below what a wrong gain would cost.

    Covariance: a sample covariance of N Gaussian draws has standard error
    ``sqrt((P_ij^2 + P_ii P_jj) / N)``; the standardised EnKF covariance errors measured ~ 1.0 standard
    deviation (errors do not pile up over steps), so the bound is 6 standard errors (~ 6 % of a variance).

    Log-likelihood: relative errors ~ sqrt(2 / N) in ``S`` and ~ sqrt(P / N) in the innovation move it by
    ~ 0.02 (at most 0.065 measured); the bound is 0.2 nats.
    """
    n_members = 20000
    model = constant_velocity_model()
    dts, ys = simulate(model)
    filt = EnsembleKF(model, n_particles=n_members, seed=3)
    filt.initialize(PRIOR_MEAN, PRIOR_COV)
    steps = zip(run(filt, dts, ys), reference_kalman(model, PRIOR_MEAN, PRIOR_COV, dts, ys))
    for k, ((m, P, ll), (m_ref, P_ref, ll_ref)) in enumerate(steps):
        sd = np.sqrt(np.diag(P_ref))
        assert np.all(np.abs(m - m_ref) < 8.0 * sd / np.sqrt(n_members)), k
        cov_se = np.sqrt((P_ref ** 2 + np.outer(sd ** 2, sd ** 2)) / n_members)
        assert np.all(np.abs(P - P_ref) < 6.0 * cov_se), k
        assert abs(ll - ll_ref) < 0.2, k
    assert filt.particles.shape == (n_members, 4)


def test_ensemble_kf_same_seed_is_bit_identical():
    model = constant_velocity_model()
    dts, ys = simulate(model)
    outputs = []
    for seed in (11, 11, 12):
        filt = EnsembleKF(model, n_particles=300, seed=seed)
        filt.initialize(PRIOR_MEAN, PRIOR_COV)
        history = [np.concatenate([m, P.ravel(), [ll]]) for m, P, ll in run(filt, dts, ys)]
        outputs.append(np.concatenate(history + [filt.particles.ravel()]))
    assert np.array_equal(outputs[0], outputs[1])
    assert not np.array_equal(outputs[0], outputs[2])


def textbook_ukf(model, x, P, dt, ys, alpha, beta, kappa):
    """Scaled unscented Kalman filter written directly from the weighted sums; yields ``(mean, cov)``."""
    n = x.shape[0]
    lam = alpha ** 2 * (n + kappa) - n
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wm[0] = lam / (n + lam)
    wc = wm.copy()
    wc[0] += 1.0 - alpha ** 2 + beta
    ang = model.angular

    def points(x, P):
        L = np.linalg.cholesky((n + lam) * P)
        return np.vstack([x, x + L.T, x - L.T])

    for y in ys:
        X = model.transition(points(x, P), dt)
        x = wm @ X
        P = (X - x).T @ np.diag(wc) @ (X - x) + model.process_noise(dt)
        X = points(x, P)
        Z = model.measure(X)
        z = wm @ Z
        z[ang] = np.arctan2(wm @ np.sin(Z[:, ang]), wm @ np.cos(Z[:, ang]))
        dZ = Z - z
        dZ[:, ang] = np.angle(np.exp(1j * dZ[:, ang]))
        r = y - z
        r[ang] = np.angle(np.exp(1j * r[ang]))
        seen = np.isfinite(y)
        dZ, r = dZ[:, seen], r[seen]
        S = dZ.T @ np.diag(wc) @ dZ + model.measurement_noise()[np.ix_(seen, seen)]
        K = np.linalg.solve(S, dZ.T @ np.diag(wc) @ (X - x)).T
        x = x + K @ r
        P = P - K @ S @ K.T
        yield x, P


def test_unscented_kf_equals_textbook_sums_on_a_nonlinear_model():
    """Lunar model observed from a station ~1 km away: strongly nonlinear, angles spread ~0.1 rad.

    With ``alpha = 0.5`` the textbook sums do not cancel, so they are an exact reference for the UKF's
    rearranged sums, its circular measurement mean and its ``(beta - alpha^2)`` central-point term.
    """
    x0 = np.array([MOON_RADIUS + 15000.0, 1000.0, 2000.0, 10.0, -20.0, 5.0])
    model = LunarDescentModel(station=x0[:3] - np.array([1000.0, 100.0, 200.0]))
    P0 = np.diag([100.0, 100.0, 100.0, 1.0, 1.0, 1.0]) ** 2
    truth = x0 + np.array([50.0, -80.0, 30.0, 0.5, -0.3, 0.1])
    ys = []
    for k in range(6):
        truth = model.transition(truth[None], 1.0)[0]
        ys.append(model.measure(truth[None])[0] + np.array([20.0, 0.02, -0.01]))
        if k == 3:
            ys[-1][0] = np.nan
    filt = UnscentedKF(model, alpha=0.5, beta=2.0, kappa=1.0)
    filt.initialize(x0, P0)
    for y, (m_ref, P_ref) in zip(ys, textbook_ukf(model, x0, P0, 1.0, ys, 0.5, 2.0, 1.0)):
        filt.predict(1.0)
        filt.update(y)
        assert rel_err(filt.mean - x0, m_ref - x0) < 1e-9
        assert rel_err(filt.covariance, P_ref) < 1e-9


# --- angle wrapping on the lunar model ------------------------------------------------------------------
FLIP = np.diag([-1.0, -1.0, 1.0, -1.0, -1.0, 1.0])  # rotation by pi about z, acting on [r, v]


def lunar_wrap_case(flip: bool):
    """Prior just below the azimuth cut (predicted azimuth ~ -pi), truth just above (measured ~ +pi).

    With ``flip`` the whole scene is rotated by pi about z: azimuths near 0, nothing to wrap.
    """
    model = LunarDescentModel()
    prior = np.array([-(MOON_RADIUS + 15000.0), -0.1, 2000.0, 5.0, 0.05, -30.0])
    truth = prior + np.array([20.0, 1500.0, -30.0, 0.5, 0.0, 0.2])  # azimuth 1.6 sigma off
    cov = np.diag([100.0, 100.0, 100.0, 1.0, 1.0, 1.0]) ** 2
    if flip:
        prior, truth = FLIP @ prior, FLIP @ truth
    y = model.measure(truth[None])[0]
    return model, prior, cov, y


def test_lunar_wrap_case_straddles_the_cut():
    model, prior, _, y = lunar_wrap_case(flip=False)
    predicted = model.measure(prior[None])[0]
    assert y[1] > np.pi - 1e-3 and predicted[1] < -np.pi + 1e-6
    assert abs(model.residual(y, predicted)[1]) < 1e-3


@pytest.mark.parametrize("make", [
    lambda m: ExtendedKF(m),
    lambda m: UnscentedKF(m),
    lambda m: UnscentedKF(m, alpha=1.0),  # sigma points ~245 m apart: they straddle the cut too
], ids=["ekf", "ukf-default", "ukf-wide"])
def test_gaussian_filters_wrap_azimuth(make):
    """Near +-pi the update equals the rotated update of the same scene near 0 (no wrapping there)."""
    results = []
    for flip in (False, True):
        model, prior, cov, y = lunar_wrap_case(flip)
        filt = make(model)
        filt.initialize(prior, cov)
        filt.update(y)
        assert np.isfinite(filt.last_log_likelihood) and filt.last_log_likelihood > -50.0
        results.append((filt.mean - prior, filt.covariance.copy(), filt.last_log_likelihood))
    (step, P, ll), (step_flipped, P_flipped, ll_flipped) = results
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(step) < 3.0 * sd)  # a small innovation moves the mean a little
    assert step[1] > 5.0  # ... but it does move it, towards the measured side of the cut (+y)
    np.testing.assert_allclose(step / sd, FLIP @ step_flipped / sd, atol=1e-6)
    np.testing.assert_allclose(P, FLIP @ P_flipped @ FLIP, rtol=1e-6, atol=1e-9 * P.max())
    assert ll == pytest.approx(ll_flipped, rel=1e-6)


def test_ensemble_kf_wraps_azimuth():
    """Members on both sides of the cut: the update still matches the EKF's within sampling error."""
    model, prior, cov, y = lunar_wrap_case(flip=False)
    enkf = EnsembleKF(model, n_particles=4000, seed=5)
    enkf.initialize(prior, cov)
    azimuths = model.measure(enkf.particles)[:, 1]
    assert (azimuths > 3.0).mean() > 0.3 and (azimuths < -3.0).mean() > 0.3
    enkf.update(y)
    ekf = ExtendedKF(model)
    ekf.initialize(prior, cov)
    ekf.update(y)
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.isfinite(enkf.particles))
    assert enkf.last_log_likelihood > -50.0
    # EnKF mean error in units of sqrt(P_prior / N): standard deviation <= 1.2 measured over 30 seeds
    # (one update), so 6 is > 5 standard deviations; an unwrapped azimuth would miss by orders of magnitude.
    assert np.all(np.abs(enkf.mean - ekf.mean) < 6.0 * sd / np.sqrt(4000))


# --- degenerate covariances, no-ops and input checks ---------------------------------------------------
FILTERS = [
    lambda m: ExtendedKF(m),
    lambda m: UnscentedKF(m),
    lambda m: EnsembleKF(m, n_particles=200, seed=0),
]
FILTER_IDS = ["ekf", "ukf", "enkf"]


@pytest.mark.parametrize("make", FILTERS, ids=FILTER_IDS)
@pytest.mark.parametrize("cov", [
    np.diag([1e-20, 1e-20, 1e-20, 1e-20, 1e-20, 1e-20]),
    np.diag([1e-20, 1e4, 1e-20, 1e-20, 1.0, 1e-20]),
    np.zeros((6, 6)),
    np.outer([100.0, 50.0, 0.0, 1.0, 0.0, 0.0], [100.0, 50.0, 0.0, 1.0, 0.0, 0.0]),  # rank one
], ids=["tiny", "mixed", "zero", "rank-one"])
def test_singular_covariance_stays_finite_on_lunar_model(make, cov):
    model = LunarDescentModel()
    truth = np.array([MOON_RADIUS + 15000.0, 1000.0, 2000.0, 10.0, -1600.0, 5.0])
    filt = make(model)
    filt.initialize(truth, cov)
    for k in range(5):
        truth = model.transition(truth[None], 1.0)[0]
        filt.predict(1.0)
        y = model.measure(truth[None])[0] + np.array([10.0, 1e-4, -1e-4])
        if k == 2:
            y[0] = np.nan
        filt.update(y)
        assert np.all(np.isfinite(filt.mean)) and np.all(np.isfinite(filt.covariance))
        assert np.isfinite(filt.last_log_likelihood)
        assert np.linalg.eigvalsh(filt.covariance).min() > -1e-9 * max(1.0, np.abs(filt.covariance).max())


@pytest.mark.parametrize("make", FILTERS, ids=FILTER_IDS)
def test_zero_dt_and_unmeasured_update_are_no_ops(make):
    model = LunarDescentModel()
    filt = make(model)
    filt.initialize(np.array([MOON_RADIUS + 15000.0, 1000.0, 2000.0, 10.0, -1600.0, 5.0]),
                    np.diag([100.0, 100.0, 100.0, 1.0, 1.0, 1.0]) ** 2)
    filt.predict(1.0)
    filt.update(model.measure(filt.mean[None])[0] + 5.0)
    assert filt.last_log_likelihood != 0.0
    mean, cov, time = filt.mean.copy(), filt.covariance.copy(), filt.time
    filt.predict(0.0)
    filt.update(np.full(3, np.nan))
    assert filt.last_log_likelihood == 0.0
    assert np.array_equal(filt.mean, mean) and np.array_equal(filt.covariance, cov) and filt.time == time


@pytest.mark.parametrize("make", FILTERS, ids=FILTER_IDS)
@pytest.mark.parametrize("y", [np.zeros(2), np.zeros(4), np.zeros((3, 1)), np.zeros((1, 3)), 1.0],
                         ids=["short", "long", "column", "row", "scalar"])
def test_malformed_measurement_raises(make, y):
    model = LunarDescentModel()
    filt = make(model)
    filt.initialize(np.array([MOON_RADIUS, 0.0, 0.0, 0.0, 1600.0, 0.0]), np.eye(6))
    with pytest.raises(ValueError):
        filt.update(y)


@pytest.mark.parametrize("make", FILTERS, ids=FILTER_IDS)
def test_estimates_are_read_only_and_initialize_is_required(make):
    model = constant_velocity_model()
    filt = make(model)
    with pytest.raises(RuntimeError):
        filt.predict(1.0)
    filt.initialize(PRIOR_MEAN, PRIOR_COV)
    for estimate in [filt.mean, filt.covariance] + ([filt.particles] if isinstance(filt, EnsembleKF) else []):
        with pytest.raises(ValueError):
            estimate[0] = 1.0
    with pytest.raises(ValueError):
        filt.predict(-1.0)
