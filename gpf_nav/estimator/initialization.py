"""Initial state from the first measurements (no rclpy): a small batch least-squares orbit fit.

The estimator, when it has neither an ``initial_state`` parameter nor a ``set_pose`` message, buffers
its first ``init_window`` measurements and calls :func:`batch_initial_state`:

1. every measurement with range, azimuth and elevation is inverted to a position (:func:`inverse_rae`);
   a straight line through them gives a first position and velocity at the first stamp;
2. Gauss-Newton on the state at the first stamp, with the filter's own model (``transition``,
   ``transition_jacobian``, ``measure_and_jacobian``; measured rows only, angles wrapped) refines it;
3. the fit and its covariance ``(J^T R^-1 J)^-1`` are propagated to the *last* stamp of the window,
   inflated and given the window's process noise, so no measurement is used twice.

It needs at least two fully measured vectors for the first guess; it returns None when the fit does not
converge or the covariance is not positive definite (the estimator then waits for more data).
"""
from __future__ import annotations

import numpy as np


def inverse_rae(y: np.ndarray, station: np.ndarray) -> np.ndarray:
    """Position ``(3,)`` of range [m], azimuth, elevation [rad] seen from ``station`` ``(3,)``."""
    r, a, e = y
    return station + r * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def batch_initial_state(model, times: np.ndarray, ys: np.ndarray, *, inflation: float = 4.0,
                        max_iterations: int = 20) -> tuple[np.ndarray, np.ndarray] | None:
    """Fit the state at ``times[0]`` to ``ys`` ``(K, m)`` (NaN = not measured) and return
    ``(mean (n,), cov (n, n))`` at ``times[-1]``, or None when the data do not determine it.

    ``model`` must have ``position_index``/``velocity_index`` and a ``station`` (the lunar model).
    ``inflation`` multiplies the fitted covariance (the window is short and the model mismatched).
    """
    times = np.asarray(times, dtype=float)
    ys = np.asarray(ys, dtype=float)
    full = np.all(np.isfinite(ys), axis=1)
    if full.sum() < 2 or times[-1] <= times[0]:
        return None
    p_idx, v_idx = list(model.position_index), list(model.velocity_index)
    positions = np.array([inverse_rae(y, model.station) for y in ys[full]])
    tf = times[full] - times[0]
    design = np.column_stack([np.ones_like(tf), tf])
    coef, *_ = np.linalg.lstsq(design, positions, rcond=None)
    x0 = np.zeros(model.state_dim)
    x0[p_idx], x0[v_idx] = coef[0], coef[1]

    whiten = 1.0 / np.sqrt(np.diag(model.measurement_noise()))
    cov0 = None
    for _ in range(max_iterations):
        jac, res, _, _ = _stack(model, x0, times, ys, whiten)
        if jac.shape[0] < model.state_dim:
            return None
        step, *_ = np.linalg.lstsq(jac, res, rcond=None)
        if not np.all(np.isfinite(step)):
            return None
        x0 = x0 + step
        scale = np.abs(x0) + 1.0
        if np.max(np.abs(step) / scale) < 1e-10:
            break
    jac, res, x_last, phi = _stack(model, x0, times, ys, whiten)
    info = jac.T @ jac
    try:
        cov0 = np.linalg.inv(info)
        np.linalg.cholesky(cov0)
    except np.linalg.LinAlgError:
        return None
    cov = inflation * (phi @ cov0 @ phi.T) + model.process_noise(times[-1] - times[0])
    cov = 0.5 * (cov + cov.T)
    if not (np.all(np.isfinite(x_last)) and np.all(np.isfinite(cov))):
        return None
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return None
    return x_last, cov


def _stack(model, x0, times, ys, whiten):
    """Whitened residuals and Jacobians of all measured rows for the state ``x0`` at ``times[0]``.

    Returns ``(J (rows, n), r (rows,), x at times[-1], d x_last / d x0)``."""
    n = model.state_dim
    x = x0[None, :].copy()
    phi = np.eye(n)
    rows_j, rows_r = [], []
    for k in range(len(times)):
        if k > 0:
            dt = times[k] - times[k - 1]
            if dt > 0:
                phi = model.transition_jacobian(x, dt)[0] @ phi
                x = model.transition(x, dt)
        y = ys[k]
        measured = np.isfinite(y)
        if not measured.any():
            continue
        h, H = model.measure_and_jacobian(x)
        r = model.residual(y, h)[0]
        rows_r.append((r * whiten)[measured])
        rows_j.append(((H[0] @ phi) * whiten[:, None])[measured])
    if not rows_r:
        return np.zeros((0, n)), np.zeros(0), x[0], phi
    return np.vstack(rows_j), np.concatenate(rows_r), x[0], phi
