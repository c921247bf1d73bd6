"""A textbook Kalman filter and a linear-Gaussian test problem: the exact posterior filters are checked against."""
from __future__ import annotations

import numpy as np

from gpf_nav.models import LinearGaussianModel


def constant_velocity_model(accel_std: float = 1.0, meas_std: float = 1.0) -> LinearGaussianModel:
    """1-D constant velocity: state [p, v], white acceleration, position measured."""
    return LinearGaussianModel(A=[[0.0, 1.0], [0.0, 0.0]], G=[[0.0], [accel_std]], C=[[1.0, 0.0]],
                               R=[[meas_std ** 2]])


def simulate(model: LinearGaussianModel, x0, steps: int, dt: float, seed: int) -> np.ndarray:
    """Measurements ``(steps, m)`` of a trajectory of ``model`` started at ``x0``."""
    rng = np.random.default_rng(seed)
    F, _, Q = model.discretise(dt)
    x = np.asarray(x0, dtype=float)
    ys = []
    for _ in range(steps):
        x = F @ x + rng.multivariate_normal(np.zeros(len(x)), Q)
        ys.append(model.C @ x + rng.multivariate_normal(np.zeros(model.C.shape[0]), model.R))
    return np.array(ys)


def kalman(model: LinearGaussianModel, mean, cov, ys, dt: float):
    """Exact posterior means and covariances after each measurement (NaN rows not measured)."""
    F, _, Q = model.discretise(dt)
    m, P = np.asarray(mean, float), np.asarray(cov, float)
    out = []
    for y in ys:
        m, P = F @ m, F @ P @ F.T + Q
        rows = np.isfinite(y)
        if rows.any():
            C, R = model.C[rows], model.R[np.ix_(rows, rows)]
            S = C @ P @ C.T + R
            K = np.linalg.solve(S, C @ P).T
            m = m + K @ (y[rows] - C @ m)
            P = P - K @ S @ K.T
        out.append((m.copy(), P.copy()))
    return out
