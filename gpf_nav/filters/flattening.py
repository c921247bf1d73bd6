"""Flattened coordinates of a GPF update: where the measurement, now and along the flow, is linear.

The cloud-metric update of :class:`~gpf_nav.filters.gpf.GeometricProjectionPF` draws its kernel along
straight lines, gives every particle one gain and weights it exactly: all three are right for a linear
measurement. A measurement curved in the state's coordinates (a range about a centre) breaks them along
the directions it cannot see: a particle far along a rotation about the centre, moved by a straight
kernel draw, lands off the shell of its range, is weighted down, and the cloud narrows where the data
never looked. The update therefore runs in the coordinates

    xi = x + K nu(x),      nu(x) = g(x) - g(m) - J (x - m),

where ``g`` stacks the measured rows now and the same rows of the state flowed ``lags`` seconds ahead,
``J`` is its Jacobian at the cloud's mean ``m`` and ``K`` a right inverse of ``J`` that moves the user's
own model's states only (never the states a filter appends, an estimated unmodelled acceleration or a
sensor bias: in the state's units, the rows ahead would put most of the move into the acceleration, and
a range's curvature would be shared with its bias). In ``xi`` every
row of ``g`` is exactly its linearisation at ``m``, so a straight draw along the directions ``J`` does not
see keeps the measurement now *and* the measurements the dynamics will turn it into (along a rotation of
an orbit, the speed and the radial velocity: without them the kernel leaves the set of orbits with the
same ranges, and the next measurements weigh the particles down).

``K`` is built in two stages so that the rows measured now stay exact when the stack is not of full rank
(a symmetry of the problem, such as the rotation about the polar axis without azimuth, is in the null
space of every row): ``K_0 = J_0^+`` on the user's state, then the rows ahead within its null space by a
noise-whitened pseudo-inverse truncated at :data:`RANK_TOLERANCE`, and without the directions along which
it would move a particle of the cloud by more than :data:`MOVE_LIMIT` of the cloud's standard deviations. The
map back solves ``x + K nu(x) = xi`` by :data:`ITERATIONS` fixed-point steps.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gpf_nav.kernels.curvature import departure, largest_scaled
from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.sensors.sensor import Sensor

ITERATIONS = 3
"""Most fixed-point steps of the map back (:meth:`Flattening.unflatten`)."""
FLAT_ENOUGH = 1e-2
"""Curvature, in measurement noise standard deviations, below which the cloud is left in the state's
coordinates (:func:`flattening`): at every particle the measured rows, now and ahead, are then their
linearisation at the mean to 1 % of the noise, and the likelihood of a particle three deviations out is
off by 3 %, below the Monte Carlo error of the weights at a few hundred particles. The update's own
linearisation is corrected by its exact weights; what flattening adds, the kernel's straight draws kept
on the measurement's shells, matters for clouds kilometres wide (a large prior, range only), whose
curvature is tenths of the noise and more. A cloud tracking the lunar descent in steady state curves by
3e-3 to 3e-2 of the noise: most updates skip the flattening and its map back."""
NEGLIGIBLE = 1e-3
"""Changes of the curvature, in measurement noise standard deviations, below which the map back has
converged (:meth:`Flattening.unflatten`)."""
RANK_TOLERANCE = 1e-8
"""Singular values of the noise-whitened rows ahead below this fraction of the largest are dropped."""
MOVE_LIMIT = 100.0
"""Largest move, in the cloud's standard deviations along it, that a direction of the rows ahead may give a
particle. A direction they barely see (a singular value just above :data:`RANK_TOLERANCE`) turns a
curvature of a fraction of the noise into a move far beyond the cloud, and the map back then runs away
instead of converging. Such directions are dropped like those below the tolerance."""
_NONE = np.zeros((0, 0))
"""No previous curvature (:func:`~gpf_nav.kernels.curvature.largest_scaled`)."""


@dataclass(frozen=True)
class Flattening:
    """The flattened coordinates of one update (built by :func:`flattening`).

    Attributes:
        mean: ``(n,)`` the cloud's weighted mean ``m``, the linearisation point.
        measured: ``(m,)`` the measurement at ``m`` (every component).
        jacobian: ``(m, n)`` its Jacobian at ``m``.
        rows: ``(m,)`` bool, the measured components.
        gain: ``(n, k + k L)`` the right inverse ``K`` of the stacked measured rows (``L`` lags).
        noise_std: ``(k + k L,)`` their noise standard deviations.
        steps: ``(L,)`` the flow's steps to the lags, s (the lags' differences).
        ahead: per lag, the measurement ``(m,)`` and Jacobian ``(m, n)`` at ``m`` flowed to it.
        time: the update's time, s.
        sensor, model, input: what the rows are measured and flowed with.
    """

    mean: np.ndarray
    measured: np.ndarray
    jacobian: np.ndarray
    rows: np.ndarray
    gain: np.ndarray
    noise_std: np.ndarray
    steps: tuple[float, ...]
    ahead: tuple[tuple[np.ndarray, np.ndarray], ...]
    time: float
    sensor: Sensor
    model: StateSpaceModel
    input: np.ndarray | None

    def curvature(self, x: np.ndarray) -> np.ndarray:
        """``nu(x)`` ``(N, k + k L)`` of the particles ``x`` ``(n, N)``: what each stacked measured row departs
        from its linearisation at the mean (angles wrapped)."""
        sensor, states, t = self.sensor, x.T, self.time
        x = np.ascontiguousarray(x)
        m, lags = self.measured.size, len(self.steps)
        nu = np.empty((x.shape[1], m * (1 + lags)))  # the times side by side, each written in place
        departure(sensor.measurement_residual(self.measured, states, t, reverse=True), x, self.mean,
                  np.ascontiguousarray(self.jacobian), nu, 0)
        for lag, (step, (measured, jacobian)) in enumerate(zip(self.steps, self.ahead), 1):
            states = self.model.transition(states, step, t, self.input)
            t += step
            departure(sensor.measurement_residual(measured, states, t, reverse=True), x, self.mean,
                      np.ascontiguousarray(jacobian), nu, lag * m)
        return nu if self.rows.all() else nu[:, np.tile(self.rows, 1 + lags)]

    def residual(self, y: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``y - h(x)`` ``(m, N)`` of the particles ``x`` ``(n, N)`` for the measurement linearised at the mean,
        the exact residual in the flattened coordinates (angles wrapped)."""
        return self.sensor.residual(y, self.measured)[:, None] - self.jacobian @ (x - self.mean[:, None])

    def unflatten(self, xi: np.ndarray) -> np.ndarray:
        """The particles ``x`` ``(n, N)`` whose flattened coordinates are ``xi`` ``(n, N)``: fixed-point steps
        ``x <- xi - K nu(x)`` until the curvature changes by less than :data:`NEGLIGIBLE` (at most
        :data:`ITERATIONS`)."""
        nu = self.curvature(xi)
        x = xi - self.gain @ nu.T
        for _ in range(ITERATIONS - 1):
            previous, nu = nu, self.curvature(x)
            x = xi - self.gain @ nu.T
            if not largest_scaled(nu, previous, self.noise_std) >= NEGLIGIBLE:
                break
        return x


