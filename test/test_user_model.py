"""A user's own model: validation of ordinary mistakes, the time argument, recoveries, the examples."""
import numpy as np
import pytest

from examples import bearings_only, bearings_only_peers, growth_model
from gpf_nav.filters import BootstrapPF, EnsembleKF, ExtendedKF, GeometricProjectionPF, UnscentedKF
from gpf_nav.models import LinearGaussianModel
from gpf_nav.models.checks import validate_model

BearingsOnlyModel = bearings_only.BearingsOnlyModel
PRIOR = (bearings_only.PRIOR_MEAN, bearings_only.PRIOR_COV)
FILTERS = {
    "BootstrapPF": lambda m: BootstrapPF(m, 50, seed=0),
    "GPF": lambda m: GeometricProjectionPF(m, 50, seed=0),
    "EKF": ExtendedKF,
    "UKF": UnscentedKF,
    "EnKF": lambda m: EnsembleKF(m, 50, seed=0),
}


# --- validation ------------------------------------------------------------------------------------------
class IndexAngular(BearingsOnlyModel):
    angular = (0,)


class UnbatchedMeasurement(BearingsOnlyModel):
    def measure(self, x):
        return np.arctan2(x[:, 2], x[:, 0])


class UnbatchedTransitionJacobian(BearingsOnlyModel):
    def transition_jacobian(self, x, dt, t=0.0, u=None):
        return super().transition_jacobian(x, dt, t, u)[0]


class ScalarR(BearingsOnlyModel):
    def measurement_noise(self):
        return bearings_only.BEARING_STD ** 2


class FlatMeasurementJacobian(BearingsOnlyModel):
    def measurement_jacobian(self, x):
        return super().measurement_jacobian(x)[:, 0, :]


class NoAngular(BearingsOnlyModel):
    def __getattribute__(self, name):
        if name == "angular":
            raise AttributeError(name)
        return super().__getattribute__(name)


MISTAKES = {  # model, words the message must contain
    "angular indices": (IndexAngular, ["angular", "boolean mask", "(1,)", "(0,)"]),
    "measure (N,)": (UnbatchedMeasurement, ["measure(", "(6,)", "expected (6, 1)"]),
    "unbatched transition_jacobian": (UnbatchedTransitionJacobian,
                                      ["transition_jacobian", "(4, 4)", "expected (6, 4, 4)"]),
    "scalar R": (ScalarR, ["measurement_noise", "shape ()", "expected (1, 1)"]),
    "(N, n) measurement Jacobian": (FlatMeasurementJacobian,
                                    ["measurement_jacobian", "(6, 4)", "expected (6, 1, 4)"]),
    "no angular": (NoAngular, ["angular", "boolean mask of shape (1,)"]),
}


@pytest.mark.parametrize("filter_name", sorted(FILTERS))
@pytest.mark.parametrize("mistake", sorted(MISTAKES))
def test_initialize_rejects_a_mistaken_model_naming_method_and_shapes(filter_name, mistake):
    cls, words = MISTAKES[mistake]
    f = FILTERS[filter_name](cls())
    with pytest.raises(ValueError) as error:
        f.initialize(*PRIOR)
    for word in words:
        assert word in str(error.value), str(error.value)
    assert not f.initialized


@pytest.mark.parametrize("filter_name", sorted(FILTERS))
def test_a_correct_model_passes_and_is_checked_once(filter_name):
    calls = []

    class Counting(BearingsOnlyModel):
        def drift(self, x, t=0.0, u=None):  # called by the validation only (and the GPF's increment reference)
            calls.append(1)
            return super().drift(x, t, u)

    f = FILTERS[filter_name](Counting())
    f.initialize(*PRIOR)
    first = len(calls)
    f.initialize(*PRIOR)
    f.predict(1.0)
    f.update(np.array([1.0]))
    assert f.initialized and first >= 1  # the GPF also checks the compensated model built on it
    assert len(calls) == first


def test_validation_names_the_prior_dimension_mismatch_and_passes_shipped_models():
    model = LinearGaussianModel(A=[[0.0]], G=[[1.0]], C=[[1.0]], R=[[1.0]])
    validate_model(model, np.zeros(1), np.eye(1))
    validate_model(growth_model.GrowthModel(), np.zeros(1), np.eye(1))
    bad = LinearGaussianModel(A=[[0.0]], G=[[1.0]], C=[[1.0]], R=[[-1.0]])
    with pytest.raises(ValueError, match="positive definite"):
        validate_model(bad, np.zeros(1), np.eye(1))


# --- time ------------------------------------------------------------------------------------------------
class Recording(BearingsOnlyModel):
    """Records the ``t`` every time-aware method is called with (after validation)."""

    def __init__(self):
        super().__init__()
        self.seen = []

    def transition(self, x, dt, t=0.0, u=None):
        self.seen.append(("transition", t))
        return super().transition(x, dt, t, u)

    def process_noise(self, dt, t=0.0):
        self.seen.append(("process_noise", t))
        return super().process_noise(dt)

    def measure(self, x, t=0.0):
        self.seen.append(("measure", t))
        return super().measure(x)


