"""Unmodelled-acceleration compensation: the augmented model against its exact linear-Gaussian form, and
the compensated filters (EKF, default GPF) against the Kalman filter of the augmented model."""
import numpy as np
import pytest

from gpf_nav.filters import CompensatedEKF, ExtendedKF, GeometricProjectionPF
from gpf_nav.filters.model_averaging import mixture_moments
from gpf_nav.models import LinearGaussianModel, LunarDescentModel
from gpf_nav.models.lunar import MOON_RADIUS, MU_MOON
from gpf_nav.models.compensation import ModelErrorCompensation
from linear_reference import kalman, simulate

TAU, SIGMA = 50.0, 0.3


def constant_velocity():
    """1-D constant velocity, position measured; declares its position and velocity."""
    model = LinearGaussianModel(A=[[0.0, 1.0], [0.0, 0.0]], G=[[0.0], [0.1]], C=[[1.0, 0.0]], R=[[1.0]])
    model.position_index, model.velocity_index = (0,), (1,)
    return model


def augmented_linear(base, sigma=SIGMA, tau=TAU):
    """The augmented model written as a linear-Gaussian model: ``[p, v, a]``, ``v' = a``,
    ``a' = -a / tau + sigma sqrt(2 / tau) w``."""
    A = np.zeros((3, 3))
    A[:2, :2] = base.A
    A[1, 2] = 1.0
    A[2, 2] = -1.0 / tau
    G = np.zeros((3, 2))
    G[:2, :1] = base.G
    G[2, 1] = sigma * np.sqrt(2.0 / tau)
    return LinearGaussianModel(A=A, G=G, C=np.hstack([base.C, [[0.0]]]), R=base.R)


# (the reference's matrix exponential over 8 correlation times is accurate to about 1e-6 only)
@pytest.mark.parametrize("dt, rtol", [(0.1, 1e-12), (2.0, 1e-12), (40.0, 1e-10), (400.0, 1e-5)])
def test_augmented_transition_and_noise_are_exact(dt, rtol):
    base = constant_velocity()
    model = ModelErrorCompensation(base, TAU, SIGMA)
    F, _, Q = augmented_linear(base).discretise(dt)
    x = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_allclose(model.transition(x, dt), x @ F.T, rtol=rtol, atol=1e-12 * np.abs(F).max())
    np.testing.assert_allclose(model.transition_jacobian(x, dt), np.broadcast_to(F, (5, 3, 3)), rtol=rtol,
                               atol=1e-12 * np.abs(F).max())
    np.testing.assert_allclose(model.process_noise(dt), Q, rtol=max(rtol, 1e-9), atol=1e-12 * np.abs(Q).max())
    assert model.compensation_index == (2,)


def test_model_without_velocities_gets_an_extra_drift_on_every_state():
    base = LinearGaussianModel(A=[[-0.1]], G=[[1.0]], C=[[1.0]], R=[[1.0]])
    model = ModelErrorCompensation(base, TAU, SIGMA)
    assert model.state_dim == 2 and list(model.acceleration_of) == [0]
    x = np.array([[1.0, 2.0]])
    dt = 0.5
    expected = base.transition(x[:, :1], dt)[0, 0] + 2.0 * TAU * (1.0 - np.exp(-dt / TAU))
    assert model.transition(x, dt)[0, 0] == pytest.approx(expected)
    assert model.transition(x, dt)[0, 1] == pytest.approx(2.0 * np.exp(-dt / TAU))


def test_lunar_compensation_noise_is_finite_for_any_gap():
    model = ModelErrorCompensation(LunarDescentModel(), 1e4, 0.1)
    for dt in (1e-6, 2.0, 1e4, 1e7, 1e12):
        Q = model.process_noise(dt)
        assert np.all(np.isfinite(Q)) and np.allclose(Q, Q.T)
        assert np.linalg.eigvalsh(Q / np.abs(Q).max()).min() > -1e-9


