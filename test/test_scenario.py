"""Tests of the lunar-descent scenario generator (gpf_nav.sim.scenario)."""
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from gpf_nav.models.lunar import MOON_RADIUS, MU_MOON, LunarDescentModel
from gpf_nav.sim.scenario import (Scenario, ScenarioConfig, filter_model, generate, load_csv,
                              parse_flat_yaml, save_csv, truth_model)

CONFIG_FILE = Path(__file__).resolve().parents[1] / "config" / "scenario.yaml"
SHORT = ScenarioConfig(duration=400.0)


def _altitude(s: Scenario) -> np.ndarray:
    return np.linalg.norm(s.truth[:, :3], axis=1) - MOON_RADIUS


def _arrays(s: Scenario) -> list[np.ndarray]:
    return [s.times, s.truth, s.measurements, s.specific_force, s.prior_mean, s.prior_cov]


def _assert_same(a: Scenario, b: Scenario) -> None:
    for x, y in zip(_arrays(a), _arrays(b)):
        np.testing.assert_array_equal(x, y)


def test_shapes_and_times():
    s = generate(ScenarioConfig(), 0)
    k = 1200
    assert s.times.shape == (k,) and s.truth.shape == (k + 1, 6)
    assert s.measurements.shape == (k, 3) and s.specific_force.shape == (k, 3)
    assert s.prior_mean.shape == (6,) and s.prior_cov.shape == (6, 6)
    np.testing.assert_allclose(s.times, 2.0 * np.arange(1, k + 1))
    assert s.start_time == 0.0
    assert not np.any(s.specific_force)
    np.testing.assert_allclose(np.diag(s.prior_cov), [1e6] * 3 + [1.0] * 3)


def test_same_seed_identical_different_seed_different():
    c = ScenarioConfig(duration=200.0, dropout_probability=0.2)
    _assert_same(generate(c, 7), generate(c, 7))
    a, b = generate(c, 7), generate(c, 8)
    assert not np.array_equal(a.truth[1:], b.truth[1:])
    assert not np.array_equal(a.prior_mean, b.prior_mean)
    assert not np.array_equal(a.measurements, b.measurements, equal_nan=True)


def test_streams_are_independent():
    base = generate(SHORT, 3)
    louder = generate(ScenarioConfig(duration=400.0, measurement_noise_scale=3.0), 3)
    np.testing.assert_array_equal(base.truth, louder.truth)
    np.testing.assert_array_equal(base.prior_mean, louder.prior_mean)
    assert not np.array_equal(base.measurements, louder.measurements)
    dropped = generate(ScenarioConfig(duration=400.0, dropout_probability=0.5), 3)
    kept = np.isfinite(dropped.measurements[:, 0])
    np.testing.assert_array_equal(dropped.measurements[kept], base.measurements[kept])
    np.testing.assert_array_equal(dropped.truth, base.truth)


def test_start_state_geometry():
    s = generate(SHORT, 0)
    r_a, r_p = MOON_RADIUS + 100e3, MOON_RADIUS + 15e3
    v_a = math.sqrt(2 * MU_MOON * 1.09 * r_p / (r_a * (r_a + r_p)))
    inc = math.radians(30.0)
    np.testing.assert_allclose(s.truth[0], [r_a, 0, 0, 0, v_a * math.cos(inc), v_a * math.sin(inc)])
    assert _altitude(s)[0] == pytest.approx(100e3)


@pytest.mark.parametrize("eps, half_period", [(0.0, 3412.0), (0.09, 3268.0)])
def test_descends_to_15_km_perilune_in_half_a_period(eps, half_period):
    c = ScenarioConfig(epsilon=eps, duration=3600.0, truth_accel_noise_density=0.0)
    s = generate(c, 0)
    alt = _altitude(s)
    assert alt.min() == pytest.approx(15e3, abs=5.0)
    t = np.concatenate([[0.0], s.times])
    assert t[np.argmin(alt)] == pytest.approx(half_period, abs=2 * c.dt)


