"""The IMM of the nominal and the compensated GPFs (gpf_nav.filters.multiple_model) on linear-Gaussian
problems whose exact answers are known: it picks the model that generated the data, at the scale of its
unmodelled acceleration, and then gives that model's Kalman posterior."""
import numpy as np
import pytest
from scipy.stats import chi2

from gpf_nav.filters import GeometricProjectionPF, MultipleModelGPF
from gpf_nav.models import LinearGaussianModel
from linear_reference import kalman, simulate
from test_compensation import SIGMA, TAU, _kalman_of_augmented, augmented_linear, constant_velocity

MEAN, COV = np.array([0.0, 1.0]), np.diag([4.0, 1.0])


def run(ys, seed=0, scales=(0.01, 1.0), times=(1.0, 1.0), size_gate=0.0):
    """The IMM on ``ys``; without the size gate by default, so that the evidence alone picks the members
    (the gate is tested on its own)."""
    f = MultipleModelGPF(constant_velocity(), 1000, seed=seed, unmodelled_acceleration_std=SIGMA,
                         unmodelled_acceleration_time=TAU, compensation_scales=scales, compensation_times=times,
                         size_gate=size_gate)
    f.initialize(MEAN, COV)
    for y in ys:
        f.predict(1.0)
        f.update(y)
    return f


def test_data_of_the_nominal_model_select_it_and_give_its_posterior():
    base = constant_velocity()
    ys = simulate(base, MEAN, 150, 1.0, seed=11)
    exact_mean, exact_cov = (v[-1] for v in zip(*kalman(base, MEAN, COV, ys, 1.0)))
    f = run(ys)
    assert f.model_probabilities[-1] < 0.1  # (a compensation of 0.01 sigma is all but the nominal model)
    np.testing.assert_array_less(np.abs(f.mean - exact_mean), 0.3 * np.sqrt(np.diag(exact_cov)))
    np.testing.assert_allclose(np.diag(f.covariance), np.diag(exact_cov), rtol=0.3)
    assert np.all(np.abs(f.unmodelled_acceleration) < 0.1 * SIGMA)


