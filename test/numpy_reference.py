"""The numpy code the compiled kernels (gpf_nav/kernels) replaced, kept as the tests' oracle: the same
operations as the filters and the lunar model ran before the kernels (at 200c859)."""
from __future__ import annotations

import numpy as np

from gpf_nav.linalg import cholesky_or_none, triangular_inverse

MIN_RANGE_SQ = 1.0
MIN_RANGE = 1.0


def weighted_moments(x, weights):
    """``(mean (n,), covariance (n, n))`` of ``x`` ``(n, N)`` with normalised ``weights`` ``(N,)``."""
    mean = x @ weights
    d = x - mean[:, None]
    root = d * np.sqrt(weights)
    return mean, root @ root.T


def match_moments(x, weights, mean, cov):
    """``mean + L_cov L_x^-1 (x - m_x)``, or None."""
    m_x, current = weighted_moments(x, weights)
    source, target = cholesky_or_none(current, symmetric=True), cholesky_or_none(cov)
    if source is None or target is None:
        return None
    return (target @ triangular_inverse(source)) @ (x - m_x[:, None]) + mean[:, None]


def systematic(weights, uniform):
    n = weights.size
    cdf = np.cumsum(weights)
    cdf /= cdf[-1]
    cdf[-1] = 1.0
    edges = np.ceil(n * cdf - uniform)
    counts = np.diff(np.clip(edges, 0, n), prepend=0.0).astype(np.intp)
    return np.repeat(np.arange(n), counts)


def normalise(logw):
    """``(log-sum-exp, normalised log-weights, weights)`` of ``logw`` (NaN set to -inf in place), or None
    when the peak is not finite."""
    logw[np.isnan(logw)] = -np.inf
    peak = logw.max()
    if not -np.inf < peak < np.inf:
        return None
    total = peak + np.log(np.exp(logw - peak).sum())
    normalised = logw - total
    return float(total), normalised, np.exp(normalised)


def gaussian_log_likelihood(e, rows, w, constant):
    """``constant - |W e|^2 / 2`` ``(N,)`` of the measured ``rows`` of the residuals ``e`` ``(m, N)``, ``W`` the
    diagonal ``w`` ``(k,)`` or a matrix ``(k, k)``."""
    e = e if rows.all() else e[rows]
    ew = e * w[:, None] if w.ndim == 1 else w @ e
    return constant - 0.5 * np.einsum("kn,kn->n", ew, ew)


def _acceleration(r, gm, u):
    r2 = np.einsum("ij,ij->j", r, r)
    np.maximum(r2, MIN_RANGE_SQ, out=r2)
    a = r * (-gm / (r2 * np.sqrt(r2)))
    if u is not None:
        a += u.T if u.ndim == 2 else u[:, None]
    return a


def leapfrog(x, gm, h, steps, u=None):
    """Lunar transition over ``steps`` sub-steps ``h`` of ``x`` ``(N, 6)``: ``(N, 6)``."""
    xt = x.T
    r, v = xt[:3].copy(), xt[3:].copy()
    a = _acceleration(r, gm, u)
    for _ in range(steps):
        v += (0.5 * h) * a
        r += h * v
        a = _acceleration(r, gm, u)
        v += (0.5 * h) * a
    return np.concatenate([r, v]).T


def leapfrog_jacobian(x, gm, h, steps, u=None):
    """``(N, 6, 6)``: ``I + A h + (A h)^2 / 2`` chained over the sub-steps."""
    n = x.shape[0]
    phi = np.broadcast_to(np.eye(6), (n, 6, 6)).copy()
    state = np.asarray(x, dtype=float)
    for _ in range(steps):
        r = state[:, :3]
        r2 = np.maximum(np.einsum("ij,ij->i", r, r), MIN_RANGE_SQ)
        k = -gm * r2 ** -1.5
        outer = r[:, :, None] * r[:, None, :] / r2[:, None, None]
        a = np.zeros((n, 6, 6))
        a[:, :3, 3:] = np.eye(3)
        a[:, 3:, :3] = k[:, None, None] * (np.eye(3) - 3.0 * outer)
        ah = a * h
        phi = (np.eye(6) + ah + ah @ ah * 0.5) @ phi
        if steps > 1:
            state = leapfrog(state, gm, h, 1, u)
    return phi


def _cross(a, b):
    out = np.empty(a.shape)
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        out[i] = a[j] * b[k] - a[k] * b[j]
    return out


