"""The lunar model's inner loops: two-body leapfrog flow and its Jacobian, orbit frames, and an
acceleration given in those frames pushed onto the velocities and positions (the compensated transition).

States are particle-last: ``x`` ``(6, N)`` with rows ``r`` (0:3) and ``v`` (3:6); the specific force ``u``
is ``(3, K)`` with ``K`` 1 (one input for every particle) or ``N``. The arithmetic is the numpy code's,
operation for operation, per particle.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from gpf_nav.kernels import CHUNK, PARALLEL


MIN_RANGE_SQ = 1.0
"""m^2: floor of |r|^2 that keeps gravity finite at the Moon's centre."""
MIN_RANGE = 1.0
"""m: floor of the range of the orbit frame's radial axis."""


@njit(cache=True, error_model="numpy")
def _gravity(r0, r1, r2, gm):
    """The factor ``k`` of two-body gravity ``k r`` at ``r`` (``|r|^2`` floored at :data:`MIN_RANGE_SQ`)."""
    rr = r0 * r0 + r1 * r1 + r2 * r2
    rr = max(rr, MIN_RANGE_SQ)
    return -gm / (rr * math.sqrt(rr))


@njit(cache=True, error_model="numpy")
def _substep(r0, r1, r2, v0, v1, v2, a0, a1, a2, gm, h, u0, u1, u2):
    """One kick-drift-kick sub-step ``h`` from ``(r, v)`` with the acceleration ``a`` at ``r``: the new
    ``(r, v)`` and the acceleration at the new ``r`` (gravity ``gm`` plus ``u``), nine floats."""
    half = 0.5 * h
    v0 += half * a0
    v1 += half * a1
    v2 += half * a2
    r0 += h * v0
    r1 += h * v1
    r2 += h * v2
    k = _gravity(r0, r1, r2, gm)
    a0, a1, a2 = r0 * k + u0, r1 * k + u1, r2 * k + u2
    v0 += half * a0
    v1 += half * a1
    v2 += half * a2
    return r0, r1, r2, v0, v1, v2, a0, a1, a2


@njit(cache=True, error_model="numpy")
def _leapfrog_block(x, gm, h, steps, u, start, buffer, out):
    """:func:`leapfrog` of the particles ``start`` to ``start + CHUNK`` of ``x`` into ``out``, through the
    rows of ``buffer`` ``(12, CHUNK)``: each sub-step runs over the whole block, a loop that vectorises
    (the sub-steps of one particle are a chain of dependent square roots and divisions)."""
    size = min(buffer.shape[1], x.shape[1] - start)
    r0, r1, r2, v0, v1, v2 = buffer[0], buffer[1], buffer[2], buffer[3], buffer[4], buffer[5]
    a0, a1, a2, u0, u1, u2 = buffer[6], buffer[7], buffer[8], buffer[9], buffer[10], buffer[11]
    each = u.shape[1] > 1
    for t in range(size):
        j = start + t
        ju = j * each  # (not ``j if each else 0``: a parallel loop's unsigned j and 0 unify to a float)
        u0[t], u1[t], u2[t] = u[0, ju], u[1, ju], u[2, ju]
        r0[t], r1[t], r2[t] = x[0, j], x[1, j], x[2, j]
        v0[t], v1[t], v2[t] = x[3, j], x[4, j], x[5, j]
    for t in range(size):
        k = _gravity(r0[t], r1[t], r2[t], gm)
        a0[t], a1[t], a2[t] = r0[t] * k + u0[t], r1[t] * k + u1[t], r2[t] * k + u2[t]
    for _ in range(steps):
        for t in range(size):
            r0[t], r1[t], r2[t], v0[t], v1[t], v2[t], a0[t], a1[t], a2[t] = _substep(
                r0[t], r1[t], r2[t], v0[t], v1[t], v2[t], a0[t], a1[t], a2[t], gm, h, u0[t], u1[t], u2[t])
    for t in range(size):
        j = start + t
        out[0, j], out[1, j], out[2, j] = r0[t], r1[t], r2[t]
        out[3, j], out[4, j], out[5, j] = v0[t], v1[t], v2[t]


@njit(cache=True, error_model="numpy")
def _leapfrog_serial(x, gm, h, steps, u):
    out = np.empty((6, x.shape[1]))
    buffer = np.empty((12, CHUNK))
    for start in range(0, x.shape[1], CHUNK):
        _leapfrog_block(x, gm, h, steps, u, start, buffer, out)
    return out


