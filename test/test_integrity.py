"""Co-state integrity monitor: calibration under H0, detection, missing data, and a short lunar run."""
import math

import numpy as np
import pytest
from scipy import stats

from gpf_nav.integrity import CostateMonitor, IntegrityStatus, hotelling_t2, t2_threshold

SCALES = np.array([1.0, 300.0, 2e5])  # co-state components differ by orders of magnitude on the lunar model


def ar1(rng, n, m, phi):
    """Stationary AR(1) rows ``(n, m)`` with unit innovations."""
    e = rng.standard_normal((n, m))
    x = np.empty((n, m))
    x[0] = e[0] / math.sqrt(1.0 - phi * phi)
    for k in range(1, n):
        x[k] = phi * x[k - 1] + e[k]
    return x


def stream(kind, rng, n, m=3):
    """Synthetic H0 co-state series: iid, AR(1) (phi = 0.7) or first-differenced white noise (the
    default GPF's co-state is close to the latter: lag-1 autocorrelation -0.5)."""
    if kind == "iid":
        x = rng.standard_normal((n, m))
    elif kind == "ar1":
        x = ar1(rng, n, m, 0.7)
    elif kind == "differenced":
        e = rng.standard_normal((n + 1, m))
        x = e[1:] - e[:-1]
    else:
        raise ValueError(kind)
    return x * SCALES[:m]


def buffer_p_values(kind, monitor, tests, seed):
    """p-values of ``tests`` independent buffers laid out as the monitor lays them out (``reference``
    blocks of ``[gap, window]`` then the test block; the monitor's own layout is checked in
    test_monitor_per_step_rate_and_buffer_consistency): under H0 each is one Bernoulli(alpha) alarm."""
    rng = np.random.default_rng(seed)
    stride = monitor.window + monitor.gap
    blocks = monitor.reference + 1
    p = np.empty(tests)
    for t in range(tests):
        x = stream(kind, rng, blocks * stride).reshape(blocks, stride, -1)
        means = x[:, monitor.gap:].mean(axis=1)
        p[t] = hotelling_t2(means[-1], means[:-1])[1]
    return p


@pytest.mark.parametrize("kind", ["iid", "ar1", "differenced"])
def test_false_alarm_rate_within_binomial_band(kind):
    monitor = CostateMonitor()
    tests = 3000
    p = buffer_p_values(kind, monitor, tests, seed={"iid": 1, "ar1": 2, "differenced": 3}[kind])
    for alpha in (0.01, 0.05):
        count = int((p < alpha).sum())
        lo, hi = stats.binom.ppf([1e-4, 1 - 1e-4], tests, alpha)  # two-sided 2e-4 band
        assert lo <= count <= hi, (kind, alpha, count, lo, hi)
    assert stats.kstest(p, "uniform").pvalue > 1e-4


def test_strongly_correlated_stream_breaks_calibration_of_short_windows():
    """The documented limit: a window shorter than the correlation time inflates the false-alarm rate."""
    monitor = CostateMonitor()
    rng = np.random.default_rng(4)
    stride = monitor.window + monitor.gap
    blocks = monitor.reference + 1
    p = []
    for _ in range(1500):
        x = ar1(rng, blocks * stride, 3, 0.97).reshape(blocks, stride, 3)
        means = x[:, monitor.gap:].mean(axis=1)
        p.append(hotelling_t2(means[-1], means[:-1])[1])
    assert np.mean(np.array(p) < 0.05) > 0.08


def test_monitor_per_step_rate_and_buffer_consistency():
    """End to end, the per-step FAULT rate is near the set rate (loose: steps share data), and the
    monitor's p-value is the Hotelling test of its last buffer (the ring buffer is in order)."""
    rng = np.random.default_rng(5)
    monitor = CostateMonitor(false_alarm_rate=0.01, warn_false_alarm_rate=0.05)
    x = stream("ar1", rng, 12000)
    levels = []
    for k in range(x.shape[0]):
        status = monitor.update(x[k], np.ones(3, bool))
        if status.ready:
            levels.append(status.level)
    levels = np.array(levels)
    assert 0.003 < np.mean(levels == "FAULT") < 0.03
    assert 0.015 < np.mean(levels != "OK") < 0.15
    # reference: consecutive blocks of window + gap samples from the first, the last `window` averaged
    stride, n = monitor.stride, x.shape[0]
    blocks = (n - stride) // stride
    expected = x[:blocks * stride].reshape(blocks, stride, 3)[-monitor.reference:, monitor.gap:].mean(axis=1)
    assert monitor.quarantined == 0
    np.testing.assert_allclose(monitor.reference_means, expected, rtol=1e-9)
    t2, p, dim, nu = hotelling_t2(x[-monitor.window:].mean(axis=0), expected)
    assert monitor.status.p_value == pytest.approx(p, rel=1e-9)
    assert monitor.status.statistic == pytest.approx(t2, rel=1e-9)
    assert monitor.status.threshold == pytest.approx(t2_threshold(3, monitor.reference - 1, 0.01))
    assert (dim, nu) == (3, monitor.reference - 1)