def frames(x):
    """Orbit frames ``(N, 3, 3)`` of ``x`` ``(N, 6)`` (columns radial, along-track, cross-track)."""
    xt = x.T
    r, v = xt[:3], xt[3:6]
    frame = np.empty((3, 3, x.shape[0]))
    radial = r / np.maximum(np.sqrt(np.einsum("in,in->n", r, r)), MIN_RANGE)
    normal = _cross(radial, v)
    size = np.sqrt(np.einsum("in,in->n", normal, normal))
    speed2 = np.einsum("in,in->n", v, v)
    flat = ~(size > 1e-12 * np.maximum(np.sqrt(speed2), 1.0))
    base = np.eye(3)[:, np.argmin(np.abs(radial), axis=0)]
    normal[:, flat] = _cross(radial[:, flat], base[:, flat])
    size[flat] = np.sqrt(np.einsum("in,in->n", normal[:, flat], normal[:, flat]))
    with np.errstate(invalid="ignore", divide="ignore"):
        normal = normal / size
    along = (v - radial * np.einsum("in,in->n", radial, v)) / np.where(flat, 1.0, np.sqrt(
        np.einsum("in,in->n", _cross(radial, v), _cross(radial, v))))
    along[:, flat] = _cross(normal[:, flat], radial[:, flat])
    frame[:, 0], frame[:, 1], frame[:, 2] = radial, along, normal
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(frame).all(axis=(0, 1))
    frame[:, :, bad] = np.eye(3)[:, :, None]
    return frame.transpose(2, 0, 1)


def push(moved, frame, a, driven, integrated, velocity_gain, position_gain):
    """``moved`` ``(n, N)`` plus the pushed acceleration (compensation.py ``transition``), a new array."""
    moved = moved.copy()
    pushed = np.einsum("ijn,jn->in", frame, a)
    moved[driven] += pushed * velocity_gain
    if integrated.size:
        moved[integrated] += pushed * position_gain
    return moved


# --- the observability tracker's arithmetic (gpf_nav/integrity/observability.py before kernels/information.py)
REANCHOR_SIGMAS = 10.0


def _symmetric(a):
    return 0.5 * (a + a.T)


def propagate(F, Q, reference, free, data):
    """``(ok, free, data)`` of the tracker's ``predict``."""
    if not (np.isfinite(F).all() and np.isfinite(Q).all() and np.isfinite(reference).all()):
        return False, free, data
    return True, _symmetric(F @ free @ F.T + Q), _symmetric(F @ data @ F.T + Q)


def far(H, R, r, free):
    """Whether the tracker's ``update`` moves its reference (None: H or r not finite, no update)."""
    if not (np.isfinite(H).all() and np.isfinite(r).all()):
        return None
    spread = H @ free @ H.T + R
    try:
        with np.errstate(all="ignore"):
            return not float(r @ np.linalg.solve(spread, r)) <= REANCHOR_SIGMAS ** 2  # NaN: far
    except np.linalg.LinAlgError:
        return True


def joseph(H, R, P):
    """The tracker's Joseph-form update of ``P``, or None when ``S`` is singular."""
    PHt = P @ H.T
    S = H @ PHt + R
    try:
        K = np.linalg.solve(S, PHt.T).T
    except np.linalg.LinAlgError:
        return None
    A = np.eye(P.shape[0]) - K @ H
    return _symmetric(A @ P @ A.T + K @ R @ K.T)


def report(free, data):
    """``(scale, information, vectors)`` of the tracker's report, or None."""
    s = np.sqrt(np.maximum(np.diag(free), 1e-300))
    free_s, data_s = free / np.outer(s, s), data / np.outer(s, s)
    try:
        L = np.linalg.cholesky(free_s)
        C = np.linalg.cholesky(data_s)
    except np.linalg.LinAlgError:
        return None
    A = np.linalg.solve(C, L)
    _, sv, vt = np.linalg.svd(A)
    information = np.maximum(sv[::-1] ** 2 - 1.0, 0.0)
    u = vt[::-1]
    vectors = (u @ L.T) * s
    vectors = vectors / np.linalg.norm(vectors / s, axis=1, keepdims=True)
    if not (np.isfinite(information).all() and np.isfinite(vectors).all()):
        return None
    return s, information, vectors