@pytest.mark.parametrize("filter_name", sorted(FILTERS))
def test_t_is_the_elapsed_time_since_initialize_at_t0(filter_name):
    model = Recording()
    f = FILTERS[filter_name](model)
    f.initialize(*PRIOR, t0=5.0)
    assert f.time == 5.0
    model.seen.clear()
    f.predict(1.0)
    f.update(np.array([1.0]))
    f.predict(2.0)
    f.update(np.array([1.0]))
    assert f.time == 8.0
    seen = set(model.seen)
    # times other than t0 (the validation already called every method at t0, and Q may be cached)
    assert {("transition", 6.0), ("measure", 6.0), ("measure", 8.0)} <= seen
    assert ("process_noise", 6.0) in seen  # the start of the interval
    f.initialize(*PRIOR)
    assert f.time == 0.0


class GrowingNoise(LinearGaussianModel):
    """Random walk whose noise intensity grows with time: ``Q(dt, t) = (1 + t) dt``."""

    def process_noise(self, dt, t=0.0):
        return np.array([[(1.0 + t) * dt]])


@pytest.mark.parametrize("filter_name", ["EKF", "UKF"])
def test_a_time_varying_process_noise_is_not_cached_across_times(filter_name):
    f = FILTERS[filter_name](GrowingNoise(A=[[0.0]], G=[[1.0]], C=[[1.0]], R=[[1.0]]))
    f.initialize(np.zeros(1), np.eye(1))
    for _ in range(3):
        f.predict(1.0)
    assert f.covariance[0, 0] == pytest.approx(1.0 + 1.0 + 2.0 + 3.0)


def test_a_time_varying_process_noise_reaches_the_particle_filter():
    f = BootstrapPF(GrowingNoise(A=[[0.0]], G=[[1.0]], C=[[1.0]], R=[[1.0]]), 20000, seed=0)
    f.initialize(np.zeros(1), np.eye(1) * 1e-12)
    for _ in range(3):
        f.predict(1.0)
    f.update(np.array([np.nan]))
    assert f.covariance[0, 0] == pytest.approx(1.0 + 2.0 + 3.0, rel=0.05)


# --- recoveries --------------------------------------------------------------------------------------------
def test_ukf_recoveries_near_close_approach_are_counted_and_never_compound():
    """Near the close approach the UKF's innovation covariance is not positive definite at many
    consecutive updates; each recovery inflates the same last good covariance once."""
    f = UnscentedKF(BearingsOnlyModel())
    truth, ys = bearings_only.simulate(np.random.default_rng(0))
    f.initialize(*PRIOR)
    largest = 0.0
    for y in ys:
        f.predict(1.0)
        f.update(y)
        largest = max(largest, np.trace(f.covariance))
    assert f.recoveries >= 3 and "innovation" in f.last_recovery_reason
    # bounded by one inflation of the prior (the largest healthy covariance) plus the steps' noise
    assert largest < f.recovery_inflation * np.trace(PRIOR[1]) * 1.5


class BlindAfterOne(LinearGaussianModel):
    """A random walk whose sensor returns NaN after t = 1: every later update is poisoned."""

    def measure(self, x, t=0.0):
        return super().measure(x) * (np.nan if t > 1.0 else 1.0)


@pytest.mark.parametrize("filter_name", sorted(FILTERS))
def test_every_filter_counts_its_recoveries_and_never_compounds_them(filter_name):
    f = FILTERS[filter_name](BlindAfterOne(A=[[0.0]], G=[[1.0]], C=[[1.0]], R=[[1.0]]))
    f.initialize(np.zeros(1), np.eye(1))
    f.predict(1.0)
    f.update(np.array([0.5]))
    assert f.recoveries == 0
    for k in range(4):
        f.predict(1.0)
        f.update(np.array([0.5]))
        assert f.recoveries == k + 1 and f.last_recovery_reason
        assert np.isfinite(f.mean).all() and np.isfinite(f.covariance).all()
        # one inflation of a last good variance (at most the prior's 1 plus a step's noise) and a step,
        # never 10^k; the 50-member EnKF's sample variance may exceed it by its sampling error
        assert f.covariance[0, 0] < 1.5 * (f.recovery_inflation * 2.0 + 1.0)


# --- the examples ------------------------------------------------------------------------------------------
def test_bearings_only_example_runs_every_filter(capsys):
    results = bearings_only.main(["--runs", "2", "--particles", "300"])
    assert set(results) == set(bearings_only.filters(10, 0))
    for r in results.values():
        assert r["runs"] == 2 and r["failed"] == 0 and np.isfinite(r["rmse"])
    assert "BootstrapPF" in capsys.readouterr().out


def test_bearings_only_peer_script_runs_with_whatever_is_installed(capsys):
    results = bearings_only_peers.main(["--runs", "1", "--particles", "200", "--skip", "Stone Soup"])
    assert "EKF" in results and "BootstrapPF" in results
    if "filterpy: EKF" in results:  # same linearisation, same numbers
        assert results["filterpy: EKF"]["rmse"] == pytest.approx(results["EKF"]["rmse"], rel=1e-9)


def test_growth_model_example_runs(capsys):
    growth_model.main()
    assert "RMSE" in capsys.readouterr().out
