"""The compiled kernels (gpf_nav/kernels) against the numpy code they replaced (test/numpy_reference.py)
on the same inputs, and a short seeded run of the particle filters against the estimates the numpy code
gave (test/data/kernels_reference.json: :func:`_run` of every filter on the numpy code, at 200c859)."""
from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import numpy_reference as reference
from gpf_nav import resampling
from gpf_nav.filters import BootstrapPF, GeometricProjectionPF, MultipleModelGPF
from gpf_nav.filters.kernel import match_moments
from gpf_nav.filters.likelihood import log_likelihood
from gpf_nav.filters.model_averaging import mixture_moments
from gpf_nav.filters.projection import project, select_columns, select_rows
from gpf_nav.linalg import positive_definite
from gpf_nav.kernels import (VECTOR_MATH, bearing, cloud, covariance, diagonal_projection, information, log_weights,
                             orbit)
from gpf_nav.kernels import curvature as curvature_kernels
from gpf_nav.kernels.curvature import departure, largest_scaled, quadratic_departure, scaled_by_particle
from gpf_nav.kernels.normals import fill_standard_normal
from gpf_nav.kernels.systematic import systematic_ancestors
from gpf_nav.models.compensation import ModelErrorCompensation
from gpf_nav.models.lunar import MU_MOON, LunarDescentModel
from gpf_nav.models.state_space import wrapped_residual
from gpf_nav.sensors.model import ModelSensor
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

RTOL = 1e-12
SIZES = (1, 7, 500, 3001)  # below, at and across the kernels' blocks of 256 particles
REFERENCE = Path(__file__).with_name("data") / "kernels_reference.json"


def _cloud(rng, n, count):
    x = rng.standard_normal((n, count)) * rng.uniform(1.0, 1e3, (n, 1)) + rng.uniform(-1e6, 1e6, (n, 1))
    w = rng.random(count) ** 4
    return x, w / w.sum()


def _orbits(rng, count):
    """States ``(6, N)`` around a 1 838 km orbit, with a few degenerate ones (r parallel to v, r = 0,
    v = 0, NaN)."""
    r = rng.standard_normal((3, count))
    r *= 1.838e6 / np.linalg.norm(r, axis=0)
    v = rng.standard_normal((3, count)) * 1.6e3
    x = np.vstack([r, v])
    if count >= 7:
        x[:, :4] = [[1.8e6, 0, 0, np.nan], [0, 0, 0, 0], [0, 0, 0, 0], [10.0, 0, 5.0, 0], [0, 0, 0, 0], [0, 0, 1.0, 0]]
    return np.ascontiguousarray(x)


def _close(got, expected, rtol=RTOL, atol=0.0):
    np.testing.assert_allclose(got, expected, rtol=rtol, atol=atol)


@pytest.mark.parametrize("count", SIZES)
def test_moments_and_the_moment_map_are_the_numpy_ones(count):
    rng = np.random.default_rng(count)
    x, w = _cloud(rng, 9, count)
    mean, cov = cloud.moments(x, w)
    expected_mean, expected_cov = reference.weighted_moments(x, w)
    _close(mean, expected_mean)
    scale = np.sqrt(np.outer(np.diag(expected_cov), np.diag(expected_cov)))
    _close(cov / np.where(scale > 0, scale, 1.0), expected_cov / np.where(scale > 0, scale, 1.0), atol=1e-12)
    np.testing.assert_array_equal(cov, cov.T)
    # the mean alone is the same number (a filter reads it with or without the covariance)
    np.testing.assert_array_equal(cloud.weighted_mean(x, w), mean)
    if count >= 9:
        target = rng.standard_normal(9)
        A = rng.standard_normal((9, 9))
        target_cov = A @ A.T + np.eye(9)
        _close(match_moments(x, w, target, target_cov), reference.match_moments(x, w, target, target_cov),
               atol=1e-9 * np.abs(target).max())


@pytest.mark.parametrize("count", SIZES)
def test_the_count_of_particles_beyond_the_state_limit_is_the_numpy_one(count):
    """The particle filters' non-finite check: NaN, infinite and huge components, in any row."""
    rng = np.random.default_rng(40 + count)
    for rows in (1, 6, 9):
        x = rng.standard_normal((rows, count)) * 1e149
        hit = rng.integers(0, count, 3)
        x[0, hit[0]], x[rows - 1, hit[1]], x[:, hit[2]] = np.nan, np.inf, 0.9e150
        assert cloud.count_outside(x, 1e150) == np.count_nonzero(~(np.abs(x.sum(axis=0)) < 1e150))