def test_an_unmodelled_acceleration_selects_the_compensated_model():
    ys = simulate(augmented_linear(constant_velocity()), np.array([0.0, 1.0, 2.0 * SIGMA]), 150, 1.0, seed=12)
    exact_mean, exact_cov = _kalman_of_augmented(ys, 1.0, MEAN, COV)
    f = run(ys)
    assert f.model_probabilities[-1] > 0.99
    sd = np.sqrt(np.diag(exact_cov))
    np.testing.assert_array_less(np.abs(f.mean - exact_mean[:2]), 0.3 * sd[:2])
    assert abs(f.unmodelled_acceleration[0] - exact_mean[2]) < 0.3 * sd[2]
    # the nominal member alone is far off: the test is not passed by the mixture being everywhere. Its
    # velocity error over the second half, in posterior standard deviations (RMS; the last step alone
    # ranges 0.2-8 over seeds and BLAS kernels: it follows the rounding, the RMS stays above 3.9)
    nominal = GeometricProjectionPF(constant_velocity(), 1000, seed=0, unmodelled_acceleration_std=0.0)
    nominal.initialize(MEAN, COV)
    linear = augmented_linear(constant_velocity())
    prior = np.diag([COV[0, 0], COV[1, 1], SIGMA ** 2])
    errors = []
    for y, (m, P) in zip(ys, kalman(linear, np.append(MEAN, 0.0), prior, ys, 1.0)):
        nominal.predict(1.0)
        nominal.update(y)
        errors.append((nominal.mean[1] - m[1]) / np.sqrt(P[1, 1]))
    assert np.sqrt(np.mean(np.square(errors[len(ys) // 2:]))) > 3.0


def test_a_small_acceleration_selects_the_member_of_its_scale():
    """An acceleration of 0.3 sigma: the member of scale 0.1 (its prior 3 standard deviations away) is more
    probable than the widest one, which pays for a prior ten times too broad, and than the nominal model,
    which cannot follow it; the estimate is the small model's Kalman posterior."""
    small = 0.1 * SIGMA
    ys = simulate(augmented_linear(constant_velocity(), small), np.array([0.0, 1.0, 3.0 * small]), 150, 1.0,
                  seed=14)
    exact_mean, exact_cov = _kalman_of_augmented(ys, 1.0, MEAN, COV, small)
    f = run(ys, scales=(0.1, 1.0))
    nominal, scaled, widest = f.model_probabilities
    assert scaled > max(nominal, widest) and scaled > 0.6
    sd = np.sqrt(np.diag(exact_cov))
    np.testing.assert_array_less(np.abs(f.mean - exact_mean[:2]), 0.3 * sd[:2])
    np.testing.assert_allclose(np.sqrt(np.diag(f.covariance)), sd[:2], rtol=0.3)


def test_the_size_gate_refuses_a_member_whose_acceleration_is_beyond_its_prior():
    """The data of the previous test, an acceleration of the 0.1 member's size that wanders up to beyond
    its prior's 0.8 quantile (1.28 sigmas for one component): after every update whose estimate of that
    member lies beyond it, the member's probability is 0, whatever its evidence; without the gate the
    evidence keeps it the most probable throughout the second half."""
    small = 0.1 * SIGMA
    ys = simulate(augmented_linear(constant_velocity(), small), np.array([0.0, 1.0, 3.0 * small]), 150, 1.0,
                  seed=14)
    limit = np.sqrt(chi2.ppf(0.8, 1))

    def probabilities(gate):
        f = MultipleModelGPF(constant_velocity(), 1000, seed=0, unmodelled_acceleration_std=SIGMA,
                             unmodelled_acceleration_time=TAU, compensation_scales=(0.1, 1.0),
                             compensation_times=(1.0, 1.0), size_gate=gate)
        f.initialize(MEAN, COV)
        out = []
        for y in ys:
            f.predict(1.0)
            f.update(y)
            out.append((abs(f.scaled[0].unmodelled_acceleration[0]) / small, f.model_probabilities[1]))
        return np.array(out)

    gated, free = probabilities(0.8), probabilities(0.0)
    beyond = gated[:, 0] > limit
    assert beyond.sum() >= 5 and np.all(gated[beyond, 1] == 0.0)
    assert np.all(free[75:, 1] > 0.5)
    for gate in (-0.1, 1.0):
        with pytest.raises(ValueError, match="size_gate"):
            MultipleModelGPF(constant_velocity(), size_gate=gate)


def test_a_varying_acceleration_selects_the_member_of_its_correlation_time():
    """An acceleration of 0.5 sigma that decorrelates in a tenth of tau (5 steps): the member of that scale
    and correlation time wins, and the estimate is its Kalman posterior, whose velocity is 26 % less certain
    than that of the same scale taken for constant (with the member's time ignored, its probability was
    0.66 and the velocity sd 13 % too small)."""
    small, short = 0.5 * SIGMA, 0.1 * TAU
    ys = simulate(augmented_linear(constant_velocity(), small, short), np.array([0.0, 1.0, small]), 200, 1.0,
                  seed=15)
    exact_mean, exact_cov = _kalman_of_augmented(ys, 1.0, MEAN, COV, small, short)
    f = run(ys, scales=(0.5, 1.0), times=(0.1, 1.0))
    assert f.model_probabilities[1] > 0.9
    sd = np.sqrt(np.diag(exact_cov))
    np.testing.assert_array_less(np.abs(f.mean - exact_mean[:2]), 0.1 * sd[:2])
    np.testing.assert_allclose(np.sqrt(np.diag(f.covariance)), sd[:2], rtol=0.05)


def test_set_moments_gives_the_cloud_the_requested_moments():
    f = GeometricProjectionPF(constant_velocity(), 300, seed=3)
    f.initialize(MEAN, COV)
    target_mean, target_cov = np.array([1.0, -2.0, 0.1]), np.array([[2.0, 0.3, 0.0], [0.3, 0.5, 0.01],
                                                                     [0.0, 0.01, 0.02]])
    f.set_moments(target_mean, target_cov)
    np.testing.assert_allclose(f.augmented_mean, target_mean, atol=1e-12)
    np.testing.assert_allclose(f.augmented_covariance, target_cov, atol=1e-12)


def test_options_are_checked_and_runs_repeat_bit_for_bit():
    with pytest.raises(ValueError):
        MultipleModelGPF(constant_velocity(), switch_time=0.0)
    with pytest.raises(ValueError):
        MultipleModelGPF(constant_velocity(), unmodelled_acceleration_std=0.0)
    with pytest.raises(ValueError, match="nominal_prior"):  # the IMM is its own test of the nominal model
        MultipleModelGPF(constant_velocity(), nominal_prior=0.5)
    for scales in ((), (0.5,), (1.0, 0.1), (0.0, 1.0), (0.1, 0.1, 1.0)):
        with pytest.raises(ValueError, match="compensation_scales"):
            MultipleModelGPF(constant_velocity(), compensation_scales=scales, compensation_times=(1.0,) * len(scales))
    for times in ((1.0,), (0.5, 0.5), (0.0, 1.0), (1.0, 1.0, 1.0)):
        with pytest.raises(ValueError, match="compensation_times"):
            MultipleModelGPF(constant_velocity(), compensation_scales=(0.1, 1.0), compensation_times=times)
    assert MultipleModelGPF(constant_velocity()).compensated.model_probabilities is None
    ys = simulate(constant_velocity(), MEAN, 20, 1.0, seed=13)
    np.testing.assert_array_equal(run(ys, seed=5).covariance, run(ys, seed=5).covariance)


def test_only_the_nominal_member_is_mixed():
    """One-way mixing: a prediction moves the compensated member exactly as if it ran alone (its model
    contains the nominal one), while the nominal member is pulled towards the mixture."""
    import copy
    ys = simulate(constant_velocity(), MEAN, 20, 1.0, seed=3)
    f = MultipleModelGPF(constant_velocity(), 300, seed=1, unmodelled_acceleration_std=SIGMA,
                         unmodelled_acceleration_time=TAU, switch_time=5.0)  # p = 0.18 per step
    f.initialize(MEAN, COV)
    for y in ys:
        f.predict(1.0)
        f.update(y)
    alone, nominal_alone = copy.deepcopy(f.compensated), copy.deepcopy(f.nominal)
    f.predict(1.0)
    alone.predict(1.0)
    nominal_alone.predict(1.0)
    assert np.array_equal(f.compensated.particles, alone.particles)
    assert not np.allclose(f.nominal.mean, nominal_alone.mean)


def planar_constant_velocity():
    """2-D constant velocity ``[px, py, vx, vy]``, both positions measurable."""
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    G = np.zeros((4, 2))
    G[2, 0] = G[3, 1] = 0.1
    model = LinearGaussianModel(A=A, G=G, C=np.eye(2, 4), R=np.eye(2))
    model.position_index, model.velocity_index = (0, 1), (2, 3)
    return model


def test_a_member_the_widest_one_does_not_admit_loses_its_probability_while_a_direction_is_undetermined():
    """The widest member's model contains every other's, so while the data leave a direction undetermined
    its posterior covers what they may be: a narrower member outside its chi-square gate is wrong
    whatever its evidence (a small member that explains an unobservable error locally). With ``py``
    never measured, ``(py, vy)`` is undetermined: a narrow member pushed 10 widest standard deviations
    along ``py`` keeps a good part of its probability without the gate and none with it. With both
    positions measured every direction is determined, and a member pushed along ``px`` towards data
    that agree with it is left to its evidence."""
    truth = simulate(planar_constant_velocity(), np.array([0.0, 0.0, 1.0, 1.0]), 40, 1.0, seed=16)
    partial = truth.copy()
    partial[:, 1] = np.nan

    def pushed(gate, axis, ys):
        f = MultipleModelGPF(planar_constant_velocity(), 500, seed=1, unmodelled_acceleration_std=SIGMA,
                             unmodelled_acceleration_time=TAU, compensation_scales=(0.01, 1.0),
                             compensation_times=(1.0, 1.0), nesting_gate=gate)
        f.initialize(np.array([0.0, 0.0, 1.0, 1.0]), np.diag([4.0, 4.0, 1.0, 1.0]))
        for y in ys[:-1]:
            f.predict(1.0)
            f.update(y)
        narrow = f.scaled[0]
        sd = np.sqrt(np.diag(f.compensated.covariance))
        shift = np.zeros(6)
        shift[axis] = 10.0 * sd[axis]
        narrow.initialize(narrow.augmented_mean + shift, narrow.augmented_covariance, narrow.time)
        before = f.model_probabilities[1]
        f.predict(1.0)
        f.update(ys[-1] + shift[:2])  # data that agree with the pushed member where they see
        return f, before, f.model_probabilities[1]

    f, before, kept = pushed(0.0, 1, partial)
    assert np.allclose(f.observability.directions[:, [0, 2]], 0.0, atol=1e-6)  # (py, vy) only
    assert before > 0.3 and kept > 0.2
    assert pushed(0.999, 1, partial)[2] == 0.0
    f, _, kept = pushed(0.999, 0, truth)
    assert f.observability.determined and kept > 0.2
    with pytest.raises(ValueError, match="nesting_gate"):
        MultipleModelGPF(constant_velocity(), nesting_gate=1.0)


def test_a_member_that_refuses_a_component_takes_the_lowest_evidence_and_the_others_still_weigh():
    """One member's gate refuses a component: the others' evidence still moves the probabilities, and the
    refusing member is weighed as the least probable of them, or lower when its own evidence with the
    refused component at its gate's edge is lower; when every member refuses, nothing moves."""
    f = MultipleModelGPF(constant_velocity(), 200, seed=0, unmodelled_acceleration_std=SIGMA,
                         unmodelled_acceleration_time=TAU, compensation_scales=(0.01, 1.0),
                         compensation_times=(1.0, 1.0), nesting_gate=0.0)
    f.initialize(MEAN, COV)
    f.predict(1.0)

    def scripted(member, evidence, refuses, edge):
        def update(y, sensor=None):
            member.last_log_likelihood = evidence
            member.gated += refuses
            member.refused_log_likelihood = edge
        return update

    def weigh(evidences, refusals, edge=-20.0):
        prior = f.model_probabilities.copy()
        for member, evidence, refuses in zip(f.members, evidences, refusals):
            member.update = scripted(member, evidence, refuses, edge)
        f.update(np.array([0.0]))
        return prior, f.model_probabilities

    prior, mu = weigh((0.0, 50.0, -3.0), (0, 1, 0))  # the middle member refuses: it gets -3, the lowest
    expected = prior * np.exp(np.array([0.0, -3.0, -3.0]))
    np.testing.assert_allclose(mu, expected / expected.sum(), rtol=1e-12)
    assert f.last_log_likelihood == pytest.approx(np.log(expected.sum()), rel=1e-12)  # log sum_j c_j p(y | j)
    prior, mu = weigh((0.0, 5.0, -3.0), (0, 1, 0))  # its used components and the refused one at the edge: -15
    expected = prior * np.exp(np.array([0.0, -15.0, -3.0]))
    np.testing.assert_allclose(mu, expected / expected.sum(), rtol=1e-12)
    prior, mu = weigh((0.0, 50.0, -3.0), (1, 1, 1))  # every member refused: the probabilities stay
    np.testing.assert_allclose(mu, prior, rtol=1e-12)
    assert f.last_log_likelihood == 0.0


def test_the_nominal_model_also_switches_to_the_narrowest_compensated_one():
    """The chain over dt: p = 1 - exp(-dt / switch_time) spread alike over the other models, and the
    nominal model's own switch, (1 - p)(1 - exp(-dt / nominal_switch_time)), to the narrowest compensated
    one; 0 turns that switch off. Equal evidence leaves the probabilities at the chain's prediction."""
    def predicted(nominal_switch_time, dt=50.0):
        f = MultipleModelGPF(constant_velocity(), 100, seed=0, unmodelled_acceleration_std=SIGMA,
                             unmodelled_acceleration_time=TAU, compensation_scales=(0.01, 0.1, 1.0),
                             compensation_times=(1.0, 1.0, 1.0), switch_time=1e3,
                             nominal_switch_time=nominal_switch_time, nesting_gate=0.0, size_gate=0.0)
        f.initialize(MEAN, COV)
        for member in f.members:
            member.update = lambda y, sensor=None, member=member: setattr(member, "last_log_likelihood", 0.0)
        f.predict(1.0)
        f.update(np.array([0.0]))  # equal evidence: the probabilities stay uniform
        f.predict(dt)
        f.update(np.array([0.0]))
        return f.model_probabilities

    p, q = 1.0 - np.exp(-50.0 / 1e3), 1.0 - np.exp(-50.0 / 400.0)
    chain = np.full((4, 4), p / 3)
    np.fill_diagonal(chain, 1.0 - p)
    np.testing.assert_allclose(predicted(0.0), chain.T @ np.full(4, 0.25), rtol=1e-12)
    chain[0, 0] -= (1.0 - p) * q
    chain[0, 1] += (1.0 - p) * q
    np.testing.assert_allclose(predicted(400.0), chain.T @ np.full(4, 0.25), rtol=1e-12)
    with pytest.raises(ValueError, match="nominal_switch_time"):
        MultipleModelGPF(constant_velocity(), nominal_switch_time=-1.0)


def test_the_narrow_members_are_gated_compensated_ekfs_unless_asked_for_gpfs():
    """By default the compensated members narrower than the widest are EKFs with the GPF members' gate;
    the nominal and the widest member are GPFs; ``narrow_filter="gpf"`` makes every member a GPF."""
    from gpf_nav.filters import CompensatedEKF
    from gpf_nav.filters.compensated import UNMODELLED_ACCELERATION_STD as SIGMA_DEFAULT
    f = MultipleModelGPF(constant_velocity(), 100, seed=0, compensation_scales=(0.01, 0.1, 1.0),
                         compensation_times=(1.0, 1.0, 1.0), outlier_gate=4.0, outlier_gate_limit=3)
    assert [type(m) for m in f.members] == [GeometricProjectionPF, CompensatedEKF, CompensatedEKF,
                                            GeometricProjectionPF]
    assert [(m.outlier_gate, m.outlier_gate_limit) for m in f.scaled[:-1]] == [(4.0, 3)] * 2
    # the nominal member's report is the mixture's: the EKFs run no observability recursions
    f.initialize(MEAN, COV)
    f.predict(1.0)
    f.update(np.array([0.5]))
    assert [m.observability is None for m in f.members] == [False, True, True, False]
    assert f.observability_trackers() == (f.nominal.observability_trackers() + f.compensated.observability_trackers())
    assert [m.model.acceleration_std for m in f.scaled] == pytest.approx([0.01 * SIGMA_DEFAULT, 0.1 * SIGMA_DEFAULT,
                                                                          SIGMA_DEFAULT])
    gpfs = MultipleModelGPF(constant_velocity(), 100, seed=0, narrow_filter="gpf")
    assert all(type(m) is GeometricProjectionPF for m in gpfs.members)
    with pytest.raises(ValueError, match="narrow_filter"):
        MultipleModelGPF(constant_velocity(), narrow_filter="ukf")


def test_the_point_set_of_the_mixture_has_its_mean_and_each_ekf_member_its_moments():
    """``particles`` and ``weights`` are a weighted point set of the mixture: the GPF members' particles
    and each EKF member's 2n sigma points, whose equal weights give that member's mean and covariance
    exactly; together, the mixture's mean."""
    from gpf_nav.filters.multiple_model import _sigma_points
    ys = simulate(augmented_linear(constant_velocity()), np.array([0.0, 1.0, 0.3 * SIGMA]), 30, 1.0, seed=4)
    f = run(ys, scales=(0.01, 0.1, 1.0), times=(1.0, 1.0, 1.0))
    points, weights = f.particles, f.weights
    assert points.shape == (2 * 1000 + 2 * 2 * 2, 2) and weights.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(weights @ points, f.mean, rtol=1e-9, atol=1e-12)
    for member in f.scaled[:-1]:
        sigma = _sigma_points(member)
        np.testing.assert_allclose(sigma.mean(axis=0), member.mean, atol=1e-12)
        np.testing.assert_allclose(np.cov(sigma.T, bias=True), member.covariance, rtol=1e-10)
    assert 0.0 < f.ess <= 1.0


def test_a_narrow_member_narrower_than_the_nominal_one_where_the_data_cannot_see_loses_its_probability():
    """A compensated model contains the nominal one, so along a direction the data have not determined its
    posterior is at least as wide as the nominal member's. With ``py`` never measured, a narrow member
    whose ``(py, vy)`` variances are shrunk to 1 % is zeroed; left as it is, it keeps its probability;
    with both positions measured every direction is determined and the evidence alone weighs it."""
    truth = simulate(planar_constant_velocity(), np.array([0.0, 0.0, 1.0, 1.0]), 40, 1.0, seed=16)
    partial = truth.copy()
    partial[:, 1] = np.nan

    def kept(ys, shrink):
        f = MultipleModelGPF(planar_constant_velocity(), 500, seed=1, unmodelled_acceleration_std=SIGMA,
                             unmodelled_acceleration_time=TAU, compensation_scales=(0.01, 1.0),
                             compensation_times=(1.0, 1.0))
        f.initialize(np.array([0.0, 0.0, 1.0, 1.0]), np.diag([4.0, 4.0, 1.0, 1.0]))
        for y in ys[:-1]:
            f.predict(1.0)
            f.update(y)
        narrow = f.scaled[0]
        scale = np.ones(6)
        scale[[1, 3]] = shrink
        narrow.initialize(narrow.augmented_mean, narrow.augmented_covariance * np.outer(scale, scale), narrow.time)
        f.predict(1.0)
        f.update(ys[-1])
        return f.model_probabilities[1]

    assert kept(partial, 0.1) == 0.0
    assert kept(partial, 1.0) > 0.05
    assert kept(truth, 0.1) > 0.05