# --- gpf_nav/linalg.py positive_definite before its Cholesky screen (kernels/covariance.py)
COVARIANCE_FLOOR_RELATIVE = 1e-10
COVARIANCE_FLOOR_ABSOLUTE = 1e-12


def positive_definite(cov):
    cov = 0.5 * (cov + cov.T)
    if not np.isfinite(cov).all():
        return cov
    variances = cov.diagonal()
    if variances.min() < COVARIANCE_FLOOR_ABSOLUTE:
        cov = cov.copy()
        np.fill_diagonal(cov, np.maximum(variances, COVARIANCE_FLOOR_ABSOLUTE))
    scale = np.sqrt(cov.diagonal())
    vals, vecs = np.linalg.eigh(cov / np.outer(scale, scale))
    floor = COVARIANCE_FLOOR_RELATIVE * max(1.0, float(vals[-1]))
    if vals[0] >= floor:
        return cov
    floored = (vecs * np.maximum(vals, floor)) @ vecs.T
    floored = 0.5 * (floored + floored.T) * np.outer(scale, scale)
    return floored


def wrapped_residual(y, y_pred, angular):
    """``y - y_pred`` with the components of the mask ``angular`` wrapped to (-pi, pi] (at 225425b)."""
    r = np.asarray(y, dtype=float) - y_pred
    angles = np.flatnonzero(angular)
    if angles.size:
        turns = np.ceil((r[..., angles] - np.pi) * (1.0 / (2.0 * np.pi)))
        if np.count_nonzero(turns):
            r[..., angles] -= 2.0 * np.pi * turns
    return r


def line_of_sight(x, station):
    """Line of sight ``(3, N)``, horizontal length and range ``(N,)`` of the states ``x`` ``(N, 6)`` (at
    225425b)."""
    d = x.T[:3] - station[:, None]
    h2 = d[0] * d[0] + d[1] * d[1]
    return d, np.sqrt(h2), np.sqrt(h2 + d[2] * d[2])


def range_bearing_jacobian(d, horizontal, rho, min_horizontal=1e-3, min_range=1.0):
    """``(3, 6, N)`` Jacobian of range, azimuth and elevation from the line of sight (at 7782d64)."""
    hor = np.maximum(horizontal, min_horizontal)
    inv_rho = 1.0 / np.maximum(rho, min_range)
    inv_rho2 = inv_rho * inv_rho
    jac = np.zeros((3, 6, d.shape[1]))
    np.multiply(d, inv_rho, out=jac[0, :3])
    inv_h2 = 1.0 / (hor * hor)
    np.multiply(d[1], inv_h2, out=jac[1, 0])
    np.negative(jac[1, 0], out=jac[1, 0])
    np.multiply(d[0], inv_h2, out=jac[1, 1])
    k = d[2] * inv_rho2
    k /= -hor
    np.multiply(k, d[0], out=jac[2, 0])
    np.multiply(k, d[1], out=jac[2, 1])
    np.multiply(hor, inv_rho2, out=jac[2, 2])
    return jac


def orthogonal_projection(H, r, w, regularization, columns):
    """Shift ``(n, N)`` and ``a`` ``(N, k)`` of the Euclidean projection with a diagonal ``H_w H_w^T``
    (``H`` ``(N, k, n)``, ``r`` ``(N, k)``, ``w`` the whitener's diagonal ``(k,)``; at 7782d64)."""
    k = w.size
    Hw = H.transpose(1, 2, 0)[:, columns]
    rw = r.T * w[:, None]
    S = np.einsum("icn,icn->in", Hw, Hw)
    S *= (w * w)[:, None]
    trace = S.sum(axis=0)
    damping = trace * (regularization / k)
    damping[trace <= 0.0] = 1.0
    S += damping
    a = rw / S
    a[~np.isfinite(a)] = 0.0
    shift = np.zeros((H.shape[2], H.shape[0]))
    shift[columns] = np.einsum("icn,in->cn", Hw, a * w[:, None])
    return shift, a.T


def mixture_moments(weights, moments):
    """Mean and covariance of ``sum_i weights_i N(m_i, P_i)``, weight-0 components left out (at 940346d)."""
    terms = [(w, m, P) for w, (m, P) in zip(weights, moments) if w != 0.0]
    mean = sum(w * m for w, m, _ in terms)
    cov = sum(w * (P + np.outer(m - mean, m - mean)) for w, m, P in terms)
    return mean, 0.5 * (cov + cov.T)
