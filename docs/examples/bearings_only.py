"""A user model run on every filter: bearings-only tracking (Gordon, Salmond & Smith 1993, Section 5).

A target moves in the plane with nearly constant velocity; an observer at the origin measures only its
bearing. State ``(x, vx, y, vy)`` (dimensionless units of the paper, one time unit per step),
measurement ``arctan2(y, x)`` with noise ``N(0, 0.005^2)``, an angle (``angular = [True]``: residuals are
wrapped to (-pi, pi]). The paper's acceleration noise acts per step (``Gamma w_k``, a rank-2 ``Q``);
here it is the continuous-time white-noise acceleration of the same intensity per time unit (standard
deviation 0.001 per axis), whose ``Q(dt)`` is positive definite, so the GPF's corrected weighting can
project. Prior and true start are the paper's.

Run it: ``python docs/examples/bearings_only.py [--runs 100] [--particles 2000]``. It prints, per
filter, the position RMSE over all steps and runs, the runs in which the filter lost the target (final
position error above ``LOST_DISTANCE``), the runs in which it was overconfident (the truth outside
its own 99.9 % position ellipse at the end) and the time per step. ``bearings_only_peers.py`` runs the
same data through other libraries.

With a fixed observer the range is not observable from bearings alone (a scaled trajectory gives the
same bearings), so the posterior stays broad along the line of sight and errors against the truth
are large for every filter; "lost" flags a final error beyond the prior's own position spread.
"""
from __future__ import annotations

import argparse
import functools
import time

import numpy as np

from gpf_nav.filters import BootstrapPF, ExtendedKF, EnsembleKF, GeometricProjectionPF, UnscentedKF
from gpf_nav.models import StateSpaceModel

ACCEL_STD = 0.001
BEARING_STD = 0.005
STEPS = 24
TRUE_START = np.array([-0.05, 0.001, 0.7, -0.055])
PRIOR_MEAN = np.array([0.0, 0.0, 0.4, -0.05])
PRIOR_COV = np.diag([0.5, 0.005, 0.3, 0.01]) ** 2
LOST_DISTANCE = 0.5
"""A run is lost when the final position estimate is further than this from the truth: the prior's
position standard deviation (0.3 to 0.5), about nine steps of the target's motion."""
OVERCONFIDENT_NEES = 13.82
"""99.9 % quantile of chi-square with 2 degrees of freedom: a final position NEES above it means the
truth lies outside the filter's own 99.9 % ellipse."""


class BearingsOnlyModel(StateSpaceModel):
    """Nearly constant velocity in the plane, bearing from the origin."""

    state_dim = 4
    measurement_dim = 1
    angular = np.array([True])
    position_index = (0, 2)
    velocity_index = (1, 3)

    def __init__(self, accel_std: float = ACCEL_STD, bearing_std: float = BEARING_STD):
        self.accel_std = float(accel_std)
        self._R = np.array([[bearing_std ** 2]])

    @staticmethod
    @functools.lru_cache(maxsize=8)
    def _transition_matrix(dt: float) -> np.ndarray:
        F = np.eye(4)
        F[0, 1] = F[2, 3] = dt
        F.flags.writeable = False
        return F

    def drift(self, x, t=0.0, u=None):
        return x @ self._transition_matrix(1.0).T - x  # (F(1) - I) x: the velocities in the positions

    def transition(self, x, dt, t=0.0, u=None):
        return x @ self._transition_matrix(dt).T

    def transition_jacobian(self, x, dt, t=0.0, u=None):
        return np.repeat(self._transition_matrix(dt)[None], x.shape[0], axis=0)

    def process_noise(self, dt):
        block = self.accel_std ** 2 * np.array([[dt ** 3 / 3.0, dt ** 2 / 2.0], [dt ** 2 / 2.0, dt]])
        Q = np.zeros((4, 4))
        Q[:2, :2] = Q[2:, 2:] = block
        return Q

    def measure(self, x):
        return np.arctan2(x[:, 2:3], x[:, 0:1])

    def measurement_jacobian(self, x):
        px, py = x[:, 0], x[:, 2]
        r2 = px * px + py * py
        H = np.zeros((x.shape[0], 1, 4))
        np.divide(py, r2, out=H[:, 0, 0])
        np.negative(H[:, 0, 0], out=H[:, 0, 0])
        np.divide(px, r2, out=H[:, 0, 2])
        return H

    def measurement_noise(self):
        return self._R


