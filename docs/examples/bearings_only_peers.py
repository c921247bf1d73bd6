"""The bearings-only example (``bearings_only.py``) through peer libraries, on the same data.

Peers, each skipped when it is not installed (none is a dependency of gpf_nav):

* ``particles`` (N. Chopin): the bootstrap filter (``SMC`` on ``Bootstrap``, systematic resampling
  when ESS < N / 2, as ours);
* ``filterpy``: ``ExtendedKalmanFilter`` and ``UnscentedKalmanFilter`` (Merwe sigma points with the
  parameters of our UKF), both with a wrapped bearing residual and, for the UKF, a circular mean;
* Stone Soup: the extended, unscented and particle (ESS-triggered systematic resampling) filters with
  its ``Cartesian2DToBearing`` measurement model, whose bearings wrap.

Run: ``python docs/examples/bearings_only_peers.py [--runs 100] [--particles 2000]``. Prints the table
of ``bearings_only.py`` for our filters and the peers' (same truth and bearings in every run).
"""
from __future__ import annotations

import argparse
import datetime
import time

import numpy as np

from bearings_only import (BEARING_STD, PRIOR_COV, PRIOR_MEAN, BearingsOnlyModel, Score, filters, report,
                           simulate, track)

MODEL = BearingsOnlyModel()
F = MODEL.transition_jacobian(PRIOR_MEAN[None], 1.0)[0]
Q = MODEL.process_noise(1.0)
R = MODEL.measurement_noise()


def wrap(a):
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def bearing(x):
    """Bearing of states ``(..., 4)``."""
    return np.arctan2(x[..., 2], x[..., 0])


def _timed(step, ys):
    """Run ``step(y) -> (mean (4,), cov (4, 4))`` over ``ys``: estimates, final covariance, time per step.

    A peer that raises (e.g. a Cholesky of a covariance no longer positive definite) has failed: its
    remaining estimates are NaN, which counts as lost."""
    out = np.full((len(ys), 4), np.nan)
    cov = np.full((4, 4), np.nan)
    start = time.perf_counter()
    for k, y in enumerate(ys):
        try:
            out[k], cov = step(y)
        except (np.linalg.LinAlgError, ValueError):
            cov = np.full((4, 4), np.nan)
            break
    return out, cov, (time.perf_counter() - start) / (k + 1)


def particles_bootstrap(ys, n_particles, seed):
    """``particles``' bootstrap filter; ``X_0`` is the prior moved one step (our predict, then update)."""
    import particles
    from particles import distributions as dists
    from particles import state_space_models as ssm

    L = np.linalg.cholesky(Q)

    class Moved(dists.ProbDist):
        """``transition(x) + N(0, Q)`` for states ``x`` ``(N, 4)`` (``rvs`` is all a bootstrap filter needs)."""

        dim = 4

        def __init__(self, xp=None):
            self.xp = xp

        def rvs(self, size=None):
            xp = self.xp if self.xp is not None else \
                PRIOR_MEAN + np.random.standard_normal((size, 4)) @ np.linalg.cholesky(PRIOR_COV).T
            return xp @ F.T + np.random.standard_normal((size, 4)) @ L.T

    class WrappedBearing(dists.ProbDist):
        def __init__(self, loc):
            self.loc = loc

        def logpdf(self, y):
            r = wrap(y - self.loc)
            return -0.5 * (r / BEARING_STD) ** 2 - np.log(BEARING_STD * np.sqrt(2.0 * np.pi))

    class Bearings(ssm.StateSpaceModel):
        def PX0(self):
            return Moved()

        def PX(self, t, xp):
            return Moved(xp)

        def PY(self, t, xp, x):
            return WrappedBearing(bearing(x))

    np.random.seed(seed)
    pf = particles.SMC(fk=ssm.Bootstrap(ssm=Bearings(), data=list(ys[:, 0])), N=n_particles,
                       resampling="systematic", ESSrmin=0.5)
    steps = iter(pf)

    def step(y):
        next(steps)
        mean = pf.W @ pf.X
        d = pf.X - mean
        return mean, (d * pf.W[:, None]).T @ d
    return _timed(step, ys)


def filterpy_ekf(ys, n_particles, seed):
    from filterpy.kalman import ExtendedKalmanFilter

    f = ExtendedKalmanFilter(dim_x=4, dim_z=1)
    f.x, f.P, f.F, f.Q, f.R = PRIOR_MEAN[:, None].copy(), PRIOR_COV.copy(), F, Q, R

    def step(y):
        f.predict()
        f.update(y, lambda x: MODEL.measurement_jacobian(x.T)[0], lambda x: MODEL.measure(x.T),
                 residual=lambda a, b: wrap(a - b))
        return f.x[:, 0], f.P
    return _timed(step, ys)