@njit(cache=True, error_model="numpy", parallel=True)
def _leapfrog_parallel(x, gm, h, steps, u):
    out = np.empty((6, x.shape[1]))
    for block in prange((x.shape[1] + CHUNK - 1) // CHUNK):
        _leapfrog_block(x, gm, h, steps, u, block * CHUNK, np.empty((12, CHUNK)), out)
    return out


@njit(cache=True, error_model="numpy")
def _frame_times(a0, a1, a2, t0, t1, t2, n0, n1, n2, c0, c1, c2):
    """``F c`` for the frame of axes ``a``, ``t``, ``n`` (columns), each component summed as :func:`push`
    sums it (from 0, over the axes in turn)."""
    return (((0.0 + a0 * c0) + t0 * c1) + n0 * c2, ((0.0 + a1 * c0) + t1 * c1) + n1 * c2,
            ((0.0 + a2 * c0) + t2 * c1) + n2 * c2)


@njit(cache=True, error_model="numpy")
def _frames_times(x, a, start, stop, pushed):
    """``F a`` of the particles ``start`` to ``stop`` (frame at ``x``) into ``pushed`` ``(4, CHUNK)``: a loop
    that vectorises, flagging in ``pushed[3]`` where there is no orbit plane or an axis is not finite (for
    :func:`_frames_times_again`); returns how many it flagged."""
    r0, r1, r2, v0, v1, v2 = x[0, start:stop], x[1, start:stop], x[2, start:stop], x[3, start:stop], \
        x[4, start:stop], x[5, start:stop]
    c0, c1, c2 = a[0, start:stop], a[1, start:stop], a[2, start:stop]
    flagged = 0
    for t in range(stop - start):
        planar, e0, e1, e2, t0, t1, t2, n0, n1, n2 = _planar_axes(r0[t], r1[t], r2[t], v0[t], v1[t], v2[t])
        pushed[0, t], pushed[1, t], pushed[2, t] = _frame_times(e0, e1, e2, t0, t1, t2, n0, n1, n2, c0[t], c1[t],
                                                                c2[t])
        flag = 0 if planar & _finite(e0, e1, e2, t0, t1, t2, n0, n1, n2) else 1
        pushed[3, t] = flag
        flagged += flag  # (an integer sum: a sum of floats would keep the loop from vectorising)
    return flagged


@njit(cache=True, error_model="numpy")
def _frames_times_again(x, a, start, stop, pushed):
    """:func:`_frames_times` with :func:`_axes` where it flagged the particle."""
    for t in range(stop - start):
        if pushed[3, t] != 0.0:
            j = start + t
            e0, e1, e2, t0, t1, t2, n0, n1, n2 = _axes(x[0, j], x[1, j], x[2, j], x[3, j], x[4, j], x[5, j])
            pushed[0, t], pushed[1, t], pushed[2, t] = _frame_times(e0, e1, e2, t0, t1, t2, n0, n1, n2, a[0, j],
                                                                    a[1, j], a[2, j])


@njit(cache=True, error_model="numpy")
def _pushed_leapfrog_block(x, a, gm, h, steps, u, driven, integrated, velocity_gain, position_gain, start,
                           buffer, pushed, out):
    """:func:`pushed_leapfrog` of the particles ``start`` to ``start + CHUNK`` through ``buffer``
    ``(12, CHUNK)`` and ``pushed`` ``(4, CHUNK)``: each one's ``F a`` (frame at its state before the step,
    :func:`_frames_times`), then the block's flow, then the pushes. Each loop over the block is a function
    of its own: inlined together, the frames' loop did not vectorise."""
    size = min(buffer.shape[1], x.shape[1] - start)
    stop = start + size
    if _frames_times(x, a, start, stop, pushed):  # (a scan of the flags costs as much as the frames: its
        # vectorised loop computes _axes for every particle)
        _frames_times_again(x, a, start, stop, pushed)
    _leapfrog_block(x, gm, h, steps, u, start, buffer, out)
    for i in range(3):
        _add_times(out[driven[i], start:stop], pushed[i, :size], velocity_gain)
        if integrated.size:
            _add_times(out[integrated[i], start:stop], pushed[i, :size], position_gain)


@njit(cache=True, error_model="numpy")
def _add_times(moved, pushed, gain):
    """``moved += pushed * gain`` (rows ``(K,)``)."""
    for t in range(moved.size):
        moved[t] += pushed[t] * gain


@njit(cache=True, error_model="numpy")
def _pushed_leapfrog_serial(x, a, gm, h, steps, u, driven, integrated, velocity_gain, position_gain, out):
    buffer, pushed = np.empty((12, CHUNK)), np.empty((4, CHUNK))
    for start in range(0, x.shape[1], CHUNK):
        _pushed_leapfrog_block(x, a, gm, h, steps, u, driven, integrated, velocity_gain, position_gain, start,
                               buffer, pushed, out)


@njit(cache=True, error_model="numpy", parallel=True)
def _pushed_leapfrog_parallel(x, a, gm, h, steps, u, driven, integrated, velocity_gain, position_gain, out):
    for block in prange((x.shape[1] + CHUNK - 1) // CHUNK):
        _pushed_leapfrog_block(x, a, gm, h, steps, u, driven, integrated, velocity_gain, position_gain,
                               block * CHUNK, np.empty((12, CHUNK)), np.empty((4, CHUNK)), out)


@njit(cache=True, error_model="numpy")
def leapfrog_chain(x: np.ndarray, gm: float, h: np.ndarray, steps: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``(6, K + 1)``: the state ``x`` ``(6,)`` and after each of ``K`` :func:`leapfrog` calls in turn, the
    ``k``-th of ``steps[k]`` sub-steps ``h[k]`` with the input ``u[:, k]`` (``u`` ``(3, K)``): the same numbers
    as the ``K`` calls, in one."""
    out = np.empty((6, h.size + 1))
    state, moved, force, buffer = np.empty((6, 1)), np.empty((6, 1)), np.empty((3, 1)), np.empty((12, 1))
    state[:, 0] = x
    out[:, 0] = x
    for k in range(h.size):
        force[:, 0] = u[:, k]
        _leapfrog_block(state, gm, h[k], steps[k], force, 0, buffer, moved)
        state[:, 0] = moved[:, 0]
        out[:, k + 1] = moved[:, 0]
    return out


@njit(cache=True, error_model="numpy")
def pushed_leapfrog_chain(x: np.ndarray, a: np.ndarray, gm: float, h: np.ndarray, steps: np.ndarray,
                          u: np.ndarray, driven: np.ndarray, integrated: np.ndarray, velocity_gain: np.ndarray,
                          position_gain: np.ndarray, decay: np.ndarray) -> np.ndarray:
    """``(9, K + 1)``: the state ``x`` ``(6,)`` with the acceleration ``a`` ``(3,)``, and after each of ``K``
    compensated transitions in turn: :func:`pushed_leapfrog` with the ``k``-th entries of ``h``, ``steps``,
    ``u`` ``(3, K)``, ``velocity_gain`` and ``position_gain``, then ``a`` times ``decay[k]`` (the same
    numbers as the ``K`` calls, in one)."""
    out = np.empty((9, h.size + 1))
    state, moved, acceleration = np.empty((6, 1)), np.empty((6, 1)), np.empty((3, 1))
    force, buffer, pushed = np.empty((3, 1)), np.empty((12, 1)), np.empty((4, 1))
    state[:, 0] = x
    acceleration[:, 0] = a
    out[:6, 0] = x
    out[6:, 0] = a
    for k in range(h.size):
        force[:, 0] = u[:, k]
        _pushed_leapfrog_block(state, acceleration, gm, h[k], steps[k], force, driven, integrated,
                               velocity_gain[k], position_gain[k], 0, buffer, pushed, moved)
        for i in range(3):
            acceleration[i, 0] = acceleration[i, 0] * decay[k]
        state[:, 0] = moved[:, 0]
        out[:6, k + 1] = moved[:, 0]
        out[6:, k + 1] = acceleration[:, 0]
    return out


def pushed_leapfrog(x: np.ndarray, a: np.ndarray, gm: float, h: float, steps: int, u: np.ndarray,
                    driven: np.ndarray, integrated: np.ndarray, velocity_gain: float, position_gain: float,
                    out: np.ndarray) -> None:
    """:func:`leapfrog` of ``x`` ``(6, N)`` into ``out`` ``(6, N)`` (rows of any array), then the
    acceleration ``a`` ``(3, N)``, given in the :func:`frames` at ``x``, pushed as :func:`push` pushes it:
    the compensated lunar transition in one pass, each frame used where it is made (the same numbers as
    the three kernels in turn; on every core from :data:`~gpf_nav.kernels.PARALLEL` particles)."""
    kernel = _pushed_leapfrog_parallel if x.shape[1] >= PARALLEL else _pushed_leapfrog_serial
    kernel(x, a, gm, h, steps, u, driven, integrated, velocity_gain, position_gain, out)


def leapfrog(x: np.ndarray, gm: float, h: float, steps: int, u: np.ndarray) -> np.ndarray:
    """Kick-drift-kick leapfrog of ``steps`` sub-steps ``h`` under two-body gravity ``gm`` plus the specific
    force ``u`` ``(3, K)``, from the states ``x`` ``(6, N)`` (C-contiguous): the new states ``(6, N)`` (on
    every core from :data:`~gpf_nav.kernels.PARALLEL` particles)."""
    return (_leapfrog_parallel if x.shape[1] >= PARALLEL else _leapfrog_serial)(x, gm, h, steps, u)


@njit(cache=True, error_model="numpy")
def leapfrog_jacobian(x: np.ndarray, gm: float, h: float, steps: int, u: np.ndarray) -> np.ndarray:
    """Jacobians ``(N, 6, 6)`` of :func:`leapfrog` at ``x`` ``(6, N)``: the second-order Taylor step
    ``I + A h + (A h)^2 / 2`` (``A = [[0, I], [gravity gradient, 0]]``) chained over the sub-steps, the
    state moved along by one leapfrog sub-step between them."""
    count = x.shape[1]
    out = np.empty((count, 6, 6))
    A = np.zeros((6, 6))
    for i in range(3):
        A[i, 3 + i] = h
    step = np.empty((6, 6))
    product = np.empty((6, 6))
    r = np.empty(3)
    for j in range(count):
        ju = j if u.shape[1] > 1 else 0
        u0, u1, u2 = u[0, ju], u[1, ju], u[2, ju]
        r0, r1, r2, v0, v1, v2 = x[0, j], x[1, j], x[2, j], x[3, j], x[4, j], x[5, j]
        phi = out[j]
        for a in range(6):
            for b in range(6):
                phi[a, b] = 1.0 if a == b else 0.0
        for _ in range(steps):
            rr = max(r0 * r0 + r1 * r1 + r2 * r2, MIN_RANGE_SQ)
            k = -gm * rr ** -1.5
            r[0], r[1], r[2] = r0, r1, r2
            for a in range(3):
                for b in range(3):
                    g = (1.0 if a == b else 0.0) - 3.0 * (r[a] * r[b] / rr)
                    A[3 + a, b] = (k * g) * h
            for a in range(6):  # I + A + (A A) / 2
                for b in range(6):
                    s = 0.0
                    for c in range(6):
                        s += A[a, c] * A[c, b]
                    step[a, b] = ((1.0 if a == b else 0.0) + A[a, b]) + s * 0.5
            for a in range(6):  # phi <- step phi
                for b in range(6):
                    s = 0.0
                    for c in range(6):
                        s += step[a, c] * phi[c, b]
                    product[a, b] = s
            for a in range(6):  # (loops, not a slice assignment: that takes seconds to compile)
                for b in range(6):
                    phi[a, b] = product[a, b]
            if steps > 1:  # (the numpy code's one-sub-step transition, its acceleration from the new r)
                k = _gravity(r0, r1, r2, gm)
                a0, a1, a2 = r0 * k + u0, r1 * k + u1, r2 * k + u2
                r0, r1, r2, v0, v1, v2, a0, a1, a2 = _substep(r0, r1, r2, v0, v1, v2, a0, a1, a2, gm, h,
                                                              u0, u1, u2)
    return out


@njit(cache=True, error_model="numpy")
def _finite(a0, a1, a2, t0, t1, t2, n0, n1, n2):
    return (math.isfinite(a0) & math.isfinite(a1) & math.isfinite(a2) & math.isfinite(t0) & math.isfinite(t1)
            & math.isfinite(t2) & math.isfinite(n0) & math.isfinite(n1) & math.isfinite(n2))


@njit(cache=True, error_model="numpy")
def _planar_axes(r0, r1, r2, v0, v1, v2):
    """``(planar, nine floats)``: whether ``(r, v)`` spans an orbit plane, and the radial, along-track and
    cross-track axes of the osculating orbit (its radial axis whether or not; the other two only when
    planar)."""
    size_r = max(math.sqrt(r0 * r0 + r1 * r1 + r2 * r2), MIN_RANGE)
    a0, a1, a2 = r0 / size_r, r1 / size_r, r2 / size_r
    n0, n1, n2 = a1 * v2 - a2 * v1, a2 * v0 - a0 * v2, a0 * v1 - a1 * v0
    size = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    planar = size > 1e-12 * max(math.sqrt(v0 * v0 + v1 * v1 + v2 * v2), 1.0)
    n0, n1, n2 = n0 / size, n1 / size, n2 / size
    along = a0 * v0 + a1 * v1 + a2 * v2
    t0, t1, t2 = (v0 - a0 * along) / size, (v1 - a1 * along) / size, (v2 - a2 * along) / size
    return planar, a0, a1, a2, t0, t1, t2, n0, n1, n2


@njit(cache=True, error_model="numpy")
def _axes(r0, r1, r2, v0, v1, v2):
    """The radial, along-track and cross-track axes of the osculating orbit of ``(r, v)``, nine floats
    (:func:`frames`)."""
    planar, a0, a1, a2, t0, t1, t2, n0, n1, n2 = _planar_axes(r0, r1, r2, v0, v1, v2)
    if not planar:  # no orbit plane: any axis normal to r, with the least-aligned base axis
        m0, m1, m2 = abs(a0), abs(a1), abs(a2)
        b = 0 if (m0 <= m1 and m0 <= m2) else (1 if m1 <= m2 else 2)
        e0, e1, e2 = (1.0 if b == 0 else 0.0), (1.0 if b == 1 else 0.0), (1.0 if b == 2 else 0.0)
        n0, n1, n2 = a1 * e2 - a2 * e1, a2 * e0 - a0 * e2, a0 * e1 - a1 * e0
        size = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        n0, n1, n2 = n0 / size, n1 / size, n2 / size
        t0, t1, t2 = n1 * a2 - n2 * a1, n2 * a0 - n0 * a2, n0 * a1 - n1 * a0
    if not _finite(a0, a1, a2, t0, t1, t2, n0, n1, n2):
        return 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    return a0, a1, a2, t0, t1, t2, n0, n1, n2


@njit(cache=True, error_model="numpy")
def _frames_block(x, start, stop, frame):
    """:func:`frames` of the particles ``start`` to ``stop`` of ``x`` into ``frame`` (a scalar loop: the
    lunar model's frames are taken at a few points at a time; its transition makes them in
    :func:`pushed_leapfrog`)."""
    for j in range(start, stop):
        a0, a1, a2, t0, t1, t2, n0, n1, n2 = _axes(x[0, j], x[1, j], x[2, j], x[3, j], x[4, j], x[5, j])
        frame[0, 0, j], frame[1, 0, j], frame[2, 0, j] = a0, a1, a2
        frame[0, 1, j], frame[1, 1, j], frame[2, 1, j] = t0, t1, t2
        frame[0, 2, j], frame[1, 2, j], frame[2, 2, j] = n0, n1, n2


@njit(cache=True, error_model="numpy")
def _frames_serial(x):
    frame = np.empty((3, 3, x.shape[1]))
    _frames_block(x, 0, x.shape[1], frame)
    return frame


@njit(cache=True, error_model="numpy", parallel=True)
def _frames_parallel(x):
    frame = np.empty((3, 3, x.shape[1]))
    for block in prange((x.shape[1] + CHUNK - 1) // CHUNK):
        _frames_block(x, block * CHUNK, min(block * CHUNK + CHUNK, x.shape[1]), frame)
    return frame


def frames(x: np.ndarray) -> np.ndarray:
    """Radial, along-track and cross-track axes ``(3, 3, N)`` (component, axis, particle) of the osculating
    orbits of ``x`` ``(6, N)`` (C-contiguous); where the orbit plane is undefined the cross-track axis is
    the cross product of the radial axis with the least-aligned base axis, and where no frame results
    (``r = 0``, a non-finite state) the frame is the world's (on every core from
    :data:`~gpf_nav.kernels.PARALLEL` particles)."""
    return (_frames_parallel if x.shape[1] >= PARALLEL else _frames_serial)(x)


@njit(cache=True, error_model="numpy")
def push_derivative(x: np.ndarray, a: np.ndarray, relative_step: float) -> np.ndarray:
    """``d(F(x) a) / dx`` ``(N, 3, 6)`` of the acceleration ``a`` ``(N, 3)`` pushed by the frame at the
    states ``x`` ``(N, 6)`` (:func:`frames`), held fixed, by central differences with the steps
    ``relative_step * max(|x|, 1)``: the numbers of the generic central differences of
    :mod:`gpf_nav.models.compensation` over :func:`frames` (each ``F a`` summed as numpy's ``einsum`` sums it
    there, from 0 over the axes in turn: :func:`_frame_times`), in one pass (a point's Jacobian is taken three
    times per step, and at every logged step when the observability tracker rebuilds)."""
    out = np.empty((x.shape[0], 3, 6))
    moved = np.empty(6)
    for m in range(x.shape[0]):
        c0, c1, c2 = a[m, 0], a[m, 1], a[m, 2]
        for j in range(6):
            size = abs(x[m, j])
            step = relative_step * (size if (size > 1.0 or size != size) else 1.0)  # (numpy's maximum)
            for k in range(6):  # x + step e_j and x - step e_j, every component shifted (by step * 0 but j)
                moved[k] = x[m, k] + step * (1.0 if k == j else 0.0)
            p0, p1, p2 = _frame_times(*_axes(moved[0], moved[1], moved[2], moved[3], moved[4], moved[5]), c0, c1, c2)
            for k in range(6):
                moved[k] = x[m, k] - step * (1.0 if k == j else 0.0)
            q0, q1, q2 = _frame_times(*_axes(moved[0], moved[1], moved[2], moved[3], moved[4], moved[5]), c0, c1, c2)
            twice = 2.0 * step
            out[m, 0, j], out[m, 1, j], out[m, 2, j] = (p0 - q0) / twice, (p1 - q1) / twice, (p2 - q2) / twice
    return out


@njit(cache=True, error_model="numpy")
def _push_block(moved, frame, a, driven, integrated, velocity_gain, position_gain, start, stop):
    """:func:`push` of the particles ``start`` to ``stop``."""
    p = a.shape[0]
    for j in range(start, stop):
        for i in range(p):
            s = 0.0
            for k in range(p):
                s += frame[i, k, j] * a[k, j]
            moved[driven[i], j] += s * velocity_gain
            if integrated.size:
                moved[integrated[i], j] += s * position_gain


@njit(cache=True, error_model="numpy")
def _push_serial(moved, frame, a, driven, integrated, velocity_gain, position_gain):
    _push_block(moved, frame, a, driven, integrated, velocity_gain, position_gain, 0, a.shape[1])


@njit(cache=True, error_model="numpy", parallel=True)
def _push_parallel(moved, frame, a, driven, integrated, velocity_gain, position_gain):
    for block in prange((a.shape[1] + CHUNK - 1) // CHUNK):
        _push_block(moved, frame, a, driven, integrated, velocity_gain, position_gain, block * CHUNK,
                    min(block * CHUNK + CHUNK, a.shape[1]))


def push(moved: np.ndarray, frame: np.ndarray, a: np.ndarray, driven: np.ndarray, integrated: np.ndarray,
         velocity_gain: float, position_gain: float) -> None:
    """Add the acceleration ``a`` ``(p, N)``, given in the local ``frame`` ``(p, p, N)``, to the states
    ``moved`` ``(n, N)`` in place: ``F a`` times ``velocity_gain`` onto the rows ``driven`` ``(p,)`` and times
    ``position_gain`` onto the rows ``integrated`` ``(p,)`` (empty: none; on every core from
    :data:`~gpf_nav.kernels.PARALLEL` particles)."""
    kernel = _push_parallel if a.shape[1] >= PARALLEL else _push_serial
    kernel(moved, frame, a, driven, integrated, velocity_gain, position_gain)


@njit(cache=True, error_model="numpy")
def line_of_sight(r: np.ndarray, station: np.ndarray) -> np.ndarray:
    """``(5, N)``: the line of sight ``d = r - station`` (rows 0 to 2), its horizontal length and its
    length (the range) of the positions ``r`` ``(3, N)`` (C-contiguous) from ``station`` ``(3,)``, in the
    numpy code's order of operations."""
    out = np.empty((5, r.shape[1]))
    s0, s1, s2 = station[0], station[1], station[2]
    for j in range(r.shape[1]):
        d0, d1, d2 = r[0, j] - s0, r[1, j] - s1, r[2, j] - s2
        horizontal = d0 * d0 + d1 * d1
        out[0, j], out[1, j], out[2, j] = d0, d1, d2
        out[3, j] = math.sqrt(horizontal)
        out[4, j] = math.sqrt(horizontal + d2 * d2)
    return out