def flattening(x: np.ndarray, weights: np.ndarray, rows: np.ndarray, sensor: Sensor, model: StateSpaceModel,
               time: float, u: np.ndarray | None, lags: tuple[float, ...], user_dim: int
               ) -> tuple[Flattening, np.ndarray] | None:
    """The flattened coordinates of the cloud ``x`` ``(n, N)`` with normalised ``weights`` ``(N,)`` for the
    measured ``rows`` ``(m,)`` of ``sensor`` at ``time``, flowed by ``model`` with the input ``u`` held to
    the increasing ``lags`` (s; none: the rows measured now only), moving the first ``user_dim``
    components of the state only, and the cloud in them, ``xi`` ``(n, N)``. None when every particle's
    curvature is below :data:`FLAT_ENOUGH` (the coordinates are then the state's own, to that accuracy),
    the rows measured now are not of full rank at the mean, or anything is non-finite. The curvature is
    tested before the gain is built: a cloud left as it is pays for one evaluation of it."""
    mean = np.einsum("in,n->i", x, weights)
    h, H = sensor.measure_and_jacobian(mean[None], time)
    h, H = h[0], H[0]
    n = x.shape[0]
    k = int(rows.sum())
    noise_std = np.concatenate([np.sqrt(np.diag(sensor.noise(time))[rows])] * (1 + len(lags)))
    steps = tuple(float(later) - float(earlier) for earlier, later in zip((0.0, *lags), lags))
    ahead = []
    flowed, t, F = mean[None], time, np.eye(n)
    for step in steps:
        F = model.transition_jacobian(flowed, step, t, u)[0] @ F
        flowed = model.transition(flowed, step, t, u)
        t += step
        measured, jacobian = sensor.measure_and_jacobian(flowed, t)
        ahead.append((measured[0], jacobian[0] @ F))
    arrays = (h, H, *(a for pair in ahead for a in pair))
    if not np.isfinite(np.concatenate([a.ravel() for a in arrays])).all():
        return None
    gain = np.zeros((n, k * (1 + len(lags))))  # (written below, once the cloud is known to need it)
    flat = Flattening(mean, h, H, rows, gain, noise_std, steps, tuple(ahead), float(time), sensor, model, u)
    nu = flat.curvature(x)
    if not largest_scaled(nu, _NONE, noise_std) >= FLAT_ENOUGH:  # (NaN: nothing to flatten with)
        return None
    now = H[rows][:, :user_dim]  # (k, n_user)
    try:
        first = np.linalg.solve(now @ now.T, now).T  # (n_user, k): J_0^+ on the user's state
    except np.linalg.LinAlgError:
        return None
    gain[:user_dim, :k] = first
    if lags:
        later = np.vstack([jacobian[rows] for _, jacobian in ahead])[:, :user_dim]  # (k L, n_user)
        # the rows ahead within the null space of the rows now: K = [J_0^+ - A^+ J_L J_0^+, A^+]
        A = (later - (later @ first) @ now) / noise_std[k:, None]
        U, s, Vt = np.linalg.svd(A, full_matrices=False)
        keep = s > RANK_TOLERANCE * s[0] if s.size and s[0] > 0.0 else np.zeros(s.size, bool)
        ahead_gain = _AheadGain(first, later @ first, U, s, Vt, noise_std[k:])
        ahead_gain.write(gain, keep)
    if not np.isfinite(gain).all():
        return None
    moves = gain @ nu.T  # (n, N)
    if lags and keep.any():
        runaway = _runaway(Vt[keep], moves[:user_dim], x[:user_dim], mean[:user_dim], weights)
        if runaway.any():
            keep[np.flatnonzero(keep)[runaway]] = False
            ahead_gain.write(gain, keep)  # (the gain ``flat`` holds, rewritten in place)
            moves = gain @ nu.T
    return flat, x + moves