def test_truth_uses_scaled_gravity():
    c = ScenarioConfig(truth_accel_noise_density=0.0)
    s = generate(c, 0)
    r = np.linalg.norm(s.truth[:, :3], axis=1)
    kinetic = 0.5 * np.einsum("ij,ij->i", s.truth[:, 3:], s.truth[:, 3:])
    scaled = kinetic - MU_MOON * (1 + c.epsilon) / r
    nominal = kinetic - MU_MOON / r
    assert np.ptp(scaled) / abs(scaled[0]) < 1e-9
    assert np.ptp(nominal) / abs(nominal[0]) > 1e-3
    h = np.cross(s.truth[:, :3], s.truth[:, 3:])
    assert np.max(np.abs(h - h[0])) < 1e-10 * np.linalg.norm(h[0])
    fine = LunarDescentModel(mu_scale=1.0 + c.epsilon, max_step=0.05)
    np.testing.assert_allclose(fine.transition(s.truth[:-1], c.dt), s.truth[1:], rtol=0, atol=1e-5)


def test_truth_noise_has_the_process_noise_covariance():
    c = ScenarioConfig(duration=1600.0)
    s = generate(c, 5)
    fine = LunarDescentModel(mu_scale=1.0 + c.epsilon, max_step=0.05)
    w = s.truth[1:] - fine.transition(s.truth[:-1], c.dt)
    q = truth_model(c).process_noise(c.dt)
    np.testing.assert_allclose(w.std(axis=0) / np.sqrt(np.diag(q)), 1.0, atol=0.12)
    corr = np.corrcoef(w[:, 0], w[:, 3])[0, 1]
    assert corr == pytest.approx(q[0, 3] / math.sqrt(q[0, 0] * q[3, 3]), abs=0.1)


def test_measurements_match_model_within_noise():
    c = ScenarioConfig()
    s = generate(c, 11)
    model = filter_model(c)
    r = model.residual(s.measurements, model.measure(s.truth[1:]))
    z = r / np.sqrt(np.diag(model.measurement_noise()))
    assert np.all(np.abs(z) < 6.0)
    np.testing.assert_allclose(z.std(axis=0), 1.0, atol=0.1)
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=0.15)
    assert np.all(np.abs(s.measurements[:, 1]) <= np.pi)


def test_noise_scale_scales_residuals():
    c = ScenarioConfig(duration=800.0, measurement_noise_scale=4.0)
    s = generate(c, 2)
    base = filter_model(ScenarioConfig())
    r = base.residual(s.measurements, base.measure(s.truth[1:]))
    ratio = r.std(axis=0) / np.sqrt(np.diag(base.measurement_noise()))
    np.testing.assert_allclose(ratio, 4.0, rtol=0.15)
    assert filter_model(c).range_noise_std == pytest.approx(120.0)


def test_partial_case_never_measures_azimuth():
    s = generate(ScenarioConfig(case="partial"), 4)
    assert np.all(np.isnan(s.measurements[:, 1]))
    assert np.all(np.isfinite(s.measurements[:, [0, 2]]))


def test_range_case_measures_only_the_range():
    full, ranged = generate(ScenarioConfig(), 4), generate(ScenarioConfig(case="range"), 4)
    assert np.all(np.isnan(ranged.measurements[:, 1:]))
    np.testing.assert_array_equal(ranged.measurements[:, 0], full.measurements[:, 0])
    np.testing.assert_array_equal(ranged.truth, full.truth)


def test_measurement_bias_is_a_constant_shift_in_channel_sigmas():
    """The bias is given in standard deviations of each channel, after the noise scale; nothing else
    changes."""
    base = generate(ScenarioConfig(duration=400.0, measurement_noise_scale=2.0), 5)
    biased = generate(ScenarioConfig(duration=400.0, measurement_noise_scale=2.0,
                                     measurement_bias_sigma=(2.0, -1.0, 0.5)), 5)
    shift = biased.measurements - base.measurements
    np.testing.assert_allclose(shift, np.broadcast_to([120.0, -2 * math.radians(0.03),
                                                       math.radians(0.03)], shift.shape), rtol=1e-6)
    np.testing.assert_array_equal(biased.truth, base.truth)
    np.testing.assert_array_equal(biased.prior_mean, base.prior_mean)


