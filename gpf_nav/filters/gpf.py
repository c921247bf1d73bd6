"""The Geometric Projection Particle Filter (paper Algorithm 1, projection written consistently).

Each update moves the predicted particles ``x^-`` onto the measurement-consistent subspace,

    x = x^- + H^T (H H^T + eps I)^-1 r + L z,      Q(dt) = L L^T,  z ~ N(0, I),

then weights them. Options:

* ``reference="innovation"``: ``r = y - h(x^-)`` (angles wrapped); ``reference="increment"``:
  ``r = (y_k - y_{k-1}) - eta(x^-) dt`` with ``eta = H f(x^-)``, the measurement increment as printed
  in Algorithm 1 (no projection on the first update, or for a component not measured last time).
* ``weighting="likelihood"``: ``w *= p(y | x)``, as in the paper's experiments (not exact: the posterior
  is biased by the proposal); ``weighting="corrected"``: also ``* p(x | x_prev) / q(x | x_prev, y)``,
  which for this Gaussian-shift proposal is ``exp(-s.z - |s|^2/2)`` with ``s = L^-1 shift``; the
  posterior is then exact as N grows. It needs ``Q(dt)`` positive definite; where it is not (``dt = 0``,
  a noise-free model), the update does not project.

* ``metric="euclidean"`` (the paper: ``H^T (H H^T + eps I)^-1``, ``eps`` relative) or
  ``metric="process_noise"``: the projection in the metric of ``Q(dt)``,
  ``Q H^T (H Q H^T + eps R)^-1`` (``eps`` absolute), which moves velocity with position the way the
  process noise correlates them. With ``eps = 1`` it is the mean of the locally optimal proposal, which
  keeps the ``corrected`` weights well spread; the Euclidean full projection shifts position alone and
  its exact weights degenerate quickly (see docs/filters.md).

The geometric co-state ``lambda = (H H^T + eps I)^-1 r / dt`` is kept per particle (whitened units).
"""
from __future__ import annotations

import numpy as np

from gpf_nav.filters.particle import ParticleFilter, gaussian_shift_correction, select_rows
from gpf_nav.filters.projection import project
from gpf_nav.models.base import StateSpaceModel

REFERENCES = ("innovation", "increment")
METRICS = ("euclidean", "process_noise")
WEIGHTINGS = ("likelihood", "corrected")


class GeometricProjectionPF(ParticleFilter):
    """GPF: the SMC loop with the geometric projection proposal.

    Args:
        model: the state-space model.
        n_particles: number of particles N.
        reference: ``innovation`` (default) or ``increment`` (Algorithm 1 as printed).
        weighting: ``likelihood`` (default, the paper's experiments) or ``corrected`` (exact).
        metric: ``euclidean`` (default, the paper) or ``process_noise``.
        regularization: Tikhonov ``eps`` > 0 of the projection (dimensionless; relative for the
            Euclidean metric, in units of the measurement noise for ``process_noise``).
        resampling: resampling scheme name.
        ess_threshold: tau in (0, 1].
        seed: seed of the filter's random generator.
        collapse_steps: see :class:`ParticleFilter`.
    """

    def __init__(self, model: StateSpaceModel, n_particles: int = 500, reference: str = "innovation",
                 weighting: str = "likelihood", metric: str = "euclidean", regularization: float = 1e-6,
                 resampling: str = "systematic", ess_threshold: float = 0.5,
                 seed: int | np.random.Generator | None = None, collapse_steps: int = 0):
        super().__init__(model, n_particles, resampling, ess_threshold, seed, collapse_steps)
        if reference not in REFERENCES:
            raise ValueError(f"reference must be one of {REFERENCES}, got {reference!r}")
        if weighting not in WEIGHTINGS:
            raise ValueError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
        if metric not in METRICS:
            raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
        if not float(regularization) > 0.0:
            raise ValueError(f"regularization must be positive, got {regularization}")
        self.reference = reference
        self.weighting = weighting
        self.metric = metric
        self.regularization = float(regularization)
        self._previous_y = np.full(model.measurement_dim, np.nan)
        self._input = None

    def predict(self, dt, u=None):
        super().predict(dt, u)
        self._input = u

    def _propose(self, x_pred, y, rows, dt, inverse_factor, z):
        if self.reference == "increment":
            rows = rows & np.isfinite(self._previous_y)
        if dt == 0.0 or not rows.any() or (self.weighting == "corrected" and inverse_factor is None):
            self._set_costate(None, rows, dt)
            return None, 0.0
        states = x_pred.T
        if self.reference == "innovation":
            H, r = self._innovation(states, y, rows)
        else:
            H = select_rows(self.model.measurement_jacobian(states), rows)
            eta = np.einsum("nkj,nj->nk", H, self.model.drift(states, self.time, self._input))
            r = self.model.residual(y, self._previous_y)[rows] - eta * dt
        metric_factor = self._noise_factors(dt)[0] if self.metric == "process_noise" else None
        shift, a = project(H, r, self._whitener(rows), self.regularization, metric_factor,
                           self.model.measured_state_index, self.model.orthogonal_jacobian_rows)
        self._set_costate(a, rows, dt)
        if self.weighting == "likelihood":
            return shift, 0.0
        return shift, gaussian_shift_correction(shift, inverse_factor, z)

    def _after_update(self, y, rows):
        self._previous_y = np.where(rows, y, np.nan)

    def initialize(self, mean, cov):
        super().initialize(mean, cov)
        self._previous_y = np.full(self.model.measurement_dim, np.nan)
