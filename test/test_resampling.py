"""Resamplers on equal, one-hot and adversarial weights."""
import numpy as np
import pytest

from gpf_nav import resampling

SCHEMES = sorted(resampling.SCHEMES)


@pytest.mark.parametrize("name", SCHEMES)
def test_equal_weights_keep_every_particle_for_low_variance_schemes(name):
    n = 1000
    ancestors = resampling.get(name)(np.full(n, 1.0 / n), np.random.default_rng(0))
    assert ancestors.shape == (n,) and ancestors.dtype.kind == "i"
    if name in ("systematic", "residual", "stratified"):
        # systematic and residual give each particle exactly one child; stratified as well for equal weights
        assert np.array_equal(np.sort(ancestors), np.arange(n))


@pytest.mark.parametrize("name", SCHEMES)
@pytest.mark.parametrize("hot", [0, 17, 99])
def test_one_hot_weights(name, hot):
    w = np.zeros(100)
    w[hot] = 1.0
    ancestors = resampling.get(name)(w, np.random.default_rng(1))
    assert np.all(ancestors == hot)


@pytest.mark.parametrize("name", SCHEMES)
def test_adversarial_weights_stay_in_range_and_unbiased(name):
    rng = np.random.default_rng(2)
    n = 500
    # huge dynamic range, many zeros, and a cumulative sum that rounds below 1
    w = np.exp(rng.uniform(-700, 0, n))
    w[::3] = 0.0
    w[-1] = 0.0
    w /= w.sum()
    counts = np.zeros(n)
    draws = 4000
    for _ in range(draws):
        a = resampling.get(name)(w, rng)
        assert a.shape == (n,) and a.min() >= 0 and a.max() < n
        assert np.all(w[a] > 0)
        counts += np.bincount(a, minlength=n)
    # expected offspring N w_i, checked on the heaviest particles
    heavy = np.argsort(w)[-3:]
    expected = draws * n * w[heavy]
    assert np.all(np.abs(counts[heavy] - expected) < 5.0 * np.sqrt(expected) + 1.0)


def test_systematic_counts_are_floor_or_ceil():
    rng = np.random.default_rng(3)
    w = rng.dirichlet(np.ones(50))
    counts = np.bincount(resampling.systematic(w, rng), minlength=50)
    assert np.all(np.abs(counts - 50 * w) < 1.0 + 1e-9)


def test_unknown_scheme():
    with pytest.raises(ValueError):
        resampling.get("bogus")


def test_effective_sample_size():
    assert resampling.effective_sample_size(np.full(4, 0.25)) == pytest.approx(4.0)
    assert resampling.effective_sample_size(np.array([1.0, 0, 0])) == pytest.approx(1.0)
