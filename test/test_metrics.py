"""Hand-computed checks of the experiment metrics (gpf_nav.experiments.metrics)."""
import math

import numpy as np
import pytest
from scipy import stats

from gpf_nav.experiments import metrics


def test_error_norms_and_rmse_hand_computed():
    est = np.array([[3.0, 4.0, 0.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]])
    truth = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 0.0, 2.0]])
    norms = metrics.error_norms(est, truth)
    np.testing.assert_allclose(norms, [5.0, 0.0, 2.0])
    # sqrt((25 + 0 + 4) / 3)
    assert metrics.rmse(norms) == pytest.approx(math.sqrt(29.0 / 3.0))


def test_rmse_is_not_mean_error():
    # errors 1 and 7: mean 4, RMSE sqrt(25) = 5
    assert metrics.rmse([1.0, 7.0]) == pytest.approx(5.0)
    assert math.isnan(metrics.rmse([1.0, np.nan]))
    with pytest.raises(ValueError):
        metrics.rmse([])


def test_nees_hand_computed_diagonal_and_correlated():
    # diagonal: e = (2, 3), P = diag(4, 9) -> 1 + 1 = 2
    # correlated: P = [[2, 1], [1, 2]], P^-1 = [[2, -1], [-1, 2]] / 3, e = (1, 1) -> (2 - 1 - 1 + 2) / 3 = 2/3
    errors = np.array([[2.0, 3.0], [1.0, 1.0]])
    covs = np.array([np.diag([4.0, 9.0]), [[2.0, 1.0], [1.0, 2.0]]])
    np.testing.assert_allclose(metrics.nees(errors, covs), [2.0, 2.0 / 3.0])
    assert metrics.nees_step(errors[1], covs[1]) == pytest.approx(2.0 / 3.0)


def test_nees_nan_for_singular_or_nonfinite_covariance_only_at_that_step():
    errors = np.array([[1.0, 0.0], [1.0, 0.0], [np.nan, 0.0]])
    covs = np.array([np.eye(2), np.zeros((2, 2)), np.eye(2)])
    out = metrics.nees(errors, covs)
    assert out[0] == pytest.approx(1.0)
    assert math.isnan(out[1]) and math.isnan(out[2])
    with pytest.raises(ValueError):
        metrics.nees(errors, np.eye(2))


def test_not_positive_definite_flags_singular_indefinite_and_nonfinite_covariances():
    good = np.array([[4.0, 1.0], [1.0, 2.0]])
    covariances = np.stack([good, np.diag([1.0, 0.0]), np.diag([1.0, -1e-12]), np.full((2, 2), np.nan),
                            np.array([[1.0, 2.0], [2.0, 1.0]]), good])
    assert metrics.not_positive_definite(covariances).tolist() == [False, True, True, True, True, False]
    assert metrics.not_positive_definite(np.stack([good] * 3)).tolist() == [False] * 3
    assert metrics.not_positive_definite(np.zeros((0, 2, 2))).shape == (0,)


def test_chi2_band_matches_scipy_and_the_textbook_value():
    lo, hi = metrics.chi2_band(dof=6, runs=100)
    assert lo == pytest.approx(stats.chi2.ppf(0.025, 600) / 100)
    assert hi == pytest.approx(stats.chi2.ppf(0.975, 600) / 100)
    # Bar-Shalom et al.: 6 dof, 100 runs -> about [5.34, 6.69]
    assert lo == pytest.approx(5.34, abs=0.01) and hi == pytest.approx(6.69, abs=0.01)
    # single run, 1 dof: the usual chi-square quantiles
    lo1, hi1 = metrics.chi2_band(1, 1)
    assert lo1 == pytest.approx(0.000982, rel=1e-3) and hi1 == pytest.approx(5.0239, rel=1e-4)
    with pytest.raises(ValueError):
        metrics.chi2_band(0, 10)


def test_fraction_in_band_and_time_average():
    assert metrics.fraction_in_band([1.0, 2.0, 3.0, np.nan, 10.0], (1.5, 3.0)) == pytest.approx(0.5)
    assert math.isnan(metrics.fraction_in_band([np.nan], (0, 1)))
    assert metrics.time_average([1.0, np.nan, 3.0]) == pytest.approx(2.0)
    assert math.isnan(metrics.time_average([np.nan]))


def test_mean_std_uses_sample_std_over_finite_values():
    out = metrics.mean_std([1.0, 2.0, 3.0, 4.0, np.nan])
    assert out["mean"] == pytest.approx(2.5)
    assert out["std"] == pytest.approx(math.sqrt(5.0 / 3.0))  # ddof = 1
    assert out["n"] == 4
    assert metrics.mean_std([7.0]) == {"mean": 7.0, "std": 0.0, "n": 1}
    assert metrics.mean_std([np.nan]) == {"mean": None, "std": None, "n": 0}


def test_wilcoxon_is_paired_and_two_sided():
    rng = np.random.default_rng(1)
    base = rng.uniform(0, 100, 30)  # large spread between runs, small consistent paired improvement
    a = base
    b = base + 0.5 + 0.01 * rng.standard_normal(30)
    p = metrics.wilcoxon_p(a, b)
    assert p == pytest.approx(stats.wilcoxon(a, b).pvalue)
    assert p < 1e-6  # paired: the consistent difference is found
    assert stats.mannwhitneyu(a, b).pvalue > 0.5  # unpaired it would not be
    # shuffling the pairing destroys it: the function must not sort or otherwise re-pair the samples
    assert metrics.wilcoxon_p(a, rng.permutation(b)) > 1e-3
    # symmetric in the sense of a two-sided test
    assert metrics.wilcoxon_p(b, a) == pytest.approx(p)


def test_wilcoxon_hand_computed_small_case():
    # differences +1, +2, +3, +4, +5: all positive, exact two-sided p = 2 / 2**5
    a = np.array([2.0, 4.0, 6.0, 8.0, 10.0])
    b = a - np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    assert metrics.wilcoxon_p(a, b) == pytest.approx(2.0 / 32.0)


def test_wilcoxon_edge_cases():
    assert metrics.wilcoxon_p([1.0, 2.0], [1.0, 2.0]) == 1.0
    assert metrics.wilcoxon_p([np.nan], [1.0]) is None
    # non-finite pairs are dropped, not the whole sample
    a = [2.0, 4.0, 6.0, 8.0, 10.0, np.nan]
    b = [1.0, 2.0, 3.0, 4.0, 5.0, 0.0]
    assert metrics.wilcoxon_p(a, b) == pytest.approx(2.0 / 32.0)
    with pytest.raises(ValueError):
        metrics.wilcoxon_p([1.0, 2.0], [1.0])


def test_correlations():
    x = np.array([1.0, 2.0, 3.0, 4.0])
    assert metrics.correlation(x, 2 * x + 1) == pytest.approx(1.0)
    assert metrics.correlation(x, -x) == pytest.approx(-1.0)
    # hand computed: x = (1,2,3), y = (1,3,2): cov = 0.5*... -> r = 0.5
    assert metrics.correlation([1, 2, 3], [1, 3, 2]) == pytest.approx(0.5)
    assert metrics.correlation(x, np.ones(4)) is None  # constant: undefined
    assert metrics.rank_correlation(x, x ** 3) == pytest.approx(1.0)  # monotone, not linear
    assert metrics.correlation([1.0, np.nan, 2.0, 3.0], [1.0, 5.0, 2.0, 3.0]) == pytest.approx(1.0)