def _kalman_of_augmented(ys, dt, mean, cov, sigma=SIGMA, tau=TAU):
    base = constant_velocity()
    linear = augmented_linear(base, sigma, tau)
    m = np.concatenate([mean, [0.0]])
    P = np.zeros((3, 3))
    P[:2, :2] = cov
    P[2, 2] = sigma ** 2
    return kalman(linear, m, P, ys, dt)[-1]


def test_compensated_ekf_is_the_kalman_filter_of_the_augmented_model():
    base = constant_velocity()
    mean, cov = np.array([0.0, 1.0]), np.diag([4.0, 1.0])
    ys = simulate(augmented_linear(base), np.array([0.0, 1.0, 0.2]), 30, 1.0, seed=4)
    exact_mean, exact_cov = _kalman_of_augmented(ys, 1.0, mean, cov)
    f = CompensatedEKF(base, SIGMA, TAU, nominal_prior=0.0)
    f.initialize(mean, cov)
    for y in ys:
        f.predict(1.0)
        f.update(y)
    assert f.model_probabilities is None
    np.testing.assert_allclose(f.augmented_mean, exact_mean, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(f.augmented_covariance, exact_cov, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(f.mean, exact_mean[:2], rtol=1e-9, atol=1e-9)
    assert f.unmodelled_acceleration == pytest.approx(exact_mean[2:])
    assert f.unmodelled_acceleration_covariance == pytest.approx(exact_cov[2:, 2:])


def _evidence_and_posterior(f, ys, mean, cov):
    """Run ``f`` from ``N(mean, cov)`` over ``ys`` (steps of 1 s): its log evidence and the filter."""
    f.initialize(mean, cov)
    evidence = 0.0
    for y in ys:
        f.predict(1.0)
        f.update(y)
        evidence += f.last_log_likelihood
    return evidence, f


@pytest.mark.parametrize("true_acceleration", [0.0, 0.05, 0.3])
def test_model_average_is_the_exact_bayesian_average_of_nominal_and_compensated(true_acceleration):
    """With a constant unmodelled acceleration (a correlation time of 1e12 s), the nominal model is nested
    in the compensated one: the averaged estimate must be the two Kalman posteriors weighted by their
    exact evidence (Savage-Dickey), whatever the truth."""
    base, prior = constant_velocity(), 0.3
    mean, cov = np.array([0.0, 1.0]), np.diag([4.0, 1.0])
    truth = augmented_linear(base)
    truth.A[2, 2], truth.G[2, 1] = 0.0, 0.0  # a constant acceleration
    ys = simulate(truth, np.array([0.0, 1.0, true_acceleration]), 25, 1.0, seed=6)
    nominal_evidence, nominal = _evidence_and_posterior(ExtendedKF(base), ys, mean, cov)
    compensated_evidence, compensated = _evidence_and_posterior(CompensatedEKF(base, SIGMA, 1e12, 0.0), ys,
                                                                mean, cov)
    _, f = _evidence_and_posterior(CompensatedEKF(base, SIGMA, 1e12, nominal_prior=prior), ys, mean, cov)
    odds = prior / (1.0 - prior) * np.exp(nominal_evidence - compensated_evidence)
    expected = odds / (1.0 + odds)
    assert f.model_probabilities == pytest.approx([expected, 1.0 - expected], rel=1e-5, abs=1e-12)
    members = [(nominal.mean, nominal.covariance), (compensated.mean, compensated.covariance)]
    exact_mean, exact_cov = mixture_moments((expected, 1.0 - expected), members)
    np.testing.assert_allclose(f.mean, exact_mean, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(f.covariance, exact_cov, rtol=1e-5, atol=1e-9)
    a, A = compensated.augmented_mean[2:], compensated.augmented_covariance[2:, 2:]
    assert f.unmodelled_acceleration == pytest.approx((1.0 - expected) * a, rel=1e-5, abs=1e-9)
    assert f.unmodelled_acceleration_covariance[0, 0] == pytest.approx(
        (1.0 - expected) * (A[0, 0] + expected * a[0] ** 2), rel=1e-5)


def test_default_gpf_converges_to_the_kalman_posterior_of_the_augmented_model():
    """Default configuration (compensation on): the weighted cloud approaches the exact posterior of
    the augmented linear-Gaussian model as N grows."""
    base = constant_velocity()
    mean, cov = np.array([0.0, 1.0]), np.diag([4.0, 1.0])
    ys = simulate(augmented_linear(base), np.array([0.0, 1.0, 0.2]), 10, 1.0, seed=5)
    exact_mean, exact_cov = _kalman_of_augmented(ys, 1.0, mean, cov)
    sd = np.sqrt(np.diag(exact_cov))

    def error(n):
        errors = []
        for seed in range(6):
            f = GeometricProjectionPF(base, n, seed=seed, unmodelled_acceleration_std=SIGMA,
                                      unmodelled_acceleration_time=TAU)
            f.initialize(mean, cov)
            for y in ys:
                f.predict(1.0)
                f.update(y)
            errors.append(np.abs(f.augmented_mean - exact_mean) / sd)
        return np.sqrt(np.mean(np.square(errors)))

    small, large = error(300), error(76800)  # 256 times the particles: the Monte Carlo error 1/16
    assert large < small / 4.0 and large < 0.01


def _lunar_states(rng: np.random.Generator, n: int) -> np.ndarray:
    """``(n, 6)`` states of low lunar orbits in random planes."""
    r = rng.normal(size=(n, 3))
    r *= 1.8e6 / np.linalg.norm(r, axis=1, keepdims=True)
    v = np.cross(r, rng.normal(size=(n, 3)))
    v *= 1.6e3 / np.linalg.norm(v, axis=1, keepdims=True)
    return np.hstack([r, v])


def test_lunar_frame_is_radial_along_track_cross_track():
    x = _lunar_states(np.random.default_rng(3), 50)
    x = np.vstack([x, [[1.8e6, 0, 0, 10.0, 0, 0]], [[0, 0, 0, 0, 1.0, 0]], [[np.nan] * 6]])
    frame = LunarDescentModel().compensation_frame(x)
    assert frame.shape == (53, 3, 3)
    np.testing.assert_allclose(np.einsum("nki,nkj->nij", frame, frame), np.broadcast_to(np.eye(3), (53, 3, 3)),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(frame), 1.0, atol=1e-12)  # right-handed
    r, v = x[:50, :3], x[:50, 3:]
    np.testing.assert_allclose(frame[:50, :, 0], r / np.linalg.norm(r, axis=1, keepdims=True), atol=1e-12)
    assert np.all(np.einsum("ni,ni->n", frame[:50, :, 1], v) > 0)  # along-track: the way the orbit goes
    assert np.allclose(np.einsum("ni,ni->n", frame[:50, :, 2], v), 0.0, atol=1e-9)
    np.testing.assert_allclose(frame[-1], np.eye(3))  # a non-finite state: the world's axes
    # one state at a time: the same frames
    single = np.concatenate([LunarDescentModel().compensation_frame(state[None]) for state in x])
    np.testing.assert_allclose(single, frame, rtol=0, atol=1e-15)


def test_acceleration_in_the_local_frame_keeps_its_direction_in_it():
    """A radial 0.1 m/s^2 held as local coordinates: the state stays (0.1, 0, 0) (decay aside) for a
    quarter orbit, each step pushes the orbit along the radius of the step's start, and it is reported on
    the world's axes along the radius of the end, not the one it started on."""
    base = LunarDescentModel()
    model = ModelErrorCompensation(base, time_constant=1e6, acceleration_std=0.1)
    x0 = _lunar_states(np.random.default_rng(4), 4)
    x = np.hstack([x0, np.tile([0.1, 0.0, 0.0], (4, 1))])
    G, _ = model._coupling(2.0)
    radial = x0[:, :3] / np.linalg.norm(x0[:, :3], axis=1, keepdims=True)
    pushed = model.transition(x, 2.0)[:, :6] - base.transition(x0, 2.0)
    np.testing.assert_allclose(pushed, 0.1 * np.hstack([G[0, 0] * radial, G[3, 0] * radial]),
                               rtol=1e-6, atol=1e-12)
    for _ in range(900):
        x = model.transition(x, 2.0)
    decay = np.exp(-1800.0 / 1e6)
    np.testing.assert_allclose(x[:, 6:], np.tile([0.1 * decay, 0.0, 0.0], (4, 1)), rtol=1e-12, atol=1e-15)
    end = x[:, :3] / np.linalg.norm(x[:, :3], axis=1, keepdims=True)
    for state, r in zip(x, end):
        a, cov = model.world_acceleration(state[:6], state[6:], np.diag([1.0, 2.0, 3.0]))
        np.testing.assert_allclose(a, 0.1 * decay * r, atol=1e-12)
        assert np.trace(cov) == pytest.approx(6.0) and cov @ r == pytest.approx(r)  # turned, not scaled
    assert np.all(np.einsum("ni,ni->n", radial, end) < 0.9)  # the orbit did turn


def test_framed_transition_jacobian_matches_finite_differences():
    model = ModelErrorCompensation(LunarDescentModel(), time_constant=1e6, acceleration_std=0.1)
    x = np.hstack([_lunar_states(np.random.default_rng(5), 1), [[0.05, -0.02, 0.01]]])
    J = model.transition_jacobian(x, 2.0)[0]
    step = np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3, 1e-4, 1e-4, 1e-4])
    numeric = np.empty((9, 9))
    for j in range(9):
        e = np.zeros(9)
        e[j] = step[j]
        numeric[:, j] = (model.transition(x + e, 2.0)[0] - model.transition(x - e, 2.0)[0]) / (2 * step[j])
    # the frame's dependence on the velocity (how the along-track push turns with it) is in J
    np.testing.assert_allclose(J, numeric, rtol=1e-5, atol=1e-7)  # (the base Jacobian is a Taylor series)
    frozen = np.array(J)
    frozen[:6, :6] = LunarDescentModel().transition_jacobian(x[:, :6], 2.0)[0]
    assert not np.allclose(frozen, numeric, rtol=1e-5, atol=1e-7)


def test_model_average_options_and_degenerate_posteriors():
    from gpf_nav.filters.model_averaging import model_average

    base = constant_velocity()
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ValueError, match="nominal_prior"):
            GeometricProjectionPF(base, 50, nominal_prior=bad)
    assert GeometricProjectionPF(base, 50, unmodelled_acceleration_std=0.0).model_probabilities is None
    mean, cov = np.array([1.0, 2.0, 0.5]), np.diag([4.0, 1.0, 0.01])
    # a non-finite posterior, or a degenerate acceleration block: the compensated moments as they are
    for m, P in ((np.array([1.0, np.nan, 0.5]), cov), (mean, np.diag([4.0, 1.0, np.inf])),
                 (mean, np.diag([4.0, 1.0, 0.0]))):
        probability, average_mean, average_cov = model_average(m, P, 2, SIGMA, 0.5)
        assert probability == 0.0
        np.testing.assert_array_equal(average_mean, m[:2])
        np.testing.assert_array_equal(average_cov, P[:2, :2])
    # far from zero: the nominal model is out (no underflow warning), and the estimate is the compensated one
    probability, average_mean, _ = model_average(np.array([1.0, 2.0, 50.0]), cov, 2, SIGMA, 0.5)
    assert probability == 0.0 and np.array_equal(average_mean, [1.0, 2.0])


