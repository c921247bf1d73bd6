"""The Geometric Projection Particle Filter (paper Algorithm 1, projection written consistently).

The SMC loop of :class:`~gpf_nav.filters.particle.ParticleFilter` (Algorithm 1's steps, in
:meth:`~gpf_nav.filters.particle.ParticleFilter._assimilate`) with a projection proposal. Each update
moves the predicted particles ``x^-`` towards the measurement-consistent subspace,

    x = x^- + M H^T (H M H^T + eps R)^-1 r + noise,

with ``r = y - h(x^-)`` (angles wrapped), then weights them. ``metric`` chooses ``M``:

* ``"cloud"`` (default, the navigation-grade configuration;
  :class:`~gpf_nav.filters.cloud_proposal.CloudProposal`): ``M = D``, the covariance of the predicted
  cloud read as a moment-preserving kernel mixture (:mod:`gpf_nav.filters.kernel`) plus ``Q(dt)``, with
  ``eps = 1``: the linearised locally optimal proposal of the smoothed prediction, with exact weights,
  so the cloud's covariance means what it says. ``linearization="flattened"``
  (:class:`~gpf_nav.filters.cloud_proposal.FlattenedProposal`) runs it in coordinates where the
  measurement is linear. The model is augmented with an estimated unmodelled acceleration
  (:class:`ModelErrorCompensation`) unless ``unmodelled_acceleration_std = 0``: the co-state drives its
  correction.
* ``"euclidean"`` (the paper; :class:`~gpf_nav.filters.paper_proposal.ProjectionProposal`): ``M = I``,
  ``H^T (H H^T + eps I)^-1`` with ``H`` and ``r`` whitened and ``eps`` relative, noise ``L z``
  (``Q = L L^T``) added. It moves position only.
* ``"process_noise"`` (:class:`~gpf_nav.filters.paper_proposal.ProjectionProposal`): ``M = Q(dt)``; with
  ``eps = 1`` the mean of the locally optimal proposal of the nominal model (noise still ``L z``).

Options of the paper's configurations: ``reference="increment"`` uses
``r = (y_k - y_{k-1}) - eta(x^-) dt`` with ``eta = H f(x^-)``, the increment as printed in Algorithm 1 (no
projection on the first update, or for a component not measured last time); ``weighting="likelihood"``
multiplies the weights by ``p(y | x)`` only, as in the paper's experiments (not exact: the posterior is
biased by the proposal); ``weighting="corrected"`` also by ``p(x | x_prev) / q(x | x_prev, y)``. For the
Euclidean and process-noise metrics that needs ``Q(dt)`` positive definite; where it is not
(``dt = 0``, a noise-free model), the update does not project.

The geometric co-state ``lambda = (H_w M_w H_w^T + eps I)^-1 W r / dt`` is kept per particle (whitened
measurement units per second).
"""
from __future__ import annotations

import math

import numpy as np

from gpf_nav.filters.cloud_proposal import CloudProposal, FlattenedProposal
from gpf_nav.filters.compensated import (UNMODELLED_ACCELERATION_STD, UNMODELLED_ACCELERATION_TIME,
                                         ModelErrorCompensated)
from gpf_nav.filters.gating import OUTLIER_GATE, OUTLIER_GATE_LIMIT, InnovationGated
from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.filters.kernel import default_bandwidth
from gpf_nav.filters.model_averaging import NOMINAL_PRIOR
from gpf_nav.filters.paper_proposal import ProjectionProposal
from gpf_nav.filters.particle import ParticleFilter
from gpf_nav.models.state_space import StateSpaceModel

REFERENCES = ("innovation", "increment")
METRICS = ("cloud", "euclidean", "process_noise")
WEIGHTINGS = ("corrected", "likelihood")
LINEARIZATIONS = ("mean", "flattened")
DEFAULT_REGULARIZATION = {"cloud": 1.0, "euclidean": 1e-6, "process_noise": 1e-6}
"""Tikhonov ``eps`` of each metric when none is given (1: the measurement noise itself, for ``cloud``)."""
OBSERVABILITY_CONSTRAINT = 1e-3
"""Cloud metric: default ``observability_constraint`` (:class:`~gpf_nav.filters.particle.ParticleFilter`):
the update keeps the prediction along directions the data carried less information about than this
fraction of the prior's."""
TEMPERING_ESS = 0.1
"""Cloud metric: default ``tempering_ess`` (:class:`~gpf_nav.filters.particle.ParticleFilter`): an update
that would leave fewer than this fraction of effective particles is tempered."""


