"""``python -m gpf_nav.experiments.tempering``: what likelihood tempering does for a large prior.

The GPF's answer to a prior far wider than its measurements (``tempering_ess``,
:meth:`gpf_nav.filters.particle.ParticleFilter.update`) against the alternatives: no tempering, a higher
threshold, and the regularised fallback the filters already have (``collapse_steps=1``: re-initialise
from the last good estimate when the ESS falls below 1.5 particles). Each variant runs as the single
compensated GPF and as the default multiple-model GPF, on the stress campaign's runs of one prior size
(the same truth, measurements, prior and filter seed per run as ``gpf-nav stress``). Prints one Markdown
table: position and velocity RMSE (mean, worst run), mean NEES, ESS/N after the first update (mean,
min), and the tempered updates per run.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from gpf_nav import registry
from gpf_nav.experiments.parallel import map_tasks
from gpf_nav.experiments.runner import run_filter, run_seeds
from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

VARIANTS = {
    "no tempering": {"tempering_ess": 0.0},
    "tempering 0.1 (default)": {},
    "tempering 0.3": {"tempering_ess": 0.3},
    "no tempering, collapse fallback": {"tempering_ess": 0.0, "collapse_steps": 1},
}
"""Variant name -> options of every GeometricProjectionPF of the variant."""
STRUCTURES = {"single": "gpf-single", "multiple model": "gpf"}
"""Table column -> the :mod:`gpf_nav.registry` GPF each variant runs as."""


def run_one(task: tuple) -> dict:
    """One run of every variant: ``(run, seed, config, n_particles)`` -> ``{(structure, variant): summary}``."""
    run, seed, config, n_particles = task
    scenario_seed, filter_seed = run_seeds(seed, run)
    scenario = generate(config, scenario_seed)
    out = {}
    for structure, filter_name in STRUCTURES.items():
        for name, options in VARIANTS.items():
            flt = registry.make(filter_name, filter_model(config), n_particles, filter_seed, **options)
            summary = run_filter(flt, scenario)
            summary.pop("series")
            summary["tempered"] = flt.tempered_updates
            out[(structure, name)] = summary
    return out


def table(results: list[dict]) -> list[str]:
    """Markdown rows of the variants over ``results`` (one dict per run, as :func:`run_one`)."""
    lines = ["| GPF | variant | position RMSE mean / worst (m) | velocity RMSE mean (m/s) | NEES | "
             "ESS/N after 1st update: mean (min) | tempered updates per run |",
             "|---|---|---|---|---|---|---|"]
    for key in results[0]:
        rows = [r[key] for r in results]
        pos = np.array([r["position_rmse"] for r in rows])
        first = np.array([r["first_ess"] for r in rows])
        lines.append(f"| {key[0]} | {key[1]} | {pos.mean():.0f} / {pos.max():.0f} | "
                     f"{np.mean([r['velocity_rmse'] for r in rows]):.2f} | "
                     f"{np.mean([r['nees'] for r in rows]):.3g} | {first.mean():.2f} ({first.min():.3f}) | "
                     f"{np.mean([r['tempered'] for r in rows]):.1f} |")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gpf_nav.experiments.tempering", description=__doc__)
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0, help="campaign seed (gpf-nav stress's, default 0)")
    parser.add_argument("--prior-km", type=float, default=20.0,
                        help="prior position sigma (km); the velocity sigma is the same number in m/s")
    parser.add_argument("--particles", type=int, default=N_PARTICLES)
    parser.add_argument("--duration", type=float, default=None, help="override the duration (s)")
    parser.add_argument("--workers", type=int, default=None)
    args = parser.parse_args(argv)
    config = dataclasses.replace(ScenarioConfig(epsilon=0.0), prior_position_std=1e3 * args.prior_km,
                                 prior_velocity_std=args.prior_km)
    if args.duration:
        config = dataclasses.replace(config, duration=args.duration)
    start = time.perf_counter()
    results = map_tasks(run_one, [(run, args.seed, config, args.particles) for run in range(args.runs)],
                        workers=args.workers, progress=False)
    print(f"Prior {args.prior_km:g} km / {args.prior_km:g} m/s, {args.runs} runs, N = {args.particles}, "
          f"seed {args.seed}; {time.perf_counter() - start:.0f} s\n")
    print("\n".join(table(results)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
