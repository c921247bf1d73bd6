"""Model derivatives against central finite differences, and the residual hook's angle wrapping."""
import numpy as np
import pytest

from gpf_nav.models import LinearGaussianModel, LunarDescentModel
from gpf_nav.models.state_space import wrap_angle


def _states(rng: np.random.Generator, n: int = 8) -> np.ndarray:
    """Lunar states ``(n, 6)`` in every octant, about 100 km above the surface, orbital speed."""
    direction = rng.standard_normal((n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    r = direction * 1.84e6
    v = np.cross(direction, rng.standard_normal((n, 3))) * 1.6e3
    return np.hstack([r, v])


def _central_difference(fun, x: np.ndarray, step: np.ndarray) -> np.ndarray:
    """``d fun / d x`` ``(N, k, n)`` of ``fun: (N, n) -> (N, k)`` by central differences."""
    columns = []
    for j in range(x.shape[1]):
        e = np.zeros_like(x)
        e[:, j] = step[j]
        columns.append((fun(x + e) - fun(x - e)) / (2.0 * step[j]))
    return np.stack(columns, axis=-1)


@pytest.mark.parametrize("station", [(0.0, 0.0, 0.0), (1.2e6, -3.0e5, 9.0e5)])
def test_lunar_measurement_jacobian_matches_finite_differences(station):
    model = LunarDescentModel(station=station)
    x = _states(np.random.default_rng(1))
    numeric = _central_difference(model.measure, x, np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3]))
    analytic = model.measurement_jacobian(x)
    assert analytic.shape == (8, 3, 6)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-12)
    h, H = model.measure_and_jacobian(x)
    np.testing.assert_array_equal(H, analytic)
    np.testing.assert_array_equal(h, model.measure(x))


def test_lunar_one_point_jacobian_is_the_batched_one():
    """The one-point path (Python floats, used at the GPF's cloud mean) gives the batched path's numbers
    exactly, also at the station, on its vertical and for a non-finite state."""
    model = LunarDescentModel(station=(1.2e6, -3.0e5, 9.0e5))
    x = np.vstack([_states(np.random.default_rng(3)),
                   [[1.2e6, -3.0e5, 9.0e5, 1.0, 2.0, 3.0],  # at the station
                    [1.2e6, -3.0e5, 2.0e6, 0.0, 0.0, 0.0],  # straight above it
                    [np.nan, 0.0, 0.0, 0.0, 0.0, 0.0],
                    [np.inf, 0.0, 0.0, 0.0, 0.0, 0.0]]])
    with np.errstate(invalid="ignore"):
        batched = model.measurement_jacobian(x)
    for state, expected in zip(x, batched):
        np.testing.assert_array_equal(model.measurement_jacobian(state[None]), expected[None])


@pytest.mark.parametrize("dt", [2.0, 35.0])
def test_lunar_transition_jacobian_matches_finite_differences(dt):
    """Second-order Taylor per sub-step: close to, not equal to, the leapfrog flow's derivative."""
    model = LunarDescentModel()
    x = _states(np.random.default_rng(2), 4)
    step = np.array([10.0, 10.0, 10.0, 1e-2, 1e-2, 1e-2])
    numeric = _central_difference(lambda s: model.transition(s, dt), x, step)
    analytic = model.transition_jacobian(x, dt)
    scale = np.abs(numeric).max(axis=(0, 1))  # per column
    assert np.abs(analytic - numeric).max(axis=(0, 1)).max() < 1e-4 * scale.max()
    np.testing.assert_allclose(np.diagonal(analytic, axis1=1, axis2=2), np.diagonal(numeric, axis1=1, axis2=2),
                               rtol=1e-5)


def test_linear_model_jacobians_are_its_matrices():
    A = np.array([[0.0, 1.0], [-0.5, -0.1]])
    C = np.array([[1.0, 0.0]])
    model = LinearGaussianModel(A, np.eye(2) * 0.1, C, np.eye(1) * 0.2)
    x = np.random.default_rng(3).standard_normal((5, 2))
    numeric = _central_difference(lambda s: model.transition(s, 0.7), x, np.full(2, 1e-4))
    np.testing.assert_allclose(model.transition_jacobian(x, 0.7), numeric, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(model.measurement_jacobian(x), np.broadcast_to(C, (5, 1, 2)))


def test_residual_wraps_only_the_angles_across_pi():
    model = LunarDescentModel()
    y = np.array([1.8e6, np.pi - 0.01, -np.pi / 2 + 0.005])
    y_pred = np.array([[1.8e6 + 50.0, -np.pi + 0.01, np.pi / 2 - 0.005],
                       [2 * np.pi + 1.8e6, np.pi - 0.02, -np.pi / 2 + 0.004]])
    r = model.residual(y, y_pred)
    np.testing.assert_allclose(r[:, 0], [-50.0, -2 * np.pi])  # a range is never wrapped
    np.testing.assert_allclose(r[0, 1:], [-0.02, -np.pi + 0.01], atol=1e-12)
    np.testing.assert_allclose(r[1, 1:], [0.01, 0.001], atol=1e-12)
    assert np.all(wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi])) == np.pi)