class GeometricProjectionPF(ModelErrorCompensated, InnovationGated, ParticleFilter):
    """GPF: the SMC loop with the geometric projection proposal.

    ``GeometricProjectionPF(model)`` is the navigation-grade configuration (cloud metric, exact weights,
    unmodelled-acceleration compensation). The paper's filter is
    ``GeometricProjectionPF(model, metric="euclidean", weighting="likelihood", unmodelled_acceleration_std=0)``.
    The default estimator is not this class but :class:`~gpf_nav.filters.multiple_model.MultipleModelGPF`
    (``make_filter("gpf", model)``: a nominal member and compensated members of this class): alone, the
    compensated filter can invent an unobservable acceleration and diverge, e.g. with range only
    (docs/filters.md, *Robust by construction*).

    With compensation on, the filter runs on ``ModelErrorCompensation(model)``: :attr:`model` is that
    augmented model, :attr:`particles` are augmented ``(N, n + p)``, but :meth:`initialize` takes the
    user's prior (``(n,)``; an augmented ``(n + p,)`` prior is accepted too) and :attr:`mean` /
    :attr:`covariance` are those of the user's state; :attr:`unmodelled_acceleration` and its covariance
    give the estimated extra acceleration.

    Args:
        model: the state-space model.
        n_particles: number of particles N.
        reference: ``innovation`` (default) or ``increment`` (Algorithm 1 as printed; not with ``cloud``).
        weighting: ``corrected`` (default, exact) or ``likelihood`` (the paper's experiments).
        metric: ``cloud`` (default), ``euclidean`` (the paper) or ``process_noise``.
        regularization: Tikhonov ``eps`` > 0 of the projection (dimensionless; relative for the
            Euclidean metric, in units of the measurement noise otherwise); default per metric,
            :data:`DEFAULT_REGULARIZATION`.
        unmodelled_acceleration_std: stationary std of the estimated unmodelled acceleration (state units
            per s^2); 0 turns the compensation off.
        unmodelled_acceleration_time: its correlation time, s.
        nominal_prior: prior probability that the model needs no unmodelled acceleration; the estimate
            (:attr:`mean`, :attr:`covariance`) is the model average of the two hypotheses
            (:mod:`gpf_nav.filters.model_averaging`); 0 gives the compensated posterior as it is.
        kernel_bandwidth: ``h`` of the cloud metric's kernel in (0, 1); default
            :func:`~gpf_nav.filters.kernel.default_bandwidth`: 1.6 times the Gaussian-optimal one with
            the mean-linearised update; with the flattened one the optimal one, and 1.6 times it while an
            update is tempered or a measured component was beyond the gate in a recent update.
        outlier_gate: cloud metric: a measured component whose innovation is beyond this many standard
            deviations is not used (counted in :attr:`gated`; its co-state is still computed, so the
            integrity monitor sees it); 0 disables the gate.
        outlier_gate_limit: consecutive refusals of a component after which it is used anyway.
        moment_matching: cloud metric: give the weighted cloud the exact mean and covariance of the
            mixture of proposals after each update (and back after a resampling); False leaves the
            sampled moments (for comparison: docs/filters.md).
        tempering_ess: cloud metric: likelihood tempering below this ESS/N
            (:mod:`gpf_nav.filters.tempering_schedule`; the kernel of the cloud metric moves the
            particles between stages); default :data:`TEMPERING_ESS`, 0 turns it off. The other metrics
            have no move between stages and take 0 only.
        observability_constraint: the update keeps the prediction along the directions the data carried
            less information about than this fraction of the prior's (:class:`ParticleFilter`); default
            :data:`OBSERVABILITY_CONSTRAINT` for the cloud metric, 0 (off) for the others.
        linearization: cloud metric: ``mean`` (default) linearises the measurement once at the cloud's
            mean; ``flattened`` runs the whole update (kernel, projection, weights, moment matching,
            resampling, the observability constraint) in coordinates where the measurement is exactly
            that linearisation, and maps the cloud back after it
            (:class:`~gpf_nav.filters.cloud_proposal.FlattenedProposal`): a measurement curved in the
            state's coordinates (a range about a centre) then no longer narrows the cloud along the
            directions it cannot see.
        flattening_horizon: ``linearization="flattened"``: the flattened coordinates also make the
            measured rows of the state flowed half this time and this time ahead linear (s; 0: the rows
            measured now only), so the kernel's draws also keep what the dynamics will turn the
            measurement into (:mod:`gpf_nav.filters.flattening`). Choose it well inside the time over
            which the dynamics stay near their linearisation across the cloud (the navigation default,
            :data:`gpf_nav.registry.NAVIGATION_GPF`, takes 100 s for the lunar descent).
        resampling: resampling scheme name.
        ess_threshold: tau in (0, 1].
        seed: seed of the filter's random generator.
        collapse_steps: see :class:`ParticleFilter`.
    """

    def __init__(self, model: StateSpaceModel, n_particles: int = N_PARTICLES, reference: str = "innovation",
                 weighting: str = "corrected", metric: str = "cloud", regularization: float | None = None,
                 unmodelled_acceleration_std: float = UNMODELLED_ACCELERATION_STD,
                 unmodelled_acceleration_time: float = UNMODELLED_ACCELERATION_TIME,
                 nominal_prior: float = NOMINAL_PRIOR, kernel_bandwidth: float | None = None,
                 outlier_gate: float = OUTLIER_GATE,
                 outlier_gate_limit: int = OUTLIER_GATE_LIMIT, moment_matching: bool = True,
                 resampling: str = "systematic",
                 ess_threshold: float = 0.5, seed: int | np.random.Generator | None = None,
                 collapse_steps: int = 0, tempering_ess: float | None = None,
                 observability_constraint: float | None = None, linearization: str = "mean",
                 flattening_horizon: float = 0.0):
        if reference not in REFERENCES:
            raise ValueError(f"reference must be one of {REFERENCES}, got {reference!r}")
        if weighting not in WEIGHTINGS:
            raise ValueError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
        if metric not in METRICS:
            raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
        if linearization not in LINEARIZATIONS:
            raise ValueError(f"linearization must be one of {LINEARIZATIONS}, got {linearization!r}")
        if not (math.isfinite(flattening_horizon) and flattening_horizon >= 0.0):
            raise ValueError(f"flattening_horizon must be a finite time >= 0, got {flattening_horizon}")
        if metric == "cloud" and reference == "increment":
            raise ValueError("reference='increment' needs metric 'euclidean' or 'process_noise'")
        if regularization is None:
            regularization = DEFAULT_REGULARIZATION[metric]
        if not float(regularization) > 0.0:
            raise ValueError(f"regularization must be positive, got {regularization}")
        if tempering_ess is None:
            tempering_ess = TEMPERING_ESS if metric == "cloud" else 0.0
        elif tempering_ess and metric != "cloud":
            raise ValueError(f"tempering_ess needs metric 'cloud' (its kernel moves the particles between "
                             f"stages), got {tempering_ess} with metric {metric!r}")
        if kernel_bandwidth is not None and not 0.0 < float(kernel_bandwidth) < 1.0:
            raise ValueError(f"kernel_bandwidth must lie in (0, 1), got {kernel_bandwidth}")
        model = self._compensate(model, unmodelled_acceleration_std, unmodelled_acceleration_time, nominal_prior)
        if observability_constraint is None:
            observability_constraint = OBSERVABILITY_CONSTRAINT if metric == "cloud" else 0.0
        super().__init__(model, n_particles, resampling, ess_threshold, seed, collapse_steps, tempering_ess,
                         observability_constraint)
        self.reference = reference
        self.weighting = weighting
        self.metric = metric
        self.regularization = float(regularization)
        flattened = metric == "cloud" and linearization == "flattened"
        self.kernel_bandwidth = (default_bandwidth(self.n_particles, model.state_dim, flattened)
                                 if kernel_bandwidth is None else float(kernel_bandwidth))
        self.moment_matching = bool(moment_matching)
        self.linearization = linearization
        self.flattening_horizon = float(flattening_horizon)
        if metric == "cloud":
            # the bandwidth while an update is in trouble (tempered, or beyond the gate): the wider kernel
            # lets the projection carry more of a large correction
            troubled = (default_bandwidth(self.n_particles, model.state_dim) if kernel_bandwidth is None
                        else self.kernel_bandwidth)
            options = (self.regularization, self.kernel_bandwidth, troubled, weighting, self.moment_matching)
            self.proposal = (FlattenedProposal(*options, self.flattening_horizon) if flattened
                             else CloudProposal(*options))
        else:
            self.proposal = ProjectionProposal(metric, self.regularization, reference, weighting)
        self._init_gate(outlier_gate, outlier_gate_limit)  # (gating.py)
