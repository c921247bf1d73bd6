"""Check a user's :class:`StateSpaceModel` once, before a filter runs on it.

Ordinary mistakes in a model (an index tuple where a boolean mask is expected, an unbatched Jacobian,
a ``(N,)`` measurement, a scalar ``R``) otherwise give silently wrong estimates or cryptic numpy errors
deep inside a filter. :func:`validate_model` calls every method on a small batch of states around the
prior mean and raises a ``ValueError`` that names the method, the shape it returned and the one
expected.
"""
from __future__ import annotations

import numpy as np

from gpf_nav.models.state_space import StateSpaceModel

_DT = 1.0
"""Interval the transition methods are called with (one step of a discrete-time model)."""


def validate_model(model: StateSpaceModel, mean: np.ndarray, cov: np.ndarray, t0: float = 0.0) -> None:
    """Raise ``ValueError`` if ``model`` does not return what the filters expect.

    Args:
        model: the model to check.
        mean: prior mean ``(n,)``; the methods are called on a batch of states around it.
        cov: prior covariance ``(n, n)``; sets the spread of that batch.
        t0: the filter's start time, passed as ``t``.
    """
    name = type(model).__name__
    n, m = _dimension(model, "state_dim"), _dimension(model, "measurement_dim")
    _check_angular(model, m)
    # A batch size different from n and m, so that an unbatched (n, n) or transposed answer is caught;
    # deterministic points (the filter's own random stream is not touched).
    batch = max(n, m) + 2
    spread = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    offsets = np.random.default_rng(0).standard_normal((batch, n)) * (0.1 * spread)
    x = mean + offsets
    x[0] = mean

    def check(method: str, value, expected: tuple[int, ...]) -> np.ndarray:
        shape = np.shape(value)
        if shape != expected:
            raise ValueError(f"{name}.{method} returned shape {shape}, expected {expected} "
                             f"(batched over N = {batch} states of dimension n = {n}, m = {m})")
        return np.asarray(value, dtype=float)

    check("drift(x (N, n), t)", model.drift(x, t0), (batch, n))
    check("transition(x (N, n), dt, t)", model.transition(x, _DT, t0), (batch, n))
    check("transition_jacobian(x (N, n), dt, t)", model.transition_jacobian(x, _DT, t0), (batch, n, n))
    q = check("process_noise(dt, t)", model.process_noise(_DT, t0), (n, n))
    if not np.all(np.isfinite(q)):
        raise ValueError(f"{name}.process_noise(dt={_DT}) is not finite")
    check("measure(x (N, n), t)", model.measure(x, t0), (batch, m))
    check("measurement_jacobian(x (N, n), t)", model.measurement_jacobian(x, t0), (batch, m, n))
    h, H = model.measure_and_jacobian(x, t0)
    check("measure_and_jacobian(x (N, n), t)[0]", h, (batch, m))
    check("measure_and_jacobian(x (N, n), t)[1]", H, (batch, m, n))
    r = check("measurement_noise()", model.measurement_noise(), (m, m))
    if not (np.all(np.isfinite(r)) and np.allclose(r, r.T) and np.linalg.eigvalsh(r).min() > 0.0):
        raise ValueError(f"{name}.measurement_noise() must be symmetric positive definite, got {r.tolist()}")


def _dimension(model: StateSpaceModel, attribute: str) -> int:
    value = getattr(model, attribute, None)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{type(model).__name__}.{attribute} must be a positive int, got {value!r}")
    return int(value)


def _check_angular(model: StateSpaceModel, m: int) -> None:
    name = type(model).__name__
    if not hasattr(model, "angular"):
        raise ValueError(f"{name} has no attribute 'angular': set a boolean mask of shape ({m},) saying "
                         f"which measurement components are angles (np.zeros({m}, bool) if none)")
    angular = np.asarray(model.angular)
    if angular.dtype != bool or angular.shape != (m,):
        raise ValueError(f"{name}.angular must be a boolean mask of shape ({m},), one flag per measurement "
                         f"component, got {model.angular!r} (dtype {angular.dtype}, shape {angular.shape}); "
                         f"indices such as (0,) are not a mask: write e.g. np.array([True] + [False] * {m - 1})")
