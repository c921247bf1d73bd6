"""N. Chopin's ``particles`` library as a filter of the bench: its bootstrap filter on one of our models.

``particles`` runs a state-space model as an iterator over its data; :class:`ParticlesBootstrap` gives it
the filters' ``initialize`` / ``predict`` / ``update`` so that ``gpf-nav bench`` times it beside ours on
the same lunar model (our transition, process noise and measurement functions, systematic resampling
below ESS N / 2, as our bootstrap PF). It draws from numpy's global stream (``particles``' own choice),
seeded at :meth:`~ParticlesBootstrap.initialize`. Its likelihood is the plain Gaussian of
``y - h(x)``: angles are not wrapped (the descent's azimuth and elevation stay far from +-pi).
"""
from __future__ import annotations

import importlib.util

import numpy as np

from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.models.state_space import StateSpaceModel


def available() -> bool:
    """Whether ``particles`` is installed."""
    return importlib.util.find_spec("particles") is not None


class ParticlesBootstrap:
    """``particles.SMC`` on ``Bootstrap`` of ``model``, one ``predict(dt)`` + ``update(y)`` per step of the
    iterator (the step's ``dt`` is the first one predicted; ``particles`` models have one)."""

    def __init__(self, model: StateSpaceModel, n_particles: int = N_PARTICLES, seed: int = 0):
        self.model, self.n_particles, self.seed = model, int(n_particles), int(seed)
        self._data: list[np.ndarray] = []
        self._smc = None
        self._dt = None

    def initialize(self, mean, cov, t0: float = 0.0) -> None:
        self._prior = (np.asarray(mean, dtype=float), np.asarray(cov, dtype=float))
        self._data, self._smc, self._dt = [], None, None

    def predict(self, dt: float, u=None) -> None:
        if self._dt is None:
            self._dt = float(dt)

    def update(self, y, sensor=None) -> None:
        if self._smc is None:
            self._smc = self._build()
        self._data.append(np.asarray(y, dtype=float))
        next(self._smc)

    @property
    def mean(self) -> np.ndarray:
        return np.average(self._smc.X, axis=0, weights=self._smc.W)

    @property
    def covariance(self) -> np.ndarray:
        """Weighted covariance ``(n, n)`` of the cloud."""
        return np.cov(self._smc.X, rowvar=False, aweights=self._smc.W, bias=True)

    @property
    def observability(self) -> None:
        """None: the library keeps no observability report (``gpf-nav bench --reports`` reads it)."""
        return None

    def _build(self):
        import particles
        from particles import distributions as dists
        from particles import state_space_models as ssm

        model, dt, (mean, cov) = self.model, self._dt, self._prior
        Q, R = model.process_noise(dt), model.measurement_noise()

        class Model(ssm.StateSpaceModel):
            def PX0(self):
                return dists.MvNormal(loc=mean, cov=cov)

            def PX(self, t, xp):
                return dists.MvNormal(loc=model.transition(xp, dt, t * dt), cov=Q)

            def PY(self, t, xp, x):
                return dists.MvNormal(loc=model.measure(x), cov=R)

        class Bootstrap(ssm.Bootstrap):
            def M0(self, N):  # the first measurement comes one step after the prior, as ours
                return self.ssm.PX(0, super().M0(N)).rvs(size=N)

        np.random.seed(self.seed)
        return particles.SMC(fk=Bootstrap(ssm=Model(), data=self._data), N=self.n_particles,
                             resampling="systematic", ESSrmin=0.5, collect=None)