def test_threshold_matches_p_value():
    """``statistic > threshold`` exactly when ``p_value < false_alarm_rate``."""
    rng = np.random.default_rng(6)
    for _ in range(200):
        ref = rng.standard_normal((12, 3))
        test = rng.standard_normal(3) * 3
        t2, p, dim, nu = hotelling_t2(test, ref)
        assert (t2 > t2_threshold(dim, nu, 0.01)) == (p < 0.01)


@pytest.mark.parametrize("kind", ["iid", "differenced"])
def test_constant_offset_detected_within_a_window(kind):
    rng = np.random.default_rng(7)
    monitor = CostateMonitor()
    x = stream(kind, rng, 700)
    onset = 400
    x[onset:, 0] += 3.0 * x[:onset, 0].std()  # 3 sigma of the per-sample co-state, one component
    levels = [monitor.update(v, np.ones(3, bool)).level for v in x]
    assert "FAULT" not in levels[:onset]
    first = levels.index("FAULT", onset)
    assert first - onset < monitor.window
    # a persistent offset stays detected: the reference is centred on its own mean
    assert np.mean(np.array(levels[onset + monitor.window:]) == "FAULT") > 0.9


def test_offset_from_the_start_detected_soon_after_ready():
    """An offset present from the first sample: the reference, centred on its own mean, still gives the
    right scale. With few reference windows the threshold is high (the F tail of few dof), so detection
    comes a few windows after the monitor is ready."""
    rng = np.random.default_rng(8)
    monitor = CostateMonitor()
    x = stream("iid", rng, 300) + 2.0 * SCALES
    statuses = [monitor.update(v, np.ones(3, bool)) for v in x]
    first_ready = next(i for i, s in enumerate(statuses) if s.ready)
    assert first_ready == (monitor.min_reference + 1) * monitor.stride - 1
    assert statuses[first_ready].level != "OK"
    first_fault = next(i for i, s in enumerate(statuses) if s.level == "FAULT")
    assert first_fault - first_ready < 6 * monitor.stride
    assert np.mean([s.level == "FAULT" for s in statuses[first_fault:]]) > 0.8


def test_scale_invariance():
    """Self-normalised: per-component rescaling of the co-state leaves every p-value unchanged."""
    rng = np.random.default_rng(9)
    x = stream("iid", rng, 400)
    a, b = CostateMonitor(), CostateMonitor()
    for v in x:
        pa = a.update(v, np.ones(3, bool)).p_value
        pb = b.update(v * np.array([1e-3, 7.0, 1e4]), np.ones(3, bool)).p_value
        assert pa == pytest.approx(pb, rel=1e-6, abs=1e-12)


def test_nan_and_inf_never_raise_and_are_counted():
    rng = np.random.default_rng(10)
    monitor = CostateMonitor()
    x = stream("iid", rng, 200)
    measured = np.ones(3, bool)
    for k, v in enumerate(x):
        monitor.update(v, measured)
        if k % 7 == 0:
            before = monitor.status
            assert monitor.update([np.nan, 1.0, 2.0], measured) is before
            assert monitor.update([1.0, np.inf, 2.0], measured) is before
            assert monitor.update([1.0, 2.0, -np.inf], measured) is before
            monitor.update([np.nan, np.nan, np.nan], np.zeros(3, bool))
    assert monitor.rejected == 3 * len(range(0, 200, 7))
    assert monitor.unmeasured == len(range(0, 200, 7))
    assert monitor.samples == 200
    # NaN in an unmeasured component is not a rejection; default mask = the finite components
    status = monitor.update([0.1, np.nan, 0.2], np.array([True, False, True]))
    assert monitor.rejected == 3 * len(range(0, 200, 7)) and isinstance(status, IntegrityStatus)
    monitor.update([0.1, np.nan, 0.2])
    assert monitor.samples == 202


