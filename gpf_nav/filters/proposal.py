"""The proposal of a particle filter: how the predicted cloud is moved towards a measurement.

A particle filter here differs from another only in its proposal ``q(x_k | x_k^-, y_k)``. A
:class:`Proposal` takes the predicted particles ``x^-`` (the drift of :meth:`ParticleFilter.predict
<gpf_nav.filters.particle.ParticleFilter.predict>`) and one :class:`Stage` of an update, and returns a
:class:`Move`: the moved particles, the log-weight correction ``log p(x | x^-) - log q(x | x^-, y)`` that
the exact weights need, the co-state it computed and the measured rows the weights use. The filter's
update (:meth:`ParticleFilter._assimilate <gpf_nav.filters.particle.ParticleFilter._assimilate>`) does
the rest: weights, normalisation, ESS, resampling.

The proposals:

* :class:`PriorProposal` (this module): the prior transition, ``x = x^- + L z`` (the bootstrap filter).
* :class:`~gpf_nav.filters.paper_proposal.ProjectionProposal`: the paper's projection of each particle onto
  the measurement-consistent subspace (Euclidean or process-noise metric).
* :class:`~gpf_nav.filters.cloud_proposal.CloudProposal`: the projection in the metric of the
  kernel-smoothed predicted cloud, and :class:`~gpf_nav.filters.cloud_proposal.FlattenedProposal`, the
  same in coordinates where the measurement is linear.

A new proposal is one subclass of :class:`Proposal` with a :meth:`~Proposal.draw`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gpf_nav.filters.flattening import Flattening
from gpf_nav.filters.projection import innovation, project

if TYPE_CHECKING:
    from gpf_nav.filters.kernel import ProposalMixture
    from gpf_nav.filters.particle import ParticleFilter


@dataclass(frozen=True)
class Stage:
    """One draw of an update, as the proposal sees it.

    Attributes:
        x: the predicted particles ``x^-`` ``(n, N)`` (the filter's cloud; not to be written).
        y: the measurement ``(m,)``.
        rows: ``(m,)`` bool, the measured components.
        dt: the interval whose process noise this draw adds, s (0 in a later tempering stage).
        fraction: the part ``f`` of the log-likelihood this stage weights by (``p(y | x)^f``; 1 untempered).
        first: the update's first draw (the one that gates outliers and sets the co-state).
        flat: the update's flattened coordinates (:meth:`Proposal.flatten`), or None.
    """

    x: np.ndarray
    y: np.ndarray
    rows: np.ndarray
    dt: float
    fraction: float
    first: bool
    flat: Flattening | None = None


@dataclass(frozen=True)
class Move:
    """What a proposal returns.

    Attributes:
        particles: the moved particles ``x`` ``(n, N)``, a new array.
        log_correction: ``log p(x | x^-) - log q(x | x^-, y)`` ``(N,)``, or 0.0 (the prior transition, or
            weights by the likelihood only).
        rows: ``(m,)`` bool, the measured components the weights use (less any refused as outliers).
        costate: the co-state ``lambda = (H_w M H_w^T + eps I)^-1 W r / dt`` of ``costate_rows`` ``(N, k)``
            (whitened measurement units per second), or None when none was computed.
        costate_rows: ``(m,)`` bool, the components of ``costate``.
        mixture: the proposals the particles were drawn from, when the filter should give the weighted
            cloud their exact moments (:class:`~gpf_nav.filters.kernel.ProposalMixture`), or None.
    """

    particles: np.ndarray
    log_correction: np.ndarray | float
    rows: np.ndarray
    costate: np.ndarray | None = None
    costate_rows: np.ndarray | None = None
    mixture: ProposalMixture | None = None


class Proposal:
    """A proposal: :meth:`draw` moves the predicted cloud. The default methods are the prior transition's."""

    def draw(self, pf: ParticleFilter, stage: Stage) -> Move:
        """The particles of ``stage`` moved by this proposal, for the filter ``pf`` (its model, random
        generator, sensor and noise)."""
        raise NotImplementedError

    def flatten(self, pf: ParticleFilter, rows: np.ndarray) -> Flattening | None:
        """Coordinates the whole update runs in (:mod:`gpf_nav.filters.flattening`), moving ``pf``'s cloud
        into them; None (the default): the state's own."""
        return None

    def reset(self) -> None:
        """Forget what earlier updates left (the filter was initialised)."""

    def observed(self, sensor: str, y: np.ndarray, rows: np.ndarray) -> None:
        """An update by ``sensor`` measured ``y`` ``(m,)`` in ``rows`` ``(m,)`` and was not abandoned."""


def prior_draw(pf: ParticleFilter, x: np.ndarray, dt: float
               ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """``(x + L z (n, N), z (n, N), L^-1 (n, n))``: the predicted particles ``x`` ``(n, N)`` with the
    process noise ``L z`` of ``dt`` (``Q(dt) = L L^T``) drawn; ``L^-1`` is None when ``Q`` is not positive
    definite, ``z`` and ``L^-1`` are None and the particles a copy when ``dt`` is 0. The result is a new
    array, so views handed out as :attr:`~gpf_nav.filters.particle.ParticleFilter.particles` keep the
    predicted state."""
    if not dt > 0.0:
        return x.copy(), None, None
    factor, inverse_factor = pf._noise_factors(dt)
    z = pf.normal_draws(pf.model.state_dim, pf.n_particles)
    moved = factor @ z
    moved += x
    return moved, z, inverse_factor


class PriorProposal(Proposal):
    """The prior transition ``x = x^- + L z`` (the bootstrap filter, the paper's SPF): no correction.

    Args:
        costate_regularization: when given, also compute, as a diagnostic only, the co-state the
            Euclidean projection (:func:`~gpf_nav.filters.projection.project`, this relative Tikhonov
            ``eps``) would apply to the predicted particles; None: no co-state.
    """

    def __init__(self, costate_regularization: float | None = None):
        self.costate_regularization = costate_regularization

    def draw(self, pf: ParticleFilter, stage: Stage) -> Move:
        x, _, _ = prior_draw(pf, stage.x, stage.dt)
        costate = None
        if self.costate_regularization is not None and stage.dt > 0.0 and stage.rows.any():
            sensor = pf._sensor
            H, r = innovation(sensor, stage.x.T, stage.y, stage.rows, pf.time)
            a = project(H, r, pf._whitening(stage.rows, stage.fraction)[0], self.costate_regularization,
                        columns=sensor.measured_state_index,
                        orthogonal_rows=sensor.orthogonal_jacobian_rows)[1]
            costate = a / stage.dt
        return Move(x, 0.0, stage.rows, costate, stage.rows)