@pytest.mark.parametrize("count", (*SIZES, 8, 128, 129, 1037, VECTOR_MATH, 70_001))  # numpy's summation blocks
def test_the_log_weight_normalisation_is_the_numpy_one_bit_for_bit(count):
    """The log-sum-exp in numpy's pairwise order, with NaN, zero and dominant weights; every weight zero
    or one infinite gives NaN and writes nothing."""
    rng = np.random.default_rng(60 + count)
    probe = rng.standard_normal(1000) * 30.0
    # with numpy's exp, or the C library's where numpy's is it (x86-64 without AVX-512): bit for bit; else
    # to rounding
    exact = count >= VECTOR_MATH or np.array_equal(np.exp(probe), [math.exp(v) for v in probe.tolist()])
    same = np.testing.assert_array_equal if exact else lambda a, b: _close(a, b, atol=1e-300)
    for case in range(-4, 4):
        logw = rng.standard_normal(count) * (30.0 if case >= 0 else 1.0)  # (weights alike: the order shows)
        if case in (1, 2):
            logw[rng.random(count) < 0.5] = np.nan if case == 1 else -np.inf
            logw[-1] = 0.0  # at least one weight
        elif case == 3:
            logw[rng.integers(count)] = 1e3
        expected = reference.normalise(logw.copy())
        normalised, weights = np.full(count, 7.0), np.full(count, 7.0)
        total = log_weights.normalise(logw, normalised, weights)
        same(np.array(total), np.array(expected[0]))
        same(normalised, expected[1])
        same(weights, expected[2])
        assert not np.isnan(logw).any()  # set to -inf in place, as the numpy code did
    for empty in (np.full(count, -np.inf), np.full(count, np.nan), np.r_[np.zeros(count - 1), np.inf]):
        untouched = np.full(count, 7.0)
        assert np.isnan(log_weights.normalise(empty, untouched, untouched))
        assert (untouched == 7.0).all()