def test_model_average_follows_every_step_and_set_moments():
    """The average is kept for the posterior it was computed from: read between steps, and after the
    cloud is moved in place of a step, it is the average of the current posterior."""
    from gpf_nav.filters.model_averaging import model_average

    base = constant_velocity()
    f = GeometricProjectionPF(base, 200, seed=3)
    f.initialize(np.array([0.0, 1.0]), np.diag([4.0, 1.0]))

    def fresh():
        return model_average(f.augmented_mean, f.augmented_covariance, 2, f.model.acceleration_std, 0.5)

    for y in simulate(constant_velocity(), np.array([0.0, 1.0]), 8, 1.0, seed=2):
        f.predict(1.0)
        assert np.array_equal(f.mean, fresh()[1])  # a prediction: the pending noise is in the covariance
        np.testing.assert_array_equal(f.covariance, fresh()[2])
        f.update(y)
        probability, mean, cov = fresh()
        assert f.model_probabilities[0] == probability and np.array_equal(f.mean, mean)
    f.set_moments(np.array([5.0, 0.0, 0.0]), np.diag([1.0, 1.0, 1e-4]))
    assert np.array_equal(f.mean, fresh()[1]) and f.mean[0] == pytest.approx(5.0)


def _gated_ekf_after_clean_steps(**options) -> tuple[CompensatedEKF, np.random.Generator]:
    """A compensated EKF on the lunar model after 20 clean 2 s steps (truth: gravity x 1.09)."""
    model, truth = LunarDescentModel(), LunarDescentModel(mu_scale=1.09)
    r0 = MOON_RADIUS + 100e3
    x = np.array([r0, 0.0, 0.0, 0.0, np.sqrt(MU_MOON / r0), 0.0])
    f = CompensatedEKF(model, **options)
    f.initialize(x, np.diag([1e6] * 3 + [1.0] * 3))
    rng = np.random.default_rng(5)
    for _ in range(20):
        x = truth.transition(x[None], 2.0)[0]
        f.predict(2.0)
        f.update(model.measure(x[None])[0] + rng.normal(size=3) * [30.0, 5e-4, 5e-4])
    return f, rng


