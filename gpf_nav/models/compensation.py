"""Dynamic model compensation: any model augmented with an estimated unmodelled acceleration.

The orbit-determination answer to structural model error. The user's model ``dx = f(x) dt + G dB`` is
augmented with ``p`` states ``a`` that act as an extra acceleration on its velocity components (or, for a
model without velocities, as an extra drift on every state) and follow a first-order Gauss-Markov process:

    dx = (f(x, t, u) + B a) dt + G dB,        da = -a / tau dt + sigma sqrt(2 / tau) dW.

``sigma`` is the stationary standard deviation of the unmodelled acceleration and ``tau`` its correlation
time. When the base model declares a local frame (:meth:`StateSpaceModel.compensation_frame`, e.g. an
orbit's radial / along-track / cross-track axes), ``a`` holds the coordinates of the acceleration in that
frame, taken at each particle's state: a force that keeps its direction in the frame (a gravity-field
error is radial, drag and thrust are along-track) is a constant to the compensation, not a rotating vector
it must keep re-learning. Nothing here knows what the error is (a gravity scale, a thrust, drag or a
mis-modelled field are all "an acceleration the nominal drift does not have"); the filter estimates
``a`` from the measurements.

Over a step, ``a`` (turned to the state's own axes by the frame at the step's start) enters the base
transition through the exact response of a double integrator (position ``tau (dt - tau (1 - e))``,
velocity ``tau (1 - e)`` per unit ``a``, ``e = exp(-dt / tau)``); the process noise is the base ``Q(dt)``
plus the exact Gauss-Markov covariance propagated through the same kinematic chain (Van Loan's matrix
exponential), cached per ``dt``. The noise of ``a`` is isotropic, so it is the same in any frame, and the
frame's turn over one step (a few milliradians) is left out of it. The transition's Jacobian includes the
frame's dependence on the state, by central differences of the frame (a model gives its frame, not the
frame's derivative).
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy.linalg import expm

from gpf_nav.kernels import orbit
from gpf_nav.models.state_space import StateSpaceModel

FRAME_STEP = 1e-6
"""Relative step of the central differences of a local frame
(:meth:`ModelErrorCompensation.transition_jacobian`)."""
MAX_GAP = 100.0
"""Longest interval, in correlation times, over which the compensation noise is integrated; a longer
one gets the noise of this one (the compensation state has long forgotten its value by then)."""


class ModelErrorCompensation(StateSpaceModel):
    """``base`` with ``p`` Gauss-Markov unmodelled-acceleration states appended: ``x_aug = [x, a]``.

    Args:
        base: the nominal model (any :class:`StateSpaceModel`).
        time_constant: correlation time ``tau`` of the unmodelled acceleration, s.
        acceleration_std: its stationary standard deviation ``sigma``, state units per s^2 (m/s^2).

    Attributes:
        compensation_index: indices of the ``a`` states in the augmented state (coordinates in the base
            model's local frame when it declares one: :meth:`world_acceleration` turns them back).
        acceleration_of: index ``(p,)`` of the base component each ``a`` drives (a velocity, or every
            state when the base declares no velocities).
    """

    def __init__(self, base: StateSpaceModel, time_constant: float = 600.0,
                 acceleration_std: float = 1e-2):
        if not (math.isfinite(time_constant) and time_constant > 0):
            raise ValueError(f"time_constant must be positive, got {time_constant}")
        if not (math.isfinite(acceleration_std) and acceleration_std >= 0):
            raise ValueError(f"acceleration_std must be non-negative, got {acceleration_std}")
        self.base = base
        self.time_constant = float(time_constant)
        self.acceleration_std = float(acceleration_std)
        n = base.state_dim
        driven = tuple(base.velocity_index) or tuple(range(n))
        self.acceleration_of = np.asarray(driven, dtype=int)
        # the position each driven velocity integrates into (none for a model without positions)
        pairs = len(base.position_index) == len(base.velocity_index) and len(base.velocity_index) > 0
        self._integrated_into = np.asarray(base.position_index, dtype=int) if pairs else None
        self._driven = _rows(self.acceleration_of)
        self._integrated = None if self._integrated_into is None else _rows(self._integrated_into)
        self._integrated_rows = (np.zeros(0, dtype=int) if self._integrated_into is None
                                 else self._integrated_into)  # (the kernel's form)
        p = len(driven)
        self.state_dim = n + p
        self.measurement_dim = base.measurement_dim
        self.angular = getattr(base, "angular", None)  # a missing mask is reported by the validation
        self.position_index = tuple(base.position_index)
        self.velocity_index = tuple(base.velocity_index)
        self.measured_state_index = (tuple(base.measured_state_index)
                                     if base.measured_state_index is not None else tuple(range(n)))
        self.orthogonal_jacobian_rows = base.orthogonal_jacobian_rows
        self.compensation_index = tuple(range(n, n + p))
        self._n, self._p = n, p
        self._decaying = n + np.arange(p)  # the acceleration's rows (its Jacobian's diagonal: the decay)
        # a local frame needs a acting on velocities (its axes are given in their coordinates)
        self._framed = bool(base.velocity_index) and type(base).compensation_frame is not \
            StateSpaceModel.compensation_frame
        self._A = self._linear_chain()
        self._coupling_key = (n, p, self.acceleration_of.tobytes(),
                              None if self._integrated_into is None else self._integrated_into.tobytes(),
                              self.time_constant)  # the arguments of the cached _coupling but dt
        self._noise_cache: tuple[tuple[float, float] | None, np.ndarray | None] = (None, None)
        self._time_varying_noise = base.time_varying_noise  # a property of the base model's class

    # --- the linear part driven by a ------------------------------------------------------------------
    def _linear_chain(self) -> np.ndarray:
        """``(n+p, n+p)`` matrix of the kinematic chain ``a -> velocity -> position`` and ``-a / tau``."""
        n, p = self._n, self._p
        A = np.zeros((n + p, n + p))
        A[self.acceleration_of, n + np.arange(p)] = 1.0
        if self._integrated_into is not None:
            A[self._integrated_into, self.acceleration_of] = 1.0
        A[n:, n:] = -np.eye(p) / self.time_constant
        return A

    def _coupling(self, dt: float) -> tuple[np.ndarray, float]:
        """``(G (n, p), decay)``: the change of ``x`` per unit ``a`` over ``dt``, and ``exp(-dt/tau)``."""
        return _coupling(*self._coupling_key, float(dt))

    def _split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return x[:, :self._n], x[:, self._n:]

    # --- StateSpaceModel -------------------------------------------------------------------------------
    def drift(self, x, t=0.0, u=None):
        xb, a = self._split(x)
        out = np.empty_like(x, dtype=float)
        out[:, :self._n] = self.base.drift(xb, t, u)
        frame = self._frame(xb.T)
        out[:, self.acceleration_of] += a if frame is None else np.einsum("ijn,nj->ni", frame, a)
        out[:, self._n:] = -a / self.time_constant
        return out

    def transition(self, x, dt, t=0.0, u=None):
        """Built particle-last ``(n + p, N)`` and returned as its ``(N, n + p)`` view, like the models: the
        filters store particles as ``(n + p, N)`` and pass the transpose, so every row here is contiguous
        and their copy back is free."""
        G, decay = self._coupling(dt)
        xt = x.T
        a = xt[self._n:]  # (p, N)
        out = np.empty((self.state_dim, x.shape[0]))
        moved = out[:self._n]
        # G has one velocity (and one position) entry per column: add them without a matrix product
        velocity_gain = G[self.acceleration_of[0], 0]
        position_gain = 0.0 if self._integrated_into is None else G[self._integrated_into[0], 0]
        fused = self._framed and self.base.pushed_transition(xt[:self._n], dt, t, u, a, velocity_gain,
                                                             position_gain, self.acceleration_of,
                                                             self._integrated_rows, moved)
        if not fused:
            moved[...] = self.base.transition(xt[:self._n].T, dt, t, u).T
            frame = self._frame(xt[:self._n])
            if frame is None:
                moved[self._driven] += a * velocity_gain
                if self._integrated_into is not None:
                    moved[self._integrated] += a * position_gain
            else:  # turned to the state's own axes by each particle's frame
                orbit.push(moved, np.ascontiguousarray(frame), np.ascontiguousarray(a), self.acceleration_of,
                           self._integrated_rows, velocity_gain, position_gain)
        np.multiply(a, decay, out=out[self._n:])
        return out.T

    def transition_chain(self, x, dt, t, u):
        """In one call where the base model has the fused path (:meth:`StateSpaceModel.pushed_transition_chain`),
        else :meth:`transition` in turn."""
        if self._framed:
            distinct, index = np.unique(dt, return_inverse=True)
            couplings = [self._coupling(step) for step in distinct.tolist()]
            gains = np.array([(G[self.acceleration_of[0], 0],
                               0.0 if self._integrated_into is None else G[self._integrated_into[0], 0], decay)
                              for G, decay in couplings]).reshape(-1, 3)[index.ravel()].T  # (3, K)
            chain = self.base.pushed_transition_chain(x[:self._n], x[self._n:], dt, t, u, gains[0], gains[1],
                                                      gains[2], self.acceleration_of, self._integrated_rows)
            if chain is not None:
                return chain
        return super().transition_chain(x, dt, t, u)

    def transition_jacobian(self, x, dt, t=0.0, u=None):
        return self._jacobian(x, self.base.transition_jacobian(x[:, :self._n], dt, t, u), ((dt, slice(None)),))

    def transition_jacobian_along(self, x, dt, t, u):
        """The base model's Jacobians along the trajectory (:meth:`StateSpaceModel.transition_jacobian_along`),
        the frames and their derivatives in one call each, the coupling once per distinct step ``dt``."""
        base = self.base.transition_jacobian_along(x[:, :self._n], dt, t, u)
        return self._jacobian(x, base, tuple((step, np.flatnonzero(dt == step)) for step in np.unique(dt).tolist()))

    def _jacobian(self, x: np.ndarray, base: np.ndarray, steps: tuple) -> np.ndarray:
        """Jacobians ``(N, n + p, n + p)`` at ``x`` ``(N, n + p)`` from the base model's ``(N, n, n)``, with the
        coupling of the step ``dt`` for the particles ``index`` of each ``(dt, index)`` of ``steps``."""
        xb, a = self._split(x)
        J = np.zeros((x.shape[0], self.state_dim, self.state_dim))
        J[:, :self._n, :self._n] = base
        frame = self._frame(xb.T)
        derivative = None if frame is None else self._push_derivative(xb, a)
        for dt, index in steps:
            G, decay = self._coupling(dt)
            if frame is None:
                J[index, :self._n, self._n:] = G
            else:  # (G has one non-zero per row: each sum is a single product, in any order, so the
                # stacked products are einsum's numbers at a fraction of its call's cost)
                J[index, :self._n, self._n:] = G @ frame[..., index].transpose(2, 0, 1)
                J[index, :self._n, :self._n] += G @ derivative[index]
            J[index if isinstance(index, slice) else index[:, None], self._decaying, self._decaying] = decay
        return J

    def _frame(self, x: np.ndarray) -> np.ndarray | None:
        """The base model's local frames ``(p, p, N)`` (particle last) at the base states ``x`` ``(n, N)``,
        or None without a local frame."""
        if not self._framed:
            return None
        frame = self.base.compensation_frame(x.T)
        return None if frame is None else frame.transpose(1, 2, 0)  # the particle-last array the model built

    def _push_derivative(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        """``d(F(x) a) / dx`` ``(N, p, n)`` of the pushed acceleration at base states ``x`` ``(N, n)`` with
        ``a`` ``(N, p)`` held, by central differences of the frame ``F`` (one call on ``2 n N`` states)."""
        derivative = self.base.compensation_push_derivative(x, a, FRAME_STEP)
        if derivative is not None:
            return derivative
        count, n = x.shape
        steps = FRAME_STEP * np.maximum(np.abs(x), 1.0)  # (N, n)
        shifts = np.einsum("nj,jk->jnk", steps, np.eye(n))  # (n, N, n): component j of particle i moved
        states = np.concatenate((x + shifts, x - shifts)).reshape(2 * n * count, n)
        frames = self.base.compensation_frame(states).reshape(2, n, count, self._p, self._p)
        pushed = np.einsum("sjnik,nk->sjni", frames, a)  # (2, n, N, p)
        return ((pushed[0] - pushed[1]) / (2.0 * steps.T[..., None])).transpose(1, 2, 0)

    def world_acceleration(self, x: np.ndarray, a: np.ndarray, cov: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
        """An estimated acceleration ``a`` ``(p,)`` with covariance ``cov`` ``(p, p)`` on the state's own
        axes (the world's, for the lunar model): turned by the local frame at the base state ``x``
        ``(n,)``, as it is without one."""
        frame = self._frame(np.asarray(x, dtype=float)[:, None])
        if frame is None:
            return a, cov
        F = frame[..., 0]
        return F @ a, F @ cov @ F.T

    @property
    def time_varying_noise(self) -> bool:
        return self.base.time_varying_noise

    @property
    def base_state_dim(self) -> int:
        """The user's model's states (this model's own are appended after them)."""
        return self.base.base_state_dim

    def process_noise(self, dt, t=0.0):
        """Base ``Q`` over ``[t, t + dt]`` plus the Gauss-Markov part; cached for the last ``dt`` (and the
        last ``t`` when the base model's noise varies with time, see ``time_varying_noise``)."""
        dt = float(dt)
        key = (dt, float(t) if self._time_varying_noise else 0.0)
        if self._noise_cache[0] != key:
            Q = np.zeros((self.state_dim, self.state_dim))
            Q[:self._n, :self._n] = self.base.process_noise(dt, t)
            Q += self._compensation_noise(dt)
            Q.flags.writeable = False
            self._noise_cache = (key, Q)
        return self._noise_cache[1]

    def _compensation_noise(self, dt: float) -> np.ndarray:
        """Covariance ``(n+p, n+p)`` the Gauss-Markov noise accumulates over ``dt`` (Van Loan)."""
        if self.acceleration_std == 0.0 or dt == 0.0:
            return np.zeros((self.state_dim, self.state_dim))
        # beyond MAX_GAP correlation times the result is of no use and the doubling loses precision
        dt = min(abs(dt), MAX_GAP * self.time_constant)
        return _van_loan(self._A.tobytes(), self.state_dim, self._n,
                         2.0 * self.acceleration_std ** 2 / self.time_constant, dt)

    def measure(self, x, t=0.0):
        return self.base.measure(x[:, :self._n], t)

    def measurement_jacobian(self, x, t=0.0):
        return self._pad(self.base.measurement_jacobian(x[:, :self._n], t))

    def measure_and_jacobian(self, x, t=0.0):
        h, H = self.base.measure_and_jacobian(x[:, :self._n], t)
        return h, self._pad(H)

    def measurement_jacobian_along(self, x, t):
        return self._pad(self.base.measurement_jacobian_along(x[:, :self._n], t))

    def _pad(self, H: np.ndarray) -> np.ndarray:
        """Base Jacobian ``(N, m, n)`` with zero columns for ``a``: ``(N, m, n+p)``."""
        out = np.zeros((H.shape[1], self.state_dim, H.shape[0]))  # built particle-last, like the models
        out[:, :self._n] = H.transpose(1, 2, 0)
        return out.transpose(2, 0, 1)

    def measurement_noise(self):
        return self.base.measurement_noise()

    def residual(self, y, y_pred):
        return self.base.residual(y, y_pred)

    def measurement_residual(self, y, x, t=0.0, reverse=False):
        return self.base.measurement_residual(y, x[:, :self._n], t, reverse)

    def measurement_mean(self, y, weights):
        return self.base.measurement_mean(y, weights)

    # --- helpers for callers -----------------------------------------------------------------------------
    def augment_prior(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A base prior ``N(mean (n,), cov (n, n))`` extended with ``a ~ N(0, sigma^2 I)``."""
        mean = np.concatenate([np.asarray(mean, dtype=float).reshape(-1), np.zeros(self._p)])
        out = np.zeros((self.state_dim, self.state_dim))
        out[:self._n, :self._n] = cov
        out[self._n:, self._n:] = self.acceleration_std ** 2 * np.eye(self._p)
        return mean, out


def _rows(index: np.ndarray) -> slice | np.ndarray:
    """``index`` as a slice when its entries are consecutive (a view, no gather), else itself."""
    if index.size and (np.diff(index) == 1).all():
        return slice(int(index[0]), int(index[-1]) + 1)
    return index


@lru_cache(maxsize=32)
def _coupling(n: int, p: int, driven: bytes, integrated: bytes | None, tau: float,
              dt: float) -> tuple[np.ndarray, float]:
    x = dt / tau
    velocity_gain = -tau * math.expm1(-x)  # integral of exp(-s/tau) over dt
    position_gain = tau * tau * _integrated_decay(x)  # its integral, tau (dt - velocity_gain)
    G = np.zeros((n, p))
    G[np.frombuffer(driven, dtype=int), np.arange(p)] = velocity_gain
    if integrated is not None:
        G[np.frombuffer(integrated, dtype=int), np.arange(p)] = position_gain
    G.flags.writeable = False
    return G, math.exp(-x)


def _integrated_decay(x: float) -> float:
    """``x - (1 - e^-x)`` without the cancellation of the direct form when ``x = dt / tau`` is small
    (a long correlation time): its series below 1e-3, where it is exact to rounding."""
    if x >= 1e-3:
        return x + math.expm1(-x)
    return x * x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x * (1.0 / 120.0 - x / 720.0))))


@lru_cache(maxsize=32)
def _van_loan(A_bytes: bytes, dim: int, n: int, spectral_density: float, dt: float) -> np.ndarray:
    """``int_0^dt e^{A s} Qc e^{A^T s} ds`` with ``Qc`` the density on the last ``dim - n`` states.

    Van Loan's block exponential over a step no longer than ``tau`` (its ``e^{-A^T dt}`` block grows like
    ``e^{dt / tau}``), then doubled: ``Q(2h) = Phi(h) Q(h) Phi(h)^T + Q(h)``, ``Phi(2h) = Phi(h)^2``.
    """
    A = np.frombuffer(A_bytes).reshape(dim, dim)
    tau = -1.0 / A[-1, -1]
    doublings = max(0, math.ceil(math.log2(dt / tau))) if dt > tau else 0
    h = dt / 2.0 ** doublings
    Qc = np.zeros((dim, dim))
    Qc[n:, n:] = spectral_density * np.eye(dim - n)
    M = np.zeros((2 * dim, 2 * dim))
    M[:dim, :dim] = -A
    M[:dim, dim:] = Qc
    M[dim:, dim:] = A.T
    E = expm(M * h)
    phi = E[dim:, dim:].T
    Q = phi @ E[:dim, dim:]
    for _ in range(doublings):
        Q = phi @ Q @ phi.T + Q
        phi = phi @ phi
    Q = 0.5 * (Q + Q.T)
    Q.flags.writeable = False
    return Q
