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
row of ``g`` is its linearisation at ``m`` (the rows now exactly; the rows ahead exactly, or from
:data:`SECOND_ORDER` particles to second order about the mean, which is checked to :data:`FLAT_ENOUGH` of
the noise at the cloud's outermost particles: :func:`_rows_ahead`), so a straight draw along the directions
``J`` does not see keeps the measurement now *and* the measurements the dynamics will turn it into (along a rotation of
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

import math
from dataclasses import dataclass

import numpy as np

from gpf_nav.kernels.curvature import departure, largest_scaled, quadratic_departure, scaled_by_particle
from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.sensors.sensor import Sensor

ITERATIONS = 3
"""Most fixed-point steps of the map back (:meth:`Flattening.unflatten`)."""
FLAT_ENOUGH = 1e-2
"""Curvature, in measurement noise standard deviations, below which the cloud is left in the state's
coordinates (:func:`flattening`): at every particle but the outermost (:data:`OUTERMOST`) the measured rows,
now and ahead, are then their linearisation at the mean to 1 % of the noise, and the likelihood of a
particle three deviations out is off by 3 %, below the Monte Carlo error of the weights at a few hundred
particles. The update's own linearisation is corrected by its exact weights; what flattening adds, the
kernel's straight draws kept on the measurement's shells, matters for clouds kilometres wide (a large
prior, range only), whose curvature is tenths of the noise and more. A cloud tracking the lunar descent in
steady state curves by 3e-3 to 3e-2 of the noise: most updates skip the flattening and its map back."""
OUTERMOST = 500
"""The cloud's outermost particles, whose curvature :func:`flattening` tests against :data:`FLAT_ENOUGH`, are its
``N // OUTERMOST`` farthest out by it (below ``2 OUTERMOST`` particles the farthest one). The farthest particle of a
cloud moves out as ``N`` grows (about 3 standard deviations of a Gaussian cloud at 500 particles, 4.4 at 100 000: twice
the curvature), so testing it would flatten a larger cloud of the same posterior more often, for particles of
negligible weight; a fixed fraction makes the decision the posterior's, the one a cloud of :data:`OUTERMOST`
particles takes by its farthest."""
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
SECOND_ORDER = 4_096
"""Particles from which the flattening takes the rows ahead to second order about the cloud's mean instead of
flowing every particle (:func:`_rows_ahead`): the second derivatives cost a flow of a few dozen states and
their Jacobians, which a cloud of a few thousand particles' flows cost too (at 4 000 particles the default's
step took 0.99 times as long either way, at 10 000 0.8 to 0.95 times, at 100 000 0.73 times, in paired runs of
the descent's first minutes). Below it, nothing changes."""
_NONE = np.zeros((0, 0))
"""No previous curvature (:func:`~gpf_nav.kernels.curvature.largest_scaled`)."""


@dataclass(frozen=True)
class RowsAhead:
    """The measured rows of the state flowed to each lag, about the cloud's mean (built by :func:`_rows_ahead`).

    Attributes:
        rows: ``(m,)`` bool, the measured components.
        ahead: per lag, the measurement ``(m,)`` and Jacobian ``(m, n)`` at the mean flowed to it.
        hessians: ``(k L, n, n)`` the second derivatives of the ``k`` measured rows at every lag, lag by lag;
            None when the particles are flowed instead (:func:`_rows_ahead`).
        steps: ``(L,)`` the flow's steps to the lags, s (the lags' differences).
        time: the update's time, s.
        sensor, model, input: what the rows are measured and flowed with.
    """

    rows: np.ndarray
    ahead: tuple[tuple[np.ndarray, np.ndarray], ...]
    hessians: np.ndarray | None
    steps: tuple[float, ...]
    time: float
    sensor: Sensor
    model: StateSpaceModel
    input: np.ndarray | None

    def departures(self, x: np.ndarray, mean: np.ndarray, out: np.ndarray, column: int) -> None:
        """Write into the columns ``column`` to ``column + k L`` of ``out`` ``(N, K)`` what the measured rows
        ahead of the particles ``x`` ``(n, N)`` (C-contiguous) depart from their linearisation at ``mean``
        ``(n,)`` (angles wrapped): ``d^T T d / 2`` with the second derivatives, else by the flow."""
        if self.hessians is not None:
            quadratic_departure(x, mean, self.hessians, out, column)
            return
        states, t, k = x.T, self.time, int(self.rows.sum())
        for lag, (step, (measured, jacobian)) in enumerate(zip(self.steps, self.ahead)):
            states = self.model.transition(states, step, t, self.input)
            t += step
            residual = self.sensor.measurement_residual(measured, states, t, reverse=True)[:, self.rows]
            departure(residual, x, mean, np.ascontiguousarray(jacobian[self.rows]), out, column + lag * k)


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
        ahead: the rows ahead (None: no lags).
        time: the update's time, s.
        sensor: what the rows are measured with.
    """

    mean: np.ndarray
    measured: np.ndarray
    jacobian: np.ndarray
    rows: np.ndarray
    gain: np.ndarray
    noise_std: np.ndarray
    ahead: RowsAhead | None
    time: float
    sensor: Sensor

    def curvature(self, x: np.ndarray) -> np.ndarray:
        """``nu(x)`` ``(N, k + k L)`` of the particles ``x`` ``(n, N)``: what each stacked measured row departs
        from its linearisation at the mean (angles wrapped); the rows now exactly."""
        x = np.ascontiguousarray(x)
        m = self.measured.size
        nu = np.empty((x.shape[1], m + self.gain.shape[1] - int(self.rows.sum())))  # (now, then ahead, in place)
        departure(self.sensor.measurement_residual(self.measured, x.T, self.time, reverse=True), x, self.mean,
                  np.ascontiguousarray(self.jacobian), nu, 0)
        if self.ahead is not None:
            self.ahead.departures(x, self.mean, nu, m)
        return nu if self.rows.all() else nu[:, np.concatenate([self.rows, np.ones(nu.shape[1] - m, bool)])]

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
    components of the state only, and the cloud in them, ``xi`` ``(n, N)``. None when the curvature of its
    outermost particles (:func:`outermost_curvature`) is below :data:`FLAT_ENOUGH` (the coordinates are then
    the state's own, to that accuracy), the rows measured now are not of full rank at the mean, or anything
    is non-finite. The curvature is tested before the gain is built: a cloud left as it is pays for one
    evaluation of it."""
    mean = np.einsum("in,n->i", x, weights)
    h, H = sensor.measure_and_jacobian(mean[None], time)
    h, H = h[0], H[0]
    n = x.shape[0]
    k = int(rows.sum())
    noise_std = np.concatenate([np.sqrt(np.diag(sensor.noise(time))[rows])] * (1 + len(lags)))
    ahead = _rows_ahead(x, weights, mean, rows, sensor, model, time, u, lags, noise_std[k:]) if lags else None
    arrays = (h, H) if ahead is None else (h, H, *(a for pair in ahead.ahead for a in pair))
    if not np.isfinite(np.concatenate([a.ravel() for a in arrays])).all():
        return None
    gain = np.zeros((n, k * (1 + len(lags))))  # (written below, once the cloud is known to need it)
    flat = Flattening(mean, h, H, rows, gain, noise_std, ahead, float(time), sensor)
    nu = flat.curvature(x)
    if not outermost_curvature(nu, noise_std) >= FLAT_ENOUGH:  # (NaN: nothing to flatten with)
        return None
    now = H[rows][:, :user_dim]  # (k, n_user)
    try:
        first = np.linalg.solve(now @ now.T, now).T  # (n_user, k): J_0^+ on the user's state
    except np.linalg.LinAlgError:
        return None
    gain[:user_dim, :k] = first
    if lags:
        later = np.vstack([jacobian[rows] for _, jacobian in ahead.ahead])[:, :user_dim]  # (k L, n_user)
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


def outermost_curvature(nu: np.ndarray, noise_std: np.ndarray) -> float:
    """The curvature of the cloud's outermost particles (:data:`OUTERMOST`), in noise standard deviations: the
    ``N // OUTERMOST``-th largest over the particles of ``max |nu / noise_std|`` (``nu`` ``(N, K)``,
    ``noise_std`` ``(K,)``); NaN when any particle's is."""
    count = nu.shape[0] // OUTERMOST
    if count <= 1:
        return largest_scaled(nu, _NONE, noise_std)
    largest = np.empty(nu.shape[0])
    if scaled_by_particle(nu, noise_std, largest):
        return math.nan
    return float(np.partition(largest, largest.size - count)[largest.size - count])


def _rows_ahead(x: np.ndarray, weights: np.ndarray, mean: np.ndarray, rows: np.ndarray, sensor: Sensor,
                model: StateSpaceModel, time: float, u: np.ndarray | None, lags: tuple[float, ...],
                noise_std: np.ndarray) -> RowsAhead:
    """The measured ``rows`` ``(m,)`` of the cloud ``x`` ``(n, N)`` (normalised ``weights`` ``(N,)``, weighted
    ``mean`` ``(n,)``) flowed by ``model`` with the input ``u`` held to each of the increasing ``lags``, about
    the mean; ``noise_std`` ``(k L,)`` are the measured rows' noise standard deviations at every lag.

    From :data:`SECOND_ORDER` particles, to second order: one flow of a few states instead of the cloud's,
    the mean, the mean moved by ``+-`` the cloud's standard deviation along each component (a relative step
    where the cloud has none), and the particles farthest from the mean on either side along each component
    (the outermost). The central differences of the moved states' Jacobians are the rows' second derivatives,
    exact for rows quadratic in the state and secants across the cloud otherwise, and the departures of
    the rows ahead are ``d^T T d / 2`` (:func:`~gpf_nav.kernels.curvature.quadratic_departure`). Where that
    misses the outermost particles' flowed rows by more than :data:`FLAT_ENOUGH` of the noise (the third
    order grows as the cube of the cloud's width: tenths of the range noise at the 3-sigma particles of a
    20 km prior), or below :data:`SECOND_ORDER` particles, the departures flow every particle."""
    steps = tuple(float(later) - float(earlier) for earlier, later in zip((0.0, *lags), lags))
    n = mean.size
    if x.shape[1] < SECOND_ORDER:
        ahead, flowed, t, F = [], mean[None], time, np.eye(n)
        for dt in steps:
            F = model.transition_jacobian(flowed, dt, t, u)[0] @ F
            flowed = model.transition(flowed, dt, t, u)
            t += dt
            measured, jacobian = sensor.measure_and_jacobian(flowed, t)
            ahead.append((measured[0], jacobian[0] @ F))
        return RowsAhead(rows, tuple(ahead), None, steps, float(time), sensor, model, u)
    offsets = x - mean[:, None]
    spread = np.sqrt(np.einsum("in,in,n->i", offsets, offsets, weights))
    step = np.where(spread > 0.0, spread, 1e-6 * np.maximum(np.abs(mean), 1.0))
    outermost = np.concatenate([offsets.argmax(axis=1), offsets.argmin(axis=1)])  # (2 n,)
    moved = np.arange(1, n + 1)
    states = np.vstack([np.tile(mean, (2 * n + 1, 1)), x[:, outermost].T])  # (the mean, moved +- along each
    # component, and the outermost particles)
    states[moved, moved - 1] += step
    states[moved + n, moved - 1] -= step
    ahead, hessians, departures, t, flow = [], [], [], time, None
    for dt in steps:
        jacobian = model.transition_jacobian(states, dt, t, u)
        flow = jacobian if flow is None else jacobian @ flow
        states = model.transition(states, dt, t, u)
        t += dt
        measured, jacobian = sensor.measure_and_jacobian(states, t)
        jacobian = jacobian @ flow  # (4 n + 1, m, n)
        ahead.append((measured[0], jacobian[0]))
        second = (jacobian[1:n + 1, rows] - jacobian[n + 1:2 * n + 1, rows]).transpose(1, 2, 0) / (2.0 * step)
        hessians.append(0.5 * (second + second.transpose(0, 2, 1)))  # (k, n, n)
        departures.append(sensor.measurement_residual(measured[0], states[2 * n + 1:], t, reverse=True)[:, rows]
                          - offsets[:, outermost].T @ jacobian[0, rows].T)  # (2 n, k)
    hessians = np.concatenate(hessians)
    d = offsets[:, outermost]
    missed = np.hstack(departures) - 0.5 * np.einsum("in,cij,jn->nc", d, hessians, d)
    second_order = np.all(np.abs(missed) <= FLAT_ENOUGH * noise_std)  # (NaN: flowed)
    return RowsAhead(rows, tuple(ahead), hessians if second_order else None, steps, float(time), sensor, model, u)


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