def _range_sigma(f: CompensatedEKF) -> tuple[np.ndarray, float]:
    """The measurement the filter expects ``(3,)`` and the std of its range innovation, m."""
    h, H = f.model.measure_and_jacobian(f.augmented_mean[None], f.time)
    S = H[0] @ f.augmented_covariance @ H[0].T + f.model.measurement_noise()
    return h[0], float(np.sqrt(S[0, 0]))


def test_gated_compensated_ekf_refuses_a_20_sigma_outlier_and_only_it():
    """With the GPF's gate, a range 20 innovation sigmas off is left out: the update is exactly the one
    without that range (the angles still used); without the gate (the default) the range is used."""
    gated, _ = _gated_ekf_after_clean_steps(outlier_gate=6.0)
    twin, _ = _gated_ekf_after_clean_steps(outlier_gate=6.0)
    plain, _ = _gated_ekf_after_clean_steps()
    for f in (gated, twin, plain):
        f.predict(2.0)
    y, sigma = _range_sigma(gated)
    y[0] += 20.0 * sigma
    gated.update(y)
    twin.update(np.array([np.nan, y[1], y[2]]))
    plain.update(y)
    assert gated.gated == 1 and plain.gated == 0 and plain.outlier_gate == 0.0
    # what the refused range could have added to the evidence: its density at the gate's edge (6 sigmas)
    assert gated.refused_log_likelihood == pytest.approx(-0.5 * (36.0 + np.log(2.0 * np.pi * sigma ** 2)), rel=1e-12)
    assert np.array_equal(gated.augmented_mean, twin.augmented_mean)
    assert np.array_equal(gated.augmented_covariance, twin.augmented_covariance)
    assert np.linalg.norm(plain.mean[:3] - gated.mean[:3]) > 3.0 * sigma
    gated.predict(2.0)
    y, sigma = _range_sigma(gated)
    gated.update(y + [3.0 * sigma, 0.0, 0.0])  # 3 sigma: inside the gate, used
    assert gated.gated == 1


def test_gated_compensated_ekf_uses_a_component_refused_outlier_gate_limit_times_in_a_row():
    """A range that stays 20 sigmas off is refused outlier_gate_limit times, then used; a good range
    resets the count (the GPF's rule, from the same code)."""
    f, _ = _gated_ekf_after_clean_steps(outlier_gate=6.0, outlier_gate_limit=3)
    gated = []
    for step in range(6):
        f.predict(2.0)
        y, sigma = _range_sigma(f)
        y[0] += 0.0 if step == 4 else 20.0 * sigma
        f.update(y)
        gated.append(f.gated)
    assert gated == [1, 2, 3, 3, 3, 4]
    with pytest.raises(ValueError):
        CompensatedEKF(LunarDescentModel(), outlier_gate=-1.0)