def test_outliers_rate_size_and_their_own_stream(tmp_path):
    """Each component is an outlier with the given probability, exactly outlier_size channel sigmas
    off with a random sign; the other components, the truth and the prior are untouched; a larger
    probability keeps the outliers of a smaller one (the same draws); load_csv draws the same ones."""
    config = ScenarioConfig(duration=2400.0, outlier_probability=0.03, outlier_size=20.0)
    base, noisy = generate(ScenarioConfig(), 6), generate(config, 6)
    std = np.array([30.0, math.radians(0.03), math.radians(0.03)])
    sigmas = (noisy.measurements - base.measurements) / std
    sigmas[:, 1] = (noisy.measurements[:, 1] - base.measurements[:, 1] + math.pi) % (2 * math.pi) - math.pi
    sigmas[:, 1] /= std[1]
    hit = np.abs(sigmas) > 1e-6
    np.testing.assert_allclose(np.abs(sigmas[hit]), 20.0, rtol=1e-6)
    assert 0.3 < np.mean(sigmas[hit] > 0) < 0.7
    assert abs(hit.mean() - 0.03) < 4 * math.sqrt(0.03 * 0.97 / hit.size)
    np.testing.assert_array_equal(noisy.truth, base.truth)
    np.testing.assert_array_equal(noisy.prior_mean, base.prior_mean)
    more = generate(dataclasses.replace(config, outlier_probability=0.1), 6)
    assert np.all(more.measurements[hit] == noisy.measurements[hit])
    save_csv(noisy, tmp_path / "truth.csv")
    _assert_same(load_csv(tmp_path / "truth.csv", config, 6), noisy)


def test_dropout_rate():
    p = 0.3
    s = generate(ScenarioConfig(dropout_probability=p), 9)
    lost = np.all(np.isnan(s.measurements), axis=1)
    partial = np.any(np.isnan(s.measurements), axis=1) & ~lost
    assert not np.any(partial)
    assert abs(lost.mean() - p) < 4 * math.sqrt(p * (1 - p) / lost.size)


def test_models():
    c = ScenarioConfig()
    assert filter_model(c).gm == pytest.approx(MU_MOON)
    assert truth_model(c).gm == pytest.approx(MU_MOON * 1.09)
    assert filter_model(c).accel_noise_density == c.filter_accel_noise_density
    assert filter_model(c).angle_noise_std == pytest.approx(5.236e-4, rel=1e-4)


def test_thrust_is_retrograde_specific_force():
    coast = generate(SHORT, 1)
    s = generate(ScenarioConfig(duration=400.0, thrust=0.5), 1)
    v = s.truth[:-1, 3:]
    np.testing.assert_allclose(np.linalg.norm(s.specific_force, axis=1), 0.5)
    np.testing.assert_allclose(np.einsum("ij,ij->i", s.specific_force, v),
                               -0.5 * np.linalg.norm(v, axis=1))
    speed = np.linalg.norm(s.truth[-1, 3:]) - np.linalg.norm(coast.truth[-1, 3:])
    assert speed == pytest.approx(-0.5 * 400.0, rel=0.1)


def test_refuses_a_truth_below_the_surface():
    with pytest.raises(ValueError, match="surface"):
        generate(ScenarioConfig(orbit_design="filter"), 0)
    s = generate(ScenarioConfig(orbit_design="filter", duration=1000.0), 0)
    assert _altitude(s).min() > 5e3


def test_config_file_holds_the_defaults():
    assert ScenarioConfig.from_yaml(CONFIG_FILE) == ScenarioConfig()
    assert ScenarioConfig.from_dict(ScenarioConfig().to_dict()) == ScenarioConfig()