def filterpy_ukf(ys, n_particles, seed):
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    def circular_mean(sigmas, wm):
        return np.array([np.arctan2(wm @ np.sin(sigmas[:, 0]), wm @ np.cos(sigmas[:, 0]))])

    f = UnscentedKalmanFilter(dim_x=4, dim_z=1, dt=1.0, hx=lambda x: np.array([bearing(x)]),
                              fx=lambda x, dt: F @ x,
                              points=MerweScaledSigmaPoints(4, alpha=1e-3, beta=2.0, kappa=0.0),
                              residual_z=lambda a, b: wrap(a - b), z_mean_fn=circular_mean)
    f.x, f.P, f.Q, f.R = PRIOR_MEAN.copy(), PRIOR_COV.copy(), Q, R

    def step(y):
        f.predict()
        f.update(y)
        return f.x, f.P
    return _timed(step, ys)


def _stonesoup(kind, ys, n_particles, seed):
    from stonesoup.models.measurement.nonlinear import Cartesian2DToBearing
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState, ParticleState, StateVectors

    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(MODEL.accel_std ** 2)] * 2)
    measurement = Cartesian2DToBearing(ndim_state=4, mapping=(0, 2), noise_covar=R)
    t0 = datetime.datetime(2000, 1, 1)
    if kind == "particle":
        from stonesoup.predictor.particle import ParticlePredictor
        from stonesoup.resampler.particle import ESSResampler, SystematicResampler
        from stonesoup.updater.particle import ParticleUpdater
        rng = np.random.default_rng(seed)
        np.random.seed(seed)  # Stone Soup's transition noise and resampling draw from numpy's global stream
        x0 = PRIOR_MEAN + rng.standard_normal((n_particles, 4)) @ np.linalg.cholesky(PRIOR_COV).T
        state = ParticleState(StateVectors(x0.T), weight=np.full(n_particles, 1.0 / n_particles), timestamp=t0)
        predictor = ParticlePredictor(transition)
        updater = ParticleUpdater(measurement, resampler=ESSResampler(n_particles / 2, SystematicResampler()))
    else:
        from stonesoup.predictor.kalman import ExtendedKalmanPredictor, UnscentedKalmanPredictor
        from stonesoup.updater.kalman import ExtendedKalmanUpdater, UnscentedKalmanUpdater
        state = GaussianState(PRIOR_MEAN[:, None], PRIOR_COV, timestamp=t0)
        if kind == "extended":
            predictor, updater = ExtendedKalmanPredictor(transition), ExtendedKalmanUpdater(measurement)
        else:
            sigma = {"alpha": 1e-3, "beta": 2.0, "kappa": 0.0}
            predictor = UnscentedKalmanPredictor(transition, **sigma)
            updater = UnscentedKalmanUpdater(measurement, **sigma)
    clock = iter(range(1, len(ys) + 1))

    def step(y):
        nonlocal state
        when = t0 + datetime.timedelta(seconds=next(clock))
        prediction = predictor.predict(state, timestamp=when)
        state = updater.update(SingleHypothesis(prediction, Detection(y[:, None], when, measurement)))
        return np.asarray(state.mean, dtype=float)[:, 0], np.asarray(state.covar, dtype=float)
    return _timed(step, ys)


PEERS = {
    "particles: bootstrap": ("particles", particles_bootstrap),
    "filterpy: EKF": ("filterpy", filterpy_ekf),
    "filterpy: UKF": ("filterpy", filterpy_ukf),
    "Stone Soup: EKF": ("stonesoup", lambda *a: _stonesoup("extended", *a)),
    "Stone Soup: UKF": ("stonesoup", lambda *a: _stonesoup("unscented", *a)),
    "Stone Soup: particle": ("stonesoup", lambda *a: _stonesoup("particle", *a)),
}


def available(module: str) -> bool:
    try:
        __import__(module)
    except ImportError:
        return False
    return True


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--particles", type=int, default=2000)
    parser.add_argument("--skip", nargs="*", default=[], help="peer names to leave out (substring)")
    args = parser.parse_args(argv)
    peers = {name: run for name, (module, run) in PEERS.items()
             if available(module) and not any(s in name for s in args.skip)}
    skipped = sorted(set(PEERS) - set(peers))
    scores: dict[str, Score] = {}
    for run in range(args.runs):
        truth, ys = simulate(np.random.default_rng(run))
        for name, f in filters(args.particles, seed=1000 + run).items():
            scores.setdefault(name, Score()).add(*_unpack(track(f, ys), truth))
        for name, peer in peers.items():
            scores.setdefault(name, Score()).add(*_unpack(peer(ys, args.particles, 1000 + run), truth))
    if skipped:
        print("skipped (not installed or --skip):", ", ".join(skipped))
    return report(f"bearings-only tracking, {args.runs} runs, N = {args.particles}, ours and peers", scores)


def _unpack(result, truth):
    estimates, final_cov, step_time = result
    return estimates, final_cov, truth[1:], step_time


if __name__ == "__main__":
    main()
