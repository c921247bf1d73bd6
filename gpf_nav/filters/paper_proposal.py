"""The paper's proposal: each particle projected onto the measurement-consistent subspace (Algorithm 1).

For a predicted particle ``x^-`` (the drift) the move is Algorithm 1's lines 5 to 9,

    H = dh/dx (x^-),   r = y - h(x^-),   lambda = (H H^T + eps I)^-1 r / dt,
    x = x^- + H^T (H H^T + eps I)^-1 r + L z,

with ``H`` and ``r`` whitened by the measurement noise (:func:`~gpf_nav.filters.projection.project`) and
``L z`` the process noise (``Q(dt) = L L^T``). With the process-noise metric ``M = Q(dt)`` the shift is
``M H^T (H M H^T + eps R)^-1 r``.

``reference="increment"`` uses ``r = (y_k - y_{k-1}) - eta(x^-) dt`` with ``eta = H f(x^-)``, the
increment as printed in Algorithm 1 (no projection on a sensor's first update, or for a component it did
not measure last time). ``weighting="corrected"`` returns the exact weights' correction
``log p(x | x^-) - log q(x | x^-, y)`` (which needs ``Q(dt)`` positive definite: where it is not, the
update does not project); ``"likelihood"`` returns none, as in the paper's experiments.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from gpf_nav.filters.projection import gaussian_shift_correction, innovation, project, select_rows
from gpf_nav.filters.proposal import Move, Proposal, Stage, prior_draw

if TYPE_CHECKING:
    from gpf_nav.filters.particle import ParticleFilter


class ProjectionProposal(Proposal):
    """The geometric projection of every particle, in the Euclidean or the process-noise metric.

    Args:
        metric: ``euclidean`` (the paper: ``M = I``, ``eps`` relative) or ``process_noise``
            (``M = Q(dt)``, ``eps`` in units of the measurement noise).
        regularization: Tikhonov ``eps`` > 0.
        reference: ``innovation`` or ``increment``.
        weighting: ``corrected`` (exact) or ``likelihood``.
    """

    def __init__(self, metric: str, regularization: float, reference: str, weighting: str):
        self.metric = metric
        self.regularization = regularization
        self.reference = reference
        self.weighting = weighting
        self._previous_y: dict[str, np.ndarray] = {}

    def draw(self, pf: ParticleFilter, stage: Stage) -> Move:
        x_pred, y, rows, dt = stage.x, stage.y, stage.rows, stage.dt
        x, z, inverse_factor = prior_draw(pf, x_pred, dt)  # x^- + L z
        sensor = pf._sensor
        projected = rows
        if self.reference == "increment":
            previous_y = self._previous_y.get(sensor.name, np.full(sensor.dim, np.nan))
            projected = rows & np.isfinite(previous_y)
        if dt == 0.0 or not projected.any() or (self.weighting == "corrected" and inverse_factor is None):
            return Move(x, 0.0, rows, None, projected)
        # the Jacobian H at each particle and the reference innovation r
        states = x_pred.T
        if self.reference == "innovation":
            H, r = innovation(sensor, states, y, projected, pf.time)
        else:
            H = select_rows(sensor.jacobian(states, pf.time), projected)
            eta = np.einsum("nkj,nj->nk", H, pf.model.drift(states, pf.time, pf._input))
            r = sensor.residual(y, previous_y)[projected] - eta * dt
        # the projection H^T (H H^T + eps I)^-1 r and a = (H H^T + eps I)^-1 r, the co-state times dt
        metric_factor = pf._noise_factors(dt)[0] if self.metric == "process_noise" else None
        # (weights by the likelihood only need no shift: it goes straight into the particles)
        likelihood = self.weighting == "likelihood"
        shift, a = project(H, r, pf._whitening(projected, stage.fraction)[0], self.regularization,
                           metric_factor, sensor.measured_state_index, sensor.orthogonal_jacobian_rows,
                           out=x if likelihood else None)
        if likelihood:
            return Move(x, 0.0, rows, a / dt, projected)
        x += shift
        return Move(x, gaussian_shift_correction(shift, inverse_factor, z), rows, a / dt, projected)

    def reset(self) -> None:
        self._previous_y = {}

    def observed(self, sensor: str, y: np.ndarray, rows: np.ndarray) -> None:
        if self.reference == "increment":  # the only reader of the previous measurement
            self._previous_y[sensor] = np.where(rows, y, np.nan)
