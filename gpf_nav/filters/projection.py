"""Geometric projection onto the measurement-consistent subspace, batched over particles.

For predicted particles ``x`` and a reference innovation ``r`` the projection is

    shift = H^T (H H^T + eps I)^-1 r,        co-state  lambda = (H H^T + eps I)^-1 r / dt,

with ``H`` and ``r`` first whitened by the measurement noise (``W R W^T = I``), so measurement rows in
metres and radians are commensurate. This is the consistent form of Algorithm 1's projection line
(``H^T lambda dt``).

Two metrics for the state space:

* Euclidean (the paper): ``eps`` is taken relative to the mean eigenvalue of ``H H^T`` (whose units mix
  metres and radians), so it is dimensionless.
* A metric ``M = L L^T`` (e.g. the process noise ``Q(dt)``): ``H`` becomes ``H L`` and the shift
  ``M H^T (H M H^T + eps R)^-1 r`` after un-whitening. ``H M H^T`` is then dimensionless in whitened
  coordinates and ``eps`` is absolute: with ``M = Q`` and ``eps = 1`` the shift is the Kalman-gain mean
  of the locally optimal proposal, while ``eps -> 0`` enforces the measurement exactly.

Also here: the linearisation the projection starts from (:func:`innovation`) and the log-weight
correction of a shifted prior transition (:func:`gaussian_shift_correction`).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from gpf_nav.kernels import diagonal_projection
from gpf_nav.linalg import solve_spd
from gpf_nav.sensors.sensor import Sensor


def innovation(sensor: Sensor, states: np.ndarray, y: np.ndarray, rows: np.ndarray, time: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Jacobian ``H`` ``(N, k, n)`` and innovation ``r = y - h(x)`` ``(N, k)`` (angles wrapped) of the
    measured ``rows`` ``(m,)`` of ``sensor`` at ``time``, for the particles ``states`` ``(N, n)``."""
    h, H = sensor.measure_and_jacobian(states, time)
    return select_rows(H, rows), select_columns(sensor.residual(y, h), rows)


def project(H: np.ndarray, r: np.ndarray, W: np.ndarray, regularization: float,
            metric_factor: np.ndarray | None = None, columns: tuple[int, ...] | None = None,
            orthogonal_rows: bool = False, out: np.ndarray | None = None
            ) -> tuple[np.ndarray | None, np.ndarray]:
    """Projection shift and whitened co-state increment.

    Args:
        H: measurement Jacobian of the measured rows ``(N, k, n)``.
        r: reference innovation of those rows ``(N, k)`` (angles already wrapped).
        W: whitener ``(k, k)`` of the rows' noise covariance, or its diagonal ``(k,)``.
        regularization: Tikhonov ``eps``: relative for the Euclidean metric, absolute otherwise.
        metric_factor: ``L`` ``(n, n)`` of the state metric ``L L^T``; None for the Euclidean metric.
        columns: the state components ``h`` depends on (other columns of ``H`` are zero); None: all.
        orthogonal_rows: the rows of ``H`` are mutually orthogonal (as for range, azimuth and
            elevation); with a diagonal ``W`` and the Euclidean metric ``H H^T`` is then diagonal and
            the solve is a division, one compiled pass over the particles
            (:func:`gpf_nav.kernels.diagonal_projection.orthogonal_projection`).
        out: particles ``(n, N)`` to add the shift to, in place (saves the ``(n, N)`` shift where the
            caller needs only the shifted particles); None: the shift is returned.

    Returns:
        ``shift`` ``(n, N)`` to add to the particles (None when added to ``out``) and
        ``a = (Hw Hw^T + eps I)^-1 W r`` ``(N, k)`` (the co-state times ``dt``, in whitened measurement
        coordinates).
    """
    k = W.shape[0]
    # With a diagonal whitener w, W H = diag(w) H is never formed: w goes into S and into a instead.
    if W.ndim == 1:
        w, diagonal = W, True
    else:
        w = np.diag(W)
        diagonal = np.count_nonzero(W) == np.count_nonzero(w)
    if orthogonal_rows and diagonal and metric_factor is None:
        shifted = np.zeros((H.shape[2], H.shape[0])) if out is None else out
        indices = _column_array(tuple(range(H.shape[2])) if columns is None else tuple(columns))
        a = diagonal_projection.orthogonal_projection(H.transpose(1, 2, 0), indices, r.T,
                                                     np.asarray(w, dtype=float), regularization / k, shifted)
        return (shifted if out is None else None), a.T
    Ht = H.transpose(1, 2, 0)  # (k, n, N)
    if metric_factor is not None:
        Ht = np.einsum("kjn,jc->kcn", Ht, metric_factor)
        columns = None
    columns = _as_index(tuple(range(H.shape[2])) if columns is None else tuple(columns))
    Ht = Ht[:, columns]
    if diagonal:
        Hw, rw = Ht, r.T * w[:, None]
    else:
        Hw, rw = np.einsum("ij,jcn->icn", W, Ht), W @ r.T
    S = np.einsum("icn,jcn->ijn", Hw, Hw)
    if diagonal:
        S *= np.outer(w, w)[:, :, None]
    # relative Tikhonov term; a zero Jacobian (degenerate geometry) gets unit damping and a zero shift
    if metric_factor is None:
        trace = np.einsum("iin->n", S)
        damping = trace * (regularization / k)
        damping[trace <= 0.0] = 1.0
    else:
        damping = np.full(S.shape[2], float(regularization))
    for i in range(k):
        S[i, i] += damping
    a = solve_spd(S, rw)
    a[~np.isfinite(a)] = 0.0
    shift = np.zeros((H.shape[2], H.shape[0]))
    shift[columns] = np.einsum("icn,in->cn", Hw, a * w[:, None] if diagonal else a)
    if metric_factor is not None:
        shift = metric_factor @ shift
    if out is None:
        return shift, a.T
    out += shift
    return None, a.T


@lru_cache(maxsize=64)
def _column_array(columns: tuple[int, ...]) -> np.ndarray:
    """``columns`` as the index array the compiled projection takes."""
    return np.array(columns, dtype=np.int64)


@lru_cache(maxsize=64)
def _as_index(columns: tuple[int, ...]) -> slice | list[int]:
    """A slice (a view, no copy) when ``columns`` are consecutive, else the list of indices."""
    columns = list(columns)
    if columns == list(range(columns[0], columns[-1] + 1)):
        return slice(columns[0], columns[-1] + 1)
    return columns


def select_rows(H: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``H[:, rows, :]`` of a Jacobian ``(N, m, n)`` without a copy when every row is kept; the
    selection runs on the particle-last layout the models build, so it copies contiguous rows."""
    if rows.all():
        return H
    return H.transpose(1, 2, 0)[rows].transpose(2, 0, 1)


def select_columns(r: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``r[:, rows]`` of ``(N, m)`` without a copy when every component is kept."""
    return r if rows.all() else r.T[rows].T


def gaussian_shift_correction(shift: np.ndarray, inverse_factor: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``log p(x|x_prev) - log q(x|x_prev, y)`` for ``q`` the prior transition shifted by ``shift``.

    With ``x = flow + shift + L z`` and ``Q = L L^T``: ``-(L^-1 shift) . z - |L^-1 shift|^2 / 2``.
    ``shift`` and ``z`` are ``(n, N)``, ``inverse_factor`` is ``L^-1`` ``(n, n)``; returns ``(N,)``.
    """
    s = inverse_factor @ shift
    return -np.einsum("ij,ij->j", s, z) - 0.5 * np.einsum("ij,ij->j", s, s)