@pytest.mark.parametrize("count", (*SIZES, 2, VECTOR_MATH))
def test_the_gaussian_log_likelihood_is_the_numpy_one_bit_for_bit(count):
    """A diagonal whitener's in one compiled pass, every row or some, residuals of every magnitude and NaN;
    a full whitener's (the numpy code) alike."""
    rng = np.random.default_rng(70 + count)
    for m in (1, 3, 6):
        e = rng.standard_normal((m, count)) * 10.0 ** rng.uniform(-8, 6, (m, 1))
        e[0, ::5] = np.nan
        for rows in (np.ones(m, bool), np.arange(m) != m // 2):
            k = int(rows.sum())
            for w in (10.0 ** rng.uniform(-6, 8, k), np.tril(rng.standard_normal((k, k))) + 3.0 * np.eye(k)):
                constant = float(rng.standard_normal() * 10.0)
                got = log_likelihood(e.copy(), rows, (w, constant))
                np.testing.assert_array_equal(got, reference.gaussian_log_likelihood(e, rows, w, constant))


@pytest.mark.parametrize("count", SIZES)
def test_systematic_resampling_is_the_numpy_one(count):
    rng = np.random.default_rng(20 + count)
    _, w = _cloud(rng, 1, count)
    for uniform in (0.0, 0.37, 0.999):
        np.testing.assert_array_equal(systematic_ancestors(w, uniform), reference.systematic(w, uniform))
    # the largest uniform draw, 1 - 2^-53, rounds N - U to N - 1: the numpy code lost the last ancestor
    assert systematic_ancestors(w, 1.0 - 2.0 ** -53).size == count
    # the stream: one uniform from the filter's generator, as before
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    np.testing.assert_array_equal(resampling.systematic(w, a), reference.systematic(w, b.random()))
    assert a.random() == b.random()


@pytest.mark.parametrize("count", SIZES)
@pytest.mark.parametrize("steps", (1, 3))
@pytest.mark.parametrize("inputs", ("none", "one", "each"))
def test_lunar_flow_and_jacobian_are_the_numpy_ones(count, steps, inputs):
    rng = np.random.default_rng(30 + count)
    x = _orbits(rng, count)[:, 4:] if count >= 7 else _orbits(rng, count)
    u = {"none": None, "one": np.array([0.1, -0.2, 0.3]), "each": rng.standard_normal((x.shape[1], 3))}[inputs]
    model = LunarDescentModel(max_step=10.0)
    dt = 10.0 * steps
    _close(model.transition(x.T, dt, 0.0, u), reference.leapfrog(x.T, MU_MOON, 10.0, steps, u))
    _close(model.transition_jacobian(x.T, dt, 0.0, u), reference.leapfrog_jacobian(x.T, MU_MOON, 10.0, steps, u),
           atol=1e-15)


@pytest.mark.parametrize("count", SIZES)
def test_orbit_frames_and_push_are_the_numpy_ones(count):
    rng = np.random.default_rng(40 + count)
    x = _orbits(rng, count)
    frame = LunarDescentModel().compensation_frame(x.T)
    _close(frame, reference.frames(x.T), atol=1e-15)
    a = np.ascontiguousarray(rng.standard_normal((3, count)))
    moved = np.ascontiguousarray(rng.standard_normal((9, count)))
    expected = reference.push(moved, frame.transpose(1, 2, 0), a, np.arange(3, 6), np.arange(3), 2.0, 2.5)
    orbit.push(moved, np.ascontiguousarray(frame.transpose(1, 2, 0)), a, np.arange(3, 6), np.arange(3), 2.0, 2.5)
    _close(moved, expected, atol=1e-15)


@pytest.mark.parametrize("count", SIZES)
def test_the_parallel_orbit_loops_are_the_serial_ones_bit_for_bit(count):
    """The loops that run on every core from ``PARALLEL`` particles (called here directly, at any N) give
    the serial loops' numbers exactly, degenerate orbits and per-particle inputs included."""
    rng = np.random.default_rng(60 + count)
    x = _orbits(rng, count)
    for u in (np.zeros((3, 1)), np.ascontiguousarray(rng.standard_normal((3, count)))):
        np.testing.assert_array_equal(orbit._leapfrog_parallel(x, MU_MOON, 10.0, 3, u),
                                      orbit._leapfrog_serial(x, MU_MOON, 10.0, 3, u))
    frame = orbit._frames_serial(x)
    np.testing.assert_array_equal(orbit._frames_parallel(x), frame)
    a = np.ascontiguousarray(rng.standard_normal((3, count)))
    moved = np.ascontiguousarray(rng.standard_normal((9, count)))
    serial, parallel = moved.copy(), moved.copy()
    for rows in (np.arange(3), np.arange(0)):
        orbit._push_serial(serial, frame, a, np.arange(3, 6), rows, 2.0, 2.5)
        orbit._push_parallel(parallel, frame, a, np.arange(3, 6), rows, 2.0, 2.5)
        np.testing.assert_array_equal(parallel, serial)


@pytest.mark.parametrize("count", SIZES)
def test_the_compensated_flow_in_one_pass_is_the_three_kernels_bit_for_bit(count):
    """``pushed_leapfrog`` (the compensated lunar transition's fast path) gives the numbers of the flow, the
    frames and the push in turn, serial and parallel, degenerate orbits and per-particle inputs included."""
    rng = np.random.default_rng(70 + count)
    x = _orbits(rng, count)
    a = np.ascontiguousarray(rng.standard_normal((3, count)) * 1e-3)
    for u in (np.zeros((3, 1)), np.ascontiguousarray(rng.standard_normal((3, count)))):
        for integrated in (np.arange(3), np.zeros(0, dtype=int)):
            expected = orbit.leapfrog(x, MU_MOON, 10.0, 3, u)
            orbit.push(expected, orbit.frames(x), a, np.arange(3, 6), integrated, 7.0, 3.0)
            for kernel in (orbit._pushed_leapfrog_serial, orbit._pushed_leapfrog_parallel):
                out = np.empty((9, count))
                kernel(x, a, MU_MOON, 10.0, 3, u, np.arange(3, 6), integrated, 7.0, 3.0, out[:6])
                np.testing.assert_array_equal(out[:6], expected)


@pytest.mark.parametrize("count", SIZES)
def test_the_residual_and_the_line_of_sight_are_the_numpy_ones_bit_for_bit(count):
    """Wrapped or not (a wrap anywhere subtracts ``2 pi * turns`` from every angle, signed zeros
    included), non-finite residuals, broadcast and stacked shapes; the lunar line of sight."""
    rng = np.random.default_rng(90 + count)
    with np.errstate(invalid="ignore"):
        for mask in ([False, True, True], [True, False, True], [False, False], [True]):
            mask = np.array(mask)
            for scale in (0.5, 4.0):
                y = rng.standard_normal((count, mask.size)) * scale
                h = rng.standard_normal((count, mask.size)) * 0.5
                y[0, -1], h[0, -1] = -0.0, 0.0
                if count >= 7:
                    y[1, 0], y[2, -1] = np.nan, np.inf
                for a, b in ((y, h), (np.asfortranarray(y), h[:1]), (y[0], h), (np.stack([y, y]), h[0])):
                    got = wrapped_residual(a, b, mask)
                    expected = reference.wrapped_residual(a, b, mask)
                    assert got.shape == expected.shape
                    np.testing.assert_array_equal(got.view(np.int64), expected.view(np.int64))
    model = LunarDescentModel(station=(1.7e6, 1e3, 2e3))
    x = _orbits(rng, count).T
    for states in (x, np.ascontiguousarray(x)):
        for got, expected in zip(model._line_of_sight(states), reference.line_of_sight(states, model.station)):
            np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("count", SIZES)
@pytest.mark.parametrize("parallel", (False, True))
def test_the_lunar_measurement_jacobian_is_the_numpy_one_bit_for_bit(count, parallel, monkeypatch):
    """Every entry, signed zeros included, at orbits with degenerate states (the station, its vertical,
    NaN, inf) among them; serial and on every core."""
    monkeypatch.setattr(bearing, "PARALLEL", 1 if parallel else 10 ** 9)
    rng = np.random.default_rng(95 + count)
    model = LunarDescentModel(station=(1.7e6, 1e3, 2e3))
    x = _orbits(rng, count)
    if count >= 7:
        x[:3, 4:7] = [[1.7e6, 1.7e6, np.inf], [1e3, 1e3, 0.0], [2e3, -5e5, 0.0]]
    with np.errstate(invalid="ignore"):
        d, horizontal, rho = model._line_of_sight(x.T)
        got = bearing.range_bearing_jacobian(d, horizontal, rho, 1e-3, 1.0)
        expected = reference.range_bearing_jacobian(d, horizontal, rho)
    np.testing.assert_array_equal(got.view(np.int64), expected.view(np.int64))


@pytest.mark.parametrize("count", (*SIZES, VECTOR_MATH, VECTOR_MATH + 7))
def test_the_lunar_measurement_residual_is_the_numpy_one_bit_for_bit(count):
    """``y - h(x)`` and ``h(x) - y`` against the numpy measurement and residual, below and from the count
    where numpy's arctangent takes over: azimuths on both sides of the cut (every angle wrapped), none near
    it (none wrapped), a component not measured (NaN: every angle wrapped), degenerate states; and through
    the compensated model and its sensor."""
    rng = np.random.default_rng(97 + count)
    model = LunarDescentModel(station=(1.7e6, 1e3, 2e3))
    x = _orbits(rng, count)
    across = np.array([1.0e5, np.pi - 1e-3, 0.2])
    ahead = np.array([1.0e5, 0.1, 0.2])
    # with numpy's arctangent, or the C library's where numpy's is it (x86-64 without AVX-512): bit for
    # bit; else to rounding
    probe = rng.standard_normal((2, 1000))
    exact = count >= VECTOR_MATH or np.array_equal(np.arctan2(*probe),
                                                     [math.atan2(a, b) for a, b in probe.T.tolist()])

    def same(got, expected):
        if exact:
            np.testing.assert_array_equal(got.view(np.int64), expected.view(np.int64))
        else:
            _close(got, expected, atol=1e-9)

    with np.errstate(invalid="ignore"):
        for y in (across, ahead, np.array([1.0e5, np.nan, 0.2])):
            for reverse in (False, True):
                h = model.measure(x.T)
                expected = model.residual(h, y) if reverse else model.residual(y, h)
                same(model.measurement_residual(y, x.T, 0.0, reverse), expected)
        compensated = ModelErrorCompensation(model, 1e6, 0.1)
        augmented = np.ascontiguousarray(np.vstack([x, rng.standard_normal((3, count))]))
        expected = model.residual(across, model.measure(x.T))
        for owner in (compensated, ModelSensor(compensated)):
            same(owner.measurement_residual(across, augmented.T, 0.0), expected)


class _OffsetRange(LunarDescentModel):
    """A user's lunar model with a measurement of its own (a range offset)."""

    def measure(self, x, t=0.0):
        return super().measure(x, t) + np.array([50.0, 0.0, 0.0])


def test_a_lunar_model_with_its_own_measurement_gets_its_own_residual():
    x = _orbits(np.random.default_rng(98), 20)
    model, y = _OffsetRange(), np.array([1.0e5, 0.1, 0.2])
    np.testing.assert_array_equal(model.measurement_residual(y, x.T), model.residual(y, model.measure(x.T)))
    assert not np.array_equal(model.measurement_residual(y, x.T), LunarDescentModel().measurement_residual(y, x.T))


@pytest.mark.parametrize("count", SIZES)
@pytest.mark.parametrize("parallel", (False, True))
def test_the_orthogonal_projection_is_the_numpy_one_bit_for_bit(count, parallel, monkeypatch):
    """The shift (returned, or added into the particles) and the co-state increment of the lunar
    measurement, every row or two of them, at orbits with degenerate states (the station: a zero
    Jacobian; NaN) among them; serial and on every core."""
    monkeypatch.setattr(diagonal_projection, "PARALLEL", 1 if parallel else 10 ** 9)
    rng = np.random.default_rng(97 + count)
    model = LunarDescentModel(station=(1.7e6, 1e3, 2e3))
    x = _orbits(rng, count)
    if count >= 7:
        x[:3, 4] = model.station
    with np.errstate(invalid="ignore", divide="ignore"):
        h, H = model.measure_and_jacobian(x.T)
        r = model.residual(model.measure(x.T + rng.standard_normal((count, 6)) * 1e3), h)
        full = 1.0 / np.sqrt(np.diag(model.measurement_noise()))
        for rows, columns in ((np.array([True, True, True]), (0, 1, 2)), (np.array([True, False, True]), (0, 1, 2)),
                              (np.array([True, True, True]), None)):
            Hr, rr, w = select_rows(H, rows), select_columns(r, rows), full[rows]  # (the filters' layouts)
            expected = reference.orthogonal_projection(Hr, rr, w, 1e-6, list(range(6)) if columns is None else
                                                       list(columns))
            for W in (w, np.diag(w)):
                shift, a = project(Hr, rr, W, 1e-6, columns=columns, orthogonal_rows=True)
                moved = x.copy()
                assert project(Hr, rr, W, 1e-6, columns=columns, orthogonal_rows=True, out=moved)[0] is None
                for got, want in ((shift, expected[0]), (a, expected[1]), (moved, x + expected[0])):
                    if count == 1:  # the one-point Jacobian is row-major: einsum then sums along its rows
                        _close(got, want, rtol=1e-15)
                    else:
                        np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))