def simulate(rng: np.random.Generator, steps: int = STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Truth ``(steps + 1, 4)`` from the paper's start and bearings ``(steps, 1)``."""
    model = BearingsOnlyModel()
    L = np.linalg.cholesky(model.process_noise(1.0))
    x = np.empty((steps + 1, 4))
    x[0] = TRUE_START
    for k in range(steps):
        x[k + 1] = model.transition(x[k:k + 1], 1.0)[0] + L @ rng.standard_normal(4)
    y = model.measure(x[1:]) + BEARING_STD * rng.standard_normal((steps, 1))
    return x, y


def filters(n_particles: int, seed: int) -> dict[str, object]:
    """Every filter of the package on the model, by name."""
    model = BearingsOnlyModel()
    return {
        "BootstrapPF": BootstrapPF(model, n_particles, seed=seed),
        "GPF (cloud metric)": GeometricProjectionPF(model, n_particles, unmodelled_acceleration_std=0.0,
                                                    seed=seed),
        "GPF (paper: likelihood, Euclidean)": GeometricProjectionPF(
            model, n_particles, weighting="likelihood", metric="euclidean", unmodelled_acceleration_std=0.0,
            seed=seed),
        "GPF (corrected, process_noise)": GeometricProjectionPF(
            model, n_particles, weighting="corrected", metric="process_noise", regularization=1.0,
            unmodelled_acceleration_std=0.0, seed=seed),
        "EKF": ExtendedKF(model),
        "UKF": UnscentedKF(model),
        "EnKF": EnsembleKF(model, n_particles, seed=seed),
    }


def track(f, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Run ``f`` over the bearings ``(K, 1)`` from the paper's prior: estimates ``(K, 4)``, the final
    covariance ``(4, 4)`` and the wall time per step in seconds."""
    f.initialize(PRIOR_MEAN, PRIOR_COV)
    out = np.empty((len(ys), 4))
    start = time.perf_counter()
    for k, y in enumerate(ys):
        f.predict(1.0)
        f.update(y)
        out[k] = f.mean
    return out, np.array(f.covariance), (time.perf_counter() - start) / len(ys)


class Score:
    """Accumulates runs of one filter: position errors, final NEES, time per step."""

    def __init__(self):
        self.errors: list[np.ndarray] = []
        self.nees: list[float] = []
        self.step_times: list[float] = []

    def add(self, estimates: np.ndarray, final_cov: np.ndarray, truth: np.ndarray, step_time: float):
        """One run: estimates ``(K, 4)``, final covariance ``(4, 4)``, truth after each step ``(K, 4)``."""
        d = (estimates - truth)[:, [0, 2]]
        self.errors.append(np.hypot(d[:, 0], d[:, 1]))
        P = final_cov[np.ix_([0, 2], [0, 2])]
        try:
            self.nees.append(float(d[-1] @ np.linalg.solve(P, d[-1])))
        except np.linalg.LinAlgError:
            self.nees.append(np.inf)
        self.step_times.append(step_time)

    def summary(self) -> dict[str, float]:
        """Position RMSE over all steps of the runs that finished, failed (raised), lost and
        overconfident runs, median time per step."""
        e = np.array(self.errors)
        finished = np.isfinite(e).all(axis=1)  # a peer library may raise and stop (see the peers' script)
        return {"rmse": float(np.sqrt(np.mean(e[finished] ** 2))), "failed": int(np.sum(~finished)),
                "lost": int(np.sum(~(e[:, -1] <= LOST_DISTANCE))),
                "overconfident": int(np.sum(~(np.array(self.nees) <= OVERCONFIDENT_NEES))),
                "runs": len(self.errors), "step_us": 1e6 * float(np.median(self.step_times))}


def report(title: str, scores: dict[str, Score]) -> dict[str, dict[str, float]]:
    """Print one line per filter and return the summaries."""
    results = {name: score.summary() for name, score in scores.items()}
    print(title)
    print(f"{'filter':32s} {'RMSE':>8s} {'lost':>5s} {'overconf.':>9s} {'failed':>6s} {'us/step':>9s}")
    for name, r in results.items():
        print(f"{name:32s} {r['rmse']:8.4f} {r['lost']:>5d} {r['overconfident']:>9d} {r['failed']:>6d} "
              f"{r['step_us']:9.1f}")
    return results


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--particles", type=int, default=2000)
    args = parser.parse_args(argv)
    scores: dict[str, Score] = {}
    for run in range(args.runs):
        truth, ys = simulate(np.random.default_rng(run))
        for name, f in filters(args.particles, seed=1000 + run).items():
            estimates, final_cov, step_time = track(f, ys)
            scores.setdefault(name, Score()).add(estimates, final_cov, truth[1:], step_time)
    return report(f"bearings-only tracking, {args.runs} runs, N = {args.particles}", scores)


if __name__ == "__main__":
    main()