@dataclass(frozen=True)
class _AheadGain:
    """The pieces of ``K``'s rows-ahead part: ``J_0^+`` ``(n_user, k)``, ``J_L J_0^+`` ``(k L, k)``, the SVD
    ``U s Vt`` of the noise-whitened rows ahead within the null space of the rows now, and their noise
    standard deviations ``(k L,)``."""

    first: np.ndarray
    later_first: np.ndarray
    U: np.ndarray
    s: np.ndarray
    Vt: np.ndarray
    noise_std: np.ndarray

    def write(self, gain: np.ndarray, keep: np.ndarray) -> None:
        """Write ``K`` ``(n, k + k L)`` into ``gain`` from the singular directions ``keep`` ``(r,)``."""
        user_dim, k = self.first.shape
        inverse = (self.Vt[keep].T / self.s[keep]) @ self.U[:, keep].T / self.noise_std  # (n_user, k L)
        gain[:user_dim, :k] = self.first
        gain[:user_dim, :k] -= inverse @ self.later_first
        gain[:user_dim, k:] = inverse


def _runaway(directions: np.ndarray, moves: np.ndarray, x: np.ndarray, mean: np.ndarray,
             weights: np.ndarray) -> np.ndarray:
    """``(r,)`` bool: the unit ``directions`` ``(r, n_user)`` along which some particle's move ``moves``
    ``(n_user, N)`` exceeds :data:`MOVE_LIMIT` standard deviations of the cloud ``x`` ``(n_user, N)`` (weighted
    ``mean`` ``(n_user,)`` and ``weights`` ``(N,)``); non-finite counts as exceeding."""
    spread = np.sqrt(np.square(directions @ (x - mean[:, None])) @ weights)
    reach = np.abs(directions @ moves).max(axis=1)
    return ~(reach <= MOVE_LIMIT * spread)
