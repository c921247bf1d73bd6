"""The GPF's options on the bearings-only example (``bearings_only.py``), beside the bootstrap PF.

Run: ``python docs/examples/bearings_only_gpf.py [--runs 100] [--particles 2000 10000]``. Same truth,
bearings and table as ``bearings_only.py``; one table per particle count.
"""
from __future__ import annotations

import argparse

import numpy as np

from bearings_only import BearingsOnlyModel, Score, report, simulate, track
from gpf_nav.filters import BootstrapPF, GeometricProjectionPF

VARIANTS = {  # no unmodelled-acceleration compensation: the example's model is the truth's
    "BootstrapPF": {},
    "GPF cloud metric (corrected)": {"metric": "cloud"},
    "GPF likelihood, Euclidean (paper)": {"weighting": "likelihood", "metric": "euclidean"},
    "GPF corrected, Euclidean": {"weighting": "corrected", "metric": "euclidean"},
    "GPF likelihood, process_noise eps=1": {"weighting": "likelihood", "metric": "process_noise",
                                            "regularization": 1.0},
    "GPF corrected, process_noise eps=1": {"weighting": "corrected", "metric": "process_noise",
                                           "regularization": 1.0},
}


def make(name: str, n_particles: int, seed: int):
    model = BearingsOnlyModel()
    if name == "BootstrapPF":
        return BootstrapPF(model, n_particles, seed=seed)
    return GeometricProjectionPF(model, n_particles, seed=seed, unmodelled_acceleration_std=0.0,
                                 **VARIANTS[name])


def main(argv: list[str] | None = None) -> dict[int, dict[str, dict[str, float]]]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--particles", type=int, nargs="+", default=[2000, 10000])
    args = parser.parse_args(argv)
    tables = {}
    for n in args.particles:
        scores: dict[str, Score] = {}
        for run in range(args.runs):
            truth, ys = simulate(np.random.default_rng(run))
            for name in VARIANTS:
                estimates, final_cov, step_time = track(make(name, n, 1000 + run), ys)
                scores.setdefault(name, Score()).add(estimates, final_cov, truth[1:], step_time)
        tables[n] = report(f"bearings-only tracking, GPF options, {args.runs} runs, N = {n}", scores)
    return tables


if __name__ == "__main__":
    main()
