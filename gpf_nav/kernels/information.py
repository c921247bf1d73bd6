"""The observability tracker's per-step arithmetic (:mod:`gpf_nav.integrity.observability`) on its small
``(n, n)`` covariances: the two propagations, the measurement update (the reanchoring test and the Joseph
form), and the report's information and directions.

Every filter runs the tracker at each predict and update; on matrices of 6 to 9 rows numpy's per-call
overhead would be the whole cost. The operations are the
numpy code's (``test/numpy_reference.py``), in loops: the results are equal to rounding. The small solves
are Gaussian elimination with partial pivoting and the factorisations Cholesky, failing where LAPACK's do
(an exactly zero pivot; a pivot that is not positive), so the tracker refuses the same steps; the SVD and
the QR are LAPACK's (numba calls scipy's), as numpy's were.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

UPDATED, FAR, SINGULAR, NOT_FINITE = 0, 1, 2, 3
"""Outcomes of :func:`update`."""


@njit(cache=True, error_model="numpy")
def _all_finite(a: np.ndarray) -> bool:
    for v in a.ravel():
        if not math.isfinite(v):
            return False
    return True


@njit(cache=True, error_model="numpy")
def _congruence(F: np.ndarray, P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """``sym(F P F^T + Q)`` (``sym(a) = (a + a^T) / 2``)."""
    n = P.shape[0]
    FP = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            f = F[i, k]
            for j in range(n):
                FP[i, j] += f * P[k, j]
    M = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += FP[i, k] * F[j, k]
            M[i, j] = s + Q[i, j]
    return _symmetric(M)


@njit(cache=True, error_model="numpy")
def _symmetric(M: np.ndarray) -> np.ndarray:
    n = M.shape[0]
    out = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.5 * (M[i, j] + M[j, i])
    return out


@njit(cache=True, error_model="numpy")
def propagate(F: np.ndarray, Q: np.ndarray, reference: np.ndarray, free: np.ndarray, data: np.ndarray):
    """Both recursions over one transition: ``(ok, sym(F free F^T + Q), sym(F data F^T + Q))``; ``ok`` False
    (and the inputs returned) when ``F``, ``Q`` or the new ``reference`` is not finite."""
    if not (_all_finite(F) and _all_finite(Q) and _all_finite(reference)):
        return False, free, data
    return True, _congruence(F, free, Q), _congruence(F, data, Q)


@njit(cache=True, error_model="numpy")
def _solve(A: np.ndarray, B: np.ndarray):
    """``(ok, A^-1 B)`` for ``A`` ``(m, m)``, ``B`` ``(m, k)`` by Gaussian elimination with partial
    pivoting (LAPACK's ``gesv``); ``ok`` False when a pivot is exactly zero (where ``gesv`` fails)."""
    m, k = B.shape
    LU = A.copy()
    X = B.copy()
    for j in range(m):
        p = j
        big = abs(LU[j, j])
        for i in range(j + 1, m):
            if abs(LU[i, j]) > big:
                big, p = abs(LU[i, j]), i
        if LU[p, j] == 0.0:
            return False, X
        if p != j:
            for c in range(m):
                LU[j, c], LU[p, c] = LU[p, c], LU[j, c]
            for c in range(k):
                X[j, c], X[p, c] = X[p, c], X[j, c]
        pivot = LU[j, j]
        for i in range(j + 1, m):
            f = LU[i, j] / pivot
            if f != 0.0:
                for c in range(j + 1, m):
                    LU[i, c] -= f * LU[j, c]
                for c in range(k):
                    X[i, c] -= f * X[j, c]
    for j in range(m - 1, -1, -1):
        for c in range(k):
            s = X[j, c]
            for i in range(j + 1, m):
                s -= LU[j, i] * X[i, c]
            X[j, c] = s / LU[j, j]
    return True, X


@njit(cache=True, error_model="numpy")
def update(H: np.ndarray, R: np.ndarray, r: np.ndarray, free: np.ndarray, data: np.ndarray, far: float):
    """The information of one measurement (Jacobian ``H`` ``(m, n)``, noise ``R`` ``(m, m)``, residual
    ``r`` ``(m,)``) added to ``data``: ``(outcome, new data)``.

    With ``far`` > 0 first: :data:`NOT_FINITE` when ``H`` or ``r`` is not finite, :data:`FAR` when
    ``r^T (H free H^T + R)^-1 r`` is not at most ``far`` (NaN, or a singular spread, included); the caller
    then moves the reference and calls again with ``far`` 0, which skips both tests. Then the Joseph form
    ``A data A^T + K R K^T`` (``A = I - K H``, ``K = data H^T S^-1``, ``S = H data H^T + R``), symmetrised:
    :data:`UPDATED`, or :data:`SINGULAR` (and ``data`` returned) when ``S`` is singular."""
    m, n = H.shape
    if far > 0.0:
        if not (_all_finite(H) and _all_finite(r)):
            return NOT_FINITE, data
        HP = np.zeros((m, n))
        for a in range(m):
            for k in range(n):
                h = H[a, k]
                for j in range(n):
                    HP[a, j] += h * free[k, j]
        spread = np.empty((m, m))
        for a in range(m):
            for b in range(m):
                s = 0.0
                for k in range(n):
                    s += HP[a, k] * H[b, k]
                spread[a, b] = s + R[a, b]
        ok, z = _solve(spread, r.copy().reshape((m, 1)))
        if not ok:
            return FAR, data
        distance = 0.0
        for a in range(m):
            distance += r[a] * z[a, 0]
        if not distance <= far:  # NaN: far
            return FAR, data
    PHt = np.zeros((n, m))
    for i in range(n):
        for k in range(n):
            p = data[i, k]
            for a in range(m):
                PHt[i, a] += p * H[a, k]
    S = np.empty((m, m))
    for a in range(m):
        for b in range(m):
            s = 0.0
            for k in range(n):
                s += H[a, k] * PHt[k, b]
            S[a, b] = s + R[a, b]
    ok, Kt = _solve(S, PHt.T.copy())  # K^T (m, n)
    if not ok:
        return SINGULAR, data
    A = np.zeros((n, n))
    for i in range(n):
        A[i, i] = 1.0
        for j in range(n):
            s = 0.0
            for a in range(m):
                s += Kt[a, i] * H[a, j]
            A[i, j] -= s
    AP = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            f = A[i, k]
            for j in range(n):
                AP[i, j] += f * data[k, j]
    KR = np.zeros((n, m))
    for i in range(n):
        for a in range(m):
            f = Kt[a, i]
            for b in range(m):
                KR[i, b] += f * R[a, b]
    M = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += AP[i, k] * A[j, k]
            t = 0.0
            for b in range(m):
                t += KR[i, b] * Kt[b, j]
            M[i, j] = s + t
    return UPDATED, _symmetric(M)


@njit(cache=True, error_model="numpy")
def replay(prior: np.ndarray, predicted: np.ndarray, F: np.ndarray, Q: np.ndarray, reference: np.ndarray,
           H: np.ndarray, R: np.ndarray, rows: np.ndarray):
    """Both recursions from ``prior`` ``(n, n)`` through a log of ``E`` entries in order: ``(free, data)``.

    Entry ``e`` is a prediction when ``predicted[e]`` (``(E,)`` bool), taking the next of ``F``, ``Q``
    ``(K, n, n)`` and the new ``reference`` ``(K, n)`` (:func:`propagate`, skipped when it refuses), or an
    update, taking the next of ``H`` ``(M, r, n)`` and ``R`` ``(M, r, r)``, of which its first ``rows[j]``
    are used (:func:`update` with no residual; skipped where ``S`` is singular): the calls the tracker made
    one at a time, in one loop."""
    free, data = prior, prior.copy()
    k = j = 0
    empty = np.zeros(0)
    for e in range(predicted.size):
        if predicted[e]:
            ok, free, data = propagate(F[k], Q[k], reference[k], free, data)
            k += 1
        else:
            m = rows[j]
            outcome, updated = update(H[j, :m].copy(), R[j, :m, :m].copy(), empty, free, data, 0.0)
            if outcome == UPDATED:
                data = updated
            j += 1
    return free, data


@njit(cache=True, error_model="numpy")
def _cholesky(S: np.ndarray):
    """``(ok, lower factor)``; ``ok`` False where LAPACK's ``potrf`` fails (a pivot not positive, or NaN)."""
    n = S.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        s = S[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False, L
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            t = S[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / d
    return True, L


@njit(cache=True, error_model="numpy")
def report(free: np.ndarray, data: np.ndarray):
    """The report's numbers: ``(ok, s, information (n,), vectors (n, n))``, ``s`` the no-data standard
    deviations (floored at 1e-150), the information smallest first and each direction ``d_i = L u_i`` in
    state units with unit length in the scaled ones; ``ok`` False when a Cholesky factor fails or a result
    is not finite.

    With ``L`` and ``C`` the Cholesky factors of ``free`` and ``data`` scaled by ``s``, the singular values
    of ``A = C^-1 L`` are ``sqrt(1 + information)`` and ``u_i`` its right singular vectors (LAPACK's
    ``gesdd``, as numpy's ``svd``)."""
    n = free.shape[0]
    s = np.empty(n)
    for i in range(n):
        s[i] = math.sqrt(max(free[i, i], 1e-300))
    free_s = np.empty((n, n))
    data_s = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            scale = s[i] * s[j]
            free_s[i, j] = free[i, j] / scale
            data_s[i, j] = data[i, j] / scale
    information = np.empty(n)
    vectors = np.empty((n, n))
    ok, L = _cholesky(free_s)
    if ok:
        ok, C = _cholesky(data_s)
    if not ok:
        return False, s, information, vectors
    A = L.copy()  # C^-1 L by forward substitution (C lower triangular)
    for i in range(n):
        d = C[i, i]
        for c in range(n):
            t = A[i, c]
            for k in range(i):
                t -= C[i, k] * A[k, c]
            A[i, c] = t / d
    if not _all_finite(A):  # (LAPACK refuses it)
        return False, s, information, vectors
    _, sv, vt = np.linalg.svd(A)
    for i in range(n):
        src = n - 1 - i
        information[i] = max(sv[src] ** 2 - 1.0, 0.0)
        for j in range(n):
            t = 0.0
            for k in range(n):
                t += vt[src, k] * L[j, k]
            vectors[i, j] = t * s[j]
        norm = 0.0
        for j in range(n):
            scaled = vectors[i, j] / s[j]
            norm += scaled * scaled
        norm = math.sqrt(norm)
        for j in range(n):
            vectors[i, j] /= norm
    ok = _all_finite(information) and _all_finite(vectors)
    return ok, s, information, vectors


@njit(cache=True, error_model="numpy")
def orthonormal(a: np.ndarray) -> np.ndarray:
    """An orthonormal basis ``(n, d)`` of the independent columns of ``a`` (LAPACK's QR, as numpy's)."""
    q, _ = np.linalg.qr(a)
    return q