def test_missing_component_is_left_out():
    """Partial observability: a never-measured component is not tested, whatever its value; an
    intermittently measured one enters once it has been measured throughout the buffer."""
    rng = np.random.default_rng(11)
    monitor = CostateMonitor()
    x = stream("iid", rng, 800)
    x[:, 1] = 1e9  # garbage in the unmeasured component
    partial = np.array([True, False, True])
    for v in x[:400]:
        status = monitor.update(v, partial)
    assert status.ready and status.components == (0, 2) and status.level == "OK"
    x[400:, 1] = rng.standard_normal(400) * SCALES[1]
    for k, v in enumerate(x[400:]):
        status = monitor.update(v, np.ones(3, bool))
        if k < (monitor.reference + 1) * monitor.stride:
            assert status.components == (0, 2)
    assert status.components == (0, 1, 2)


def test_reset_level_and_validation():
    rng = np.random.default_rng(12)
    monitor = CostateMonitor()
    for v in stream("iid", rng, 300) + 5.0 * SCALES:
        monitor.update(v, np.ones(3, bool))
    assert monitor.level == "FAULT" and monitor.ready
    monitor.update([np.nan] * 3, np.ones(3, bool))
    monitor.reset()
    assert monitor.level == "OK" and not monitor.ready and monitor.samples == 0 and monitor.rejected == 0
    assert math.isnan(monitor.status.statistic) and monitor.status.p_value == 1.0
    d = monitor.status.to_dict()
    assert set(d) == {"level", "statistic", "threshold", "p_value", "ready", "components"}
    with pytest.raises(ValueError):
        CostateMonitor(false_alarm_rate=0.1, warn_false_alarm_rate=0.01)
    with pytest.raises(ValueError):
        CostateMonitor(min_reference=1)
    with pytest.raises(ValueError):
        CostateMonitor(window=0)
    with pytest.raises(ValueError):
        monitor.update([1.0, 2.0, 3.0], [True, False])


def test_degenerate_reference_does_not_raise():
    monitor = CostateMonitor()
    for _ in range(300):
        status = monitor.update([0.0, 1.0, 2.0], np.ones(3, bool))  # constant: zero reference variance
    assert status.level == "OK" and not status.ready
    collinear = np.array([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0], [0.0, 0.0]])
    t2, p, dim, _ = hotelling_t2(np.array([1.0, 1.0]), collinear)
    assert dim == 1 and np.isfinite(t2) and 0.0 <= p <= 1.0  # collinear components: rank 1


def _lunar_fault_fraction(epsilon: float, **options) -> tuple[float, object]:
    """Fraction of ready steps at FAULT for a GPF (100 particles) on the lunar descent, and the filter."""
    from gpf_nav.filters import GeometricProjectionPF
    from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

    config = ScenarioConfig(epsilon=epsilon)
    scenario = generate(config, 3)
    flt = GeometricProjectionPF(filter_model(config), 100, seed=4, **options)
    flt.initialize(scenario.prior_mean, scenario.prior_cov)
    monitor = CostateMonitor()
    levels = []
    for k in range(config.steps):
        flt.predict(config.dt)
        flt.update(scenario.measurements[k])
        status = monitor.update(flt.costate_mean, np.isfinite(scenario.measurements[k]))
        if status.ready:
            levels.append(status.level)
    return float(np.mean(np.array(levels) == "FAULT")), flt


def test_lunar_paper_gpf_nominal_mostly_ok_and_mismatch_flagged():
    """The paper's GPF: at epsilon = 0 the monitor is almost always OK; at epsilon = 0.09 it reaches FAULT
    (the velocity error the Euclidean projection does not fix shows in the range co-state)."""
    paper = {"metric": "euclidean", "weighting": "likelihood", "unmodelled_acceleration_std": 0.0}
    assert _lunar_fault_fraction(0.0, **paper)[0] < 0.02
    assert _lunar_fault_fraction(0.09, **paper)[0] > 0.3


def test_lunar_default_gpf_absorbs_the_mismatch_and_reports_it_as_acceleration():
    """The default GPF estimates the unmodelled acceleration: at epsilon = 0.09 its co-state stays
    consistent (no FAULT) and the estimated acceleration is the missing 9 % of gravity instead."""
    from gpf_nav.models import MU_MOON

    nominal, _ = _lunar_fault_fraction(0.0)
    mismatched, flt = _lunar_fault_fraction(0.09)
    assert nominal < 0.02 and mismatched < 0.02
    r = flt.mean[:3]
    missing = -0.09 * MU_MOON * r / np.linalg.norm(r) ** 3
    estimate = flt.unmodelled_acceleration
    sigma = np.sqrt(np.diag(flt.unmodelled_acceleration_covariance))
    assert np.linalg.norm(estimate - missing) < 0.25 * np.linalg.norm(missing)
    assert np.all(np.abs(estimate - missing) < 5 * sigma + 1e-3)
