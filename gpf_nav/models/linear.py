"""Linear-Gaussian model ``dx = (A x + B u) dt + G dB``, ``y = C x + v``, discretised exactly.

The transition matrix, input matrix and process-noise covariance over ``dt`` come from the matrix
exponential (Van Loan's method), so a Kalman filter run on this model is its exact posterior: the
reference every other filter is tested against.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from gpf_nav.models.state_space import StateSpaceModel


class LinearGaussianModel(StateSpaceModel):
    """Continuous-time linear-Gaussian model with exact discretisation.

    Args:
        A: drift matrix ``(n, n)``.
        G: diffusion matrix ``(n, r)``.
        C: measurement matrix ``(m, n)``.
        R: measurement-noise covariance ``(m, m)``.
        B: optional input matrix ``(n, p)`` for a known input ``u`` held constant over a step.
        angular: optional mask ``(m,)`` of angular measurement components.
    """

    def __init__(self, A, G, C, R, B=None, angular=None):
        self.A = np.atleast_2d(np.asarray(A, dtype=float))
        self.G = np.atleast_2d(np.asarray(G, dtype=float))
        self.C = np.atleast_2d(np.asarray(C, dtype=float))
        self.R = np.atleast_2d(np.asarray(R, dtype=float))
        n, m = self.A.shape[0], self.C.shape[0]
        if self.A.shape != (n, n) or self.G.shape[0] != n or self.C.shape[1] != n or self.R.shape != (m, m):
            raise ValueError("inconsistent shapes: A (n,n), G (n,r), C (m,n), R (m,m)")
        self.B = np.zeros((n, 0)) if B is None else np.atleast_2d(np.asarray(B, dtype=float))
        self.state_dim, self.measurement_dim = n, m
        self.angular = np.zeros(m, bool) if angular is None else np.asarray(angular, bool)
        self._cache: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def discretise(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``(F, Gamma, Q)`` over ``dt``: ``x' = F x + Gamma u + w``, ``w ~ N(0, Q)``."""
        key = float(dt)
        if key not in self._cache:
            n, p = self.state_dim, self.B.shape[1]
            # Van Loan: expm([[-A, G G^T], [0, A^T]] dt) gives Q; expm([[A, B], [0, 0]] dt) gives F, Gamma.
            vl = np.zeros((2 * n, 2 * n))
            vl[:n, :n], vl[:n, n:], vl[n:, n:] = -self.A, self.G @ self.G.T, self.A.T
            e = expm(vl * key)
            F = e[n:, n:].T
            Q = F @ e[:n, n:]
            aug = np.zeros((n + p, n + p))
            aug[:n, :n], aug[:n, n:] = self.A, self.B
            Gamma = expm(aug * key)[:n, n:]
            if len(self._cache) > 64:
                self._cache.clear()
            self._cache[key] = (F, Gamma, 0.5 * (Q + Q.T))
        return self._cache[key]

    def drift(self, x, t=0.0, u=None):
        out = x @ self.A.T
        if u is not None and self.B.shape[1]:
            out = out + np.asarray(u, dtype=float) @ self.B.T
        return out

    def transition(self, x, dt, t=0.0, u=None):
        F, Gamma, _ = self.discretise(dt)
        out = x @ F.T
        if u is not None and Gamma.shape[1]:
            out = out + np.asarray(u, dtype=float) @ Gamma.T
        return out

    def transition_jacobian(self, x, dt, t=0.0, u=None):
        F = self.discretise(dt)[0]
        return np.broadcast_to(F, (x.shape[0],) + F.shape)

    def process_noise(self, dt):
        return self.discretise(dt)[2]

    def measure(self, x):
        return x @ self.C.T

    def measurement_jacobian(self, x):
        return np.broadcast_to(self.C, (x.shape[0],) + self.C.shape)

    def measurement_noise(self):
        return self.R