def test_flat_yaml_parser(tmp_path):
    text = ("# comment\n\nepsilon: 0   # int becomes float\ncase: 'partial'\nthrust: 0.25\n"
            "station: [1, 2.5, -3e3]\ndropout_probability: 1e-2\n")
    f = tmp_path / "s.yaml"
    f.write_text(text)
    c = ScenarioConfig.from_yaml(f)
    assert c.epsilon == 0.0 and isinstance(c.epsilon, float)
    assert c.case == "partial" and c.thrust == 0.25 and c.dropout_probability == 0.01
    assert c.station == (1.0, 2.5, -3000.0)
    parsed = parse_flat_yaml("a: null\nb: true\nc: [ ]\nd: word")
    assert parsed == {"a": None, "b": True, "c": [], "d": "word"}
    for bad in ("a: 1\na: 2", "a:\n  b: 1", "just text"):
        with pytest.raises(ValueError):
            parse_flat_yaml(bad)
    with pytest.raises(ValueError, match="unknown"):
        ScenarioConfig.from_dict({"epsilom": 0.1})


@pytest.mark.parametrize("kwargs", [{"case": "half"}, {"dropout_probability": 1.5}, {"dt": 0.0},
                                    {"measurement_noise_scale": 0.0}, {"orbit_design": "x"},
                                    {"duration": 1.0}, {"outlier_probability": 1.5}, {"outlier_size": -1.0},
                                    {"measurement_bias_sigma": (math.nan, 0.0, 0.0)}])
def test_invalid_config(kwargs):
    with pytest.raises(ValueError):
        ScenarioConfig(**kwargs)


def test_csv_round_trip(tmp_path):
    c = ScenarioConfig(duration=300.0, thrust=0.1, case="partial", dropout_probability=0.1)
    s = generate(c, 21)
    path = tmp_path / "truth.csv"
    save_csv(s, path)
    _assert_same(load_csv(path, c, 21), s)
    assert path.read_text().startswith("t,x,y,z")


def test_csv_without_header_or_force(tmp_path):
    s = generate(SHORT, 2)
    rows = np.column_stack([10.0 + np.concatenate([[0.0], s.times]), s.truth])
    path = tmp_path / "bare.csv"
    np.savetxt(path, rows, delimiter=",", fmt="%.17g")
    replay = load_csv(path, SHORT, 2)
    np.testing.assert_array_equal(replay.truth, s.truth)
    np.testing.assert_array_equal(replay.times, 10.0 + s.times)
    assert replay.start_time == 10.0 and not np.any(replay.specific_force)
    np.testing.assert_array_equal(replay.measurements, s.measurements)
    bad = tmp_path / "bad.csv"
    np.savetxt(bad, rows[::-1], delimiter=",")
    with pytest.raises(ValueError, match="increasing"):
        load_csv(bad)


def test_disturbance_is_a_hidden_constant_world_frame_acceleration():
    quiet = ScenarioConfig(duration=40.0, truth_accel_noise_density=0.0)
    push = np.array([0.3, -0.2, 0.1])
    a, b = generate(quiet, 1), generate(ScenarioConfig(**{**quiet.to_dict(), "disturbance": tuple(push)}), 1)
    t = a.times[-1]
    # over 40 s the two-body gradient acts on the 240 m offset: 1e-5 relative, far below the tolerance
    np.testing.assert_allclose(b.truth[-1, :3] - a.truth[-1, :3], 0.5 * push * t ** 2, rtol=1e-3)
    np.testing.assert_allclose(b.truth[-1, 3:] - a.truth[-1, 3:], push * t, rtol=1e-3)
    assert not b.specific_force.any()  # neither the filters nor the IMU are told
    with pytest.raises(ValueError, match="disturbance"):
        ScenarioConfig(disturbance=(0.0, math.nan, 0.0))