@pytest.mark.parametrize("count", SIZES)
def test_the_flattening_size_tests_are_the_numpy_ones(count):
    rng = np.random.default_rng(100 + count)
    nu, previous = rng.standard_normal((2, count, 9)) * rng.uniform(0.1, 10.0, 9)
    scale = rng.uniform(0.1, 2.0, 9)
    assert largest_scaled(nu, np.zeros((0, 0)), scale) == np.abs(nu / scale).max()
    assert largest_scaled(nu, previous, scale) == np.abs((nu - previous) / scale).max()
    nu[-1, 4] = np.nan
    assert np.isnan(largest_scaled(nu, np.zeros((0, 0)), scale))
    assert np.isnan(largest_scaled(nu, previous, scale))


@pytest.mark.parametrize("count", SIZES)
def test_each_particles_scaled_curvature_is_the_numpy_one(count):
    rng = np.random.default_rng(200 + count)
    nu = rng.standard_normal((count, 9)) * rng.uniform(0.1, 10.0, 9)
    scale = rng.uniform(0.1, 2.0, 9)
    out = np.empty(count)
    assert not scaled_by_particle(nu, scale, out)
    np.testing.assert_array_equal(out, np.abs(nu / scale).max(axis=1))
    nu[count // 2, 4] = np.nan
    assert scaled_by_particle(nu, scale, out)


@pytest.mark.parametrize("count", SIZES)
def test_the_flattening_departures_are_the_numpy_ones(count):
    """Residual minus its linear part at the mean, into columns of a wider array; serial and parallel
    loops alike bit for bit (equal to the BLAS product to rounding, and bit for bit where that product is
    a chain of fused multiply-adds)."""
    rng = np.random.default_rng(110 + count)
    x, _ = _cloud(rng, 9, count)
    mean, jacobian = x.mean(axis=1), rng.standard_normal((3, 9))
    for residual in (rng.standard_normal((count, 3)), np.asfortranarray(rng.standard_normal((count, 3)))):
        expected = residual - (x.T - mean) @ jacobian.T
        for kernel in (departure, curvature_kernels._departure_parallel):
            out = np.full((count, 9), np.nan)
            kernel(residual, x, mean, jacobian, out, 3)
            _close(out[:, 3:6], expected, atol=1e-12 * np.abs((x.T - mean) @ np.abs(jacobian).T).max())
            assert np.isnan(out[:, :3]).all() and np.isnan(out[:, 6:]).all()
        serial = np.empty((count, 3))
        curvature_kernels._departure_serial(residual, x, mean, jacobian, serial, 0)
        parallel = np.empty((count, 3))
        curvature_kernels._departure_parallel(residual, x, mean, jacobian, parallel, 0)
        np.testing.assert_array_equal(parallel, serial)



@pytest.mark.parametrize("count", SIZES)
def test_the_second_order_departures_are_the_numpy_ones(count):
    """``d^T T_c d / 2`` of every particle for each symmetric ``T_c``, into columns of a wider array, to
    rounding; serial and parallel loops alike bit for bit."""
    rng = np.random.default_rng(120 + count)
    x, _ = _cloud(rng, 9, count)
    mean = x.mean(axis=1)
    hessians = rng.standard_normal((4, 9, 9))
    hessians += hessians.transpose(0, 2, 1)
    d = x.T - mean
    expected = 0.5 * np.einsum("ni,cij,nj->nc", d, hessians, d)
    scale = np.einsum("ni,cij,nj->nc", np.abs(d), np.abs(hessians), np.abs(d)).max()
    out = np.full((count, 8), np.nan)
    quadratic_departure(x, mean, hessians, out, 2)
    _close(out[:, 2:6], expected, atol=1e-13 * scale)
    assert np.isnan(out[:, :2]).all() and np.isnan(out[:, 6:]).all()
    upper = np.ascontiguousarray(np.triu(hessians, 1) + 0.5 * np.diagonal(hessians, axis1=1, axis2=2)[:, :, None]
                                 * np.eye(9))
    serial, parallel = np.empty((count, 4)), np.empty((count, 4))
    curvature_kernels._quadratic_serial(x, mean, upper, serial, 0)
    curvature_kernels._quadratic_parallel(x, mean, upper, parallel, 0)
    np.testing.assert_array_equal(parallel, serial)


class _WithoutFastPath(LunarDescentModel):
    """The lunar model as a user's framed model would be: no compensated fast paths."""

    def pushed_transition(self, *args):
        return False

    def compensation_push_derivative(self, *args):
        return None


@pytest.mark.parametrize("inputs", ("none", "each"))
def test_the_compensated_fast_path_is_the_generic_transition_bit_for_bit(inputs):
    rng = np.random.default_rng(80)
    x = np.ascontiguousarray(np.vstack([_orbits(rng, 300), rng.standard_normal((3, 300)) * 0.1]))
    u = None if inputs == "none" else rng.standard_normal((300, 3))
    fast = ModelErrorCompensation(LunarDescentModel(), 1e6, 0.1).transition(x.T, 25.0, 0.0, u)
    generic = ModelErrorCompensation(_WithoutFastPath(), 1e6, 0.1).transition(x.T, 25.0, 0.0, u)
    np.testing.assert_array_equal(fast, generic)


@pytest.mark.parametrize("count", (1, 7, 300))
def test_the_compensated_jacobian_fast_path_is_the_generic_one_bit_for_bit(count):
    """The frame's central differences in one kernel against the generic differences of the frames,
    degenerate orbits (no plane, r = 0, NaN), signed zeros and infinities included."""
    rng = np.random.default_rng(81)
    x = np.ascontiguousarray(np.vstack([_orbits(rng, count), rng.standard_normal((3, count)) * 1e-3]))
    x[6:, -1] = [0.0, -0.0, 0.0]  # no acceleration: every pushed term a signed zero
    if count >= 7:
        x[:, 4:6] = [[0.0, 1.8e6], [-0.0, np.inf], [1.0, 0.0], [0.0, 1.0], [-0.0, 0.0], [0.0, 0.0], [0.0, 1e-3],
                     [-0.0, 0.0], [2e-3, 0.0]]
    with np.errstate(invalid="ignore"):  # (inf - inf in the shifted states)
        fast = ModelErrorCompensation(LunarDescentModel(), 1e6, 0.1).transition_jacobian(x.T, 2.0)
        generic = ModelErrorCompensation(_WithoutFastPath(), 1e6, 0.1).transition_jacobian(x.T, 2.0)
    np.testing.assert_array_equal(fast, generic)
    np.testing.assert_array_equal(np.signbit(fast), np.signbit(generic))


def test_compensated_lunar_transition_is_the_numpy_one():
    rng = np.random.default_rng(50)
    model = ModelErrorCompensation(LunarDescentModel(), 1e6, 0.1)
    x = np.vstack([_orbits(rng, 300)[:, 4:], rng.standard_normal((3, 296)) * 0.1])
    G, decay = model._coupling(2.0)
    base = reference.leapfrog(x[:6].T, MU_MOON, 2.0, 1).T
    pushed = reference.push(base, reference.frames(x[:6].T).transpose(1, 2, 0), x[6:], np.arange(3, 6),
                            np.arange(3), G[3, 0], G[0, 0])
    _close(model.transition(np.ascontiguousarray(x).T, 2.0), np.vstack([pushed, x[6:] * decay]).T)


FILTERS = {
    # the nominal and one compensated member: the configuration the numpy reference was recorded with
    "gpf-pair": lambda model, n: MultipleModelGPF(model, n, seed=0, compensation_scales=(1.0,),
                                                  compensation_times=(1.0,), nesting_gate=0.0,
                                                  nominal_switch_time=0.0, nominal_acceleration_noise=0.0),
    "gpf-single": lambda model, n: GeometricProjectionPF(model, n, seed=0),
    "gpf-paper": lambda model, n: GeometricProjectionPF(model, n, seed=0, metric="euclidean",
                                                        weighting="likelihood", unmodelled_acceleration_std=0.0),
    "spf": lambda model, n: BootstrapPF(model, n, seed=0),
}
STEPS = 25


def _run(name: str, n: int) -> np.ndarray:
    """Mean and covariance diagonal ``(STEPS, 12)`` of ``STEPS`` steps of the lunar descent (seed 0)."""
    config = replace(ScenarioConfig(), duration=ScenarioConfig().dt * (STEPS + 1))
    scenario, model = generate(config, 0), filter_model(config)
    f = FILTERS[name](model, n)
    f.initialize(scenario.prior_mean, scenario.prior_cov)
    out = []
    for k in range(STEPS):
        f.predict(config.dt)
        f.update(scenario.measurements[k])
        out.append(np.concatenate([f.mean, np.diag(f.covariance)]))
    return np.array(out)


@pytest.mark.parametrize("name", FILTERS)
def test_seeded_run_gives_the_estimates_of_the_numpy_code(name):
    """The random streams are those of the numpy code, so the filters' estimates are equal to rounding
    (which the filters' nonlinear steps grow to about 1e-10 over 25 steps)."""
    expected = json.loads(REFERENCE.read_text())
    for n in (500, 3000):
        _close(_run(name, n), np.array(expected[f"{name}/{n}"]), rtol=1e-9)



def _spd(rng, n, spread=1e3):
    """A random ``(n, n)`` covariance with variances over ``spread**2`` (metres and m/s mixed)."""
    A = rng.standard_normal((n, n)) * rng.uniform(1.0, spread, (n, 1))
    return A @ A.T + np.diag(rng.uniform(0.1, 1.0, n))


@pytest.mark.parametrize("n, m", [(1, 1), (3, 1), (6, 3), (9, 3), (9, 2), (12, 5)])
def test_the_observability_arithmetic_is_the_numpy_one(n, m):
    """The tracker's propagation, measurement update (reanchoring test, Joseph form) and report
    (gpf_nav/kernels/information.py) against the numpy code they replaced, on random inputs."""
    rng = np.random.default_rng(60 + 10 * n + m)
    for trial in range(20):
        free = _spd(rng, n)
        # the data's covariance: the prior's after a few measurements of random combinations, noise 1 % to
        # 1e-4 of their prior standard deviation (information up to about 1e8)
        G = rng.standard_normal((max(1, n // 2), n))
        data = reference.joseph(G, np.diag(np.diag(G @ free @ G.T) * rng.uniform(1e-6, 1e-4, G.shape[0])), free)
        F = np.eye(n) + 0.3 * rng.standard_normal((n, n))
        Q, x = _spd(rng, n, 10.0), rng.standard_normal(n)
        got, expected = information.propagate(F, Q, x, free, data), reference.propagate(F, Q, x, free, data)
        assert got[0] == expected[0]
        for a, b in zip(got[1:], expected[1:]):
            np.testing.assert_array_equal(a, a.T)
            _close(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
        H = rng.standard_normal((m, n)) * rng.uniform(1e-3, 1.0, (m, 1))
        R = _spd(rng, m, 10.0) * 1e-4
        # residuals inside and beyond the reanchoring distance (100 standard deviations of the spread)
        r = rng.standard_normal(m) * np.sqrt(np.diag(H @ free @ H.T + R)) * (3.0 if trial % 2 else 40.0)
        expected_far = reference.far(H, R, r, free)
        outcome, updated = information.update(H, R, r, free, data, reference.REANCHOR_SIGMAS ** 2)
        assert outcome == (information.FAR if expected_far else information.UPDATED), (trial, expected_far)
        if outcome == information.FAR:
            outcome, updated = information.update(H, R, np.zeros(0), free, data, 0.0)
        assert outcome == information.UPDATED
        expected = reference.joseph(H, R, data)
        np.testing.assert_array_equal(updated, updated.T)
        _close(updated, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
        ok, s, info, vectors = information.report(free, updated)
        expected_s, expected_info, expected_vectors = reference.report(free, updated)
        assert ok
        _close(s, expected_s)
        # rounding grows with the condition of the scaled data covariance, (1 + max info) / (1 + min info);
        # the small information is sv^2 - 1, an absolute error of the largest singular value's rounding
        condition = (1.0 + expected_info.max()) / (1.0 + expected_info.min())
        _close(info, expected_info, rtol=max(1e-12, 1e-15 * condition), atol=1e-14 * np.sqrt(condition))
        # a direction is defined up to its sign (the same SVD on nearly the same matrix keeps it) where its
        # information is apart from the others'; rounding grows with the condition there too
        level = np.log1p(expected_info)
        apart = np.array([np.delete(np.abs(level - v), i).min(initial=np.inf) > 0.1 for i, v in enumerate(level)])
        assert apart.any()
        _close(vectors[apart], expected_vectors[apart], rtol=0.0,
               atol=1e-13 * condition * np.abs(expected_vectors).max())


def test_the_observability_arithmetic_fails_where_the_numpy_one_does():
    n, m = 4, 2
    free, data, H, R = np.eye(n), np.eye(n), np.ones((m, n)), np.eye(m)
    r = np.ones(m)
    for bad in (np.nan, np.inf):
        F = np.eye(n)
        F[1, 2] = bad
        assert not information.propagate(F, np.eye(n), np.zeros(n), free, data)[0]
        assert not reference.propagate(F, np.eye(n), np.zeros(n), free, data)[0]
        assert not information.propagate(np.eye(n), np.eye(n), np.full(n, bad), free, data)[0]
        assert information.update(H, R, np.full(m, bad), free, data, 100.0)[0] == information.NOT_FINITE
        assert reference.far(H, R, np.full(m, bad), free) is None
    # a singular spread is far; a singular innovation covariance refuses the update
    zero = np.zeros((m, m))
    assert reference.far(H, zero, r, np.zeros((n, n))) is True
    assert information.update(H, zero, r, np.zeros((n, n)), data, 100.0)[0] == information.FAR
    assert reference.joseph(H, zero, np.zeros((n, n))) is None
    assert information.update(H, zero, r, free, np.zeros((n, n)), 0.0)[0] == information.SINGULAR
    # a covariance that is not positive definite gives no report
    singular = np.ones((n, n))
    assert reference.report(singular, data) is None and reference.report(free, -data) is None
    assert not information.report(singular, data)[0] and not information.report(free, -data)[0]
    # the basis of the constrained directions: numpy's QR
    a = np.random.default_rng(70).standard_normal((9, 3))
    _close(information.orthonormal(a), np.linalg.qr(a)[0], atol=1e-15)


def test_positive_definite_is_the_numpy_one_bit_for_bit():
    """The Cholesky screen (gpf_nav/kernels/covariance.py) only decides whether the eigen-decomposition
    runs: covariances of every condition, near and across the eigenvalue floor, collapsed variances,
    asymmetric and non-finite input give the numpy code's result exactly."""
    rng = np.random.default_rng(80)
    cases = []
    for n in (1, 2, 6, 9):
        for smallest in (1.0, 1e-4, 1e-8, 3e-10 * n, 2e-10 * n, 1e-10 * n, 5e-11, 1e-12, 0.0, -1e-6):
            Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
            vals = np.concatenate([[smallest], rng.uniform(0.1, 2.0, n - 1)])[:n]
            corr = (Q * vals) @ Q.T
            scale = rng.uniform(1e-3, 1e4, n)
            cases.append(corr * np.outer(scale, scale))
        A = rng.standard_normal((n, n))
        cases += [A @ A.T, A, A @ A.T * 1e-30, np.zeros((n, n)), np.full((n, n), np.nan)]
        collapsed = A @ A.T
        collapsed[0, :] = collapsed[:, 0] = 0.0
        cases.append(collapsed)
        inf = A @ A.T
        inf[-1, 0] = np.inf
        cases.append(inf)
    screened = 0
    for cov in cases:
        got, expected = positive_definite(cov), reference.positive_definite(cov)
        np.testing.assert_array_equal(got, expected)
        screened += covariance.screen(np.ascontiguousarray(cov), reference.COVARIANCE_FLOOR_ABSOLUTE,
                                      2.0 * reference.COVARIANCE_FLOOR_RELATIVE)[0] == covariance.ABOVE
    assert 0 < screened < len(cases)
    # read-only and non-contiguous input (a cached Q, a transposed view)
    cov = cases[2].T.copy()
    cov.flags.writeable = False
    np.testing.assert_array_equal(positive_definite(cov), reference.positive_definite(cov))
    np.testing.assert_array_equal(positive_definite(cases[3].T), reference.positive_definite(cases[3].T))


def test_the_mixture_moments_are_the_numpy_ones_bit_for_bit():
    """The model averages' mixture (gpf_nav/kernels/mixture.py) sums in the components' order, as the numpy
    code did: the same numbers exactly, a weight-0 component with non-finite moments left out."""
    rng = np.random.default_rng(90)
    for count, d in ((1, 1), (2, 6), (4, 6), (4, 3), (5, 9)):
        weights = rng.dirichlet(np.ones(count))
        moments = []
        for _ in range(count):
            A = rng.standard_normal((d, d)) * rng.uniform(1e-3, 1e4)
            moments.append((rng.uniform(-1e6, 1e6, d), A @ A.T))
        if count > 2:
            weights[1] = 0.0
            moments[1] = (np.full(d, np.inf), np.full((d, d), np.nan))
        got, expected = mixture_moments(weights, moments), reference.mixture_moments(weights, moments)
        np.testing.assert_array_equal(got[0], expected[0])
        np.testing.assert_array_equal(got[1], expected[1])


@pytest.mark.parametrize("bit_generator", (np.random.PCG64, np.random.SFC64, np.random.Philox, np.random.MT19937))
@pytest.mark.parametrize("count", (0, 1, 7, 3000))
def test_the_compiled_normal_draw_is_numpys_number_for_number(bit_generator, count):
    """The numbers of ``Generator.standard_normal``, and the generator left in the state it leaves."""
    ours, numpys = (np.random.Generator(bit_generator(17)) for _ in range(2))
    row = np.full(count, np.nan)
    fill_standard_normal(ours, row)
    np.testing.assert_array_equal(row, numpys.standard_normal(count))
    assert ours.random() == numpys.random()
