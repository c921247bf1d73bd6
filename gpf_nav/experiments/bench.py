"""``gpf-nav bench``: per-step cost (one ``predict`` + one ``update``) of every filter on the lunar model.

"GPF" is the default (navigation-grade) configuration, "GPF-paper" the paper's (:data:`PAPER_GPF`),
"GPF-mm" the multiple-model option (two GPFs of N particles each).
Each filter runs on the same seeded lunar-descent measurements. A step is timed over a block of
steps; the reported figure is the median block time per step over ``--repeats`` blocks, after a warm-up.
The GPF/SPF ratio compares figures measured in the same run. ``gpf-nav bench`` runs with the heap
tuning of :mod:`gpf_nav.allocator` (the report says whether it was applied); ``python -m
gpf_nav.experiments.bench`` runs with the C library's default allocator, for comparison.
``--node`` runs the ROS node-latency benchmark instead (``gpf_nav.ros.latency``).
"""
from __future__ import annotations

import json
import platform
import time
from dataclasses import replace

import numpy as np

from gpf_nav import allocator
from gpf_nav.cli import CommandParser, positive_int
from gpf_nav.filters import (BootstrapPF, EnsembleKF, ExtendedKF, GeometricProjectionPF, MultipleModelGPF,
                             UnscentedKF)
from gpf_nav.scenario import ScenarioConfig, filter_model, generate

PARTICLE_COUNTS = (500, 10_000, 100_000)
PAPER_GPF = {"metric": "euclidean", "weighting": "likelihood", "unmodelled_acceleration_std": 0.0}
"""The paper's GPF (Euclidean projection, likelihood weights, no compensation): the "GPF-paper" rows."""
ENSEMBLE_SIZE = 500


def _cases(particle_counts) -> list[tuple[str, int | None, object]]:
    """``(filter name, N or None, constructor(model, seed))`` in table order."""
    cases = []
    for n in particle_counts:
        cases.append(("GPF", n, lambda model, seed, n=n: GeometricProjectionPF(model, n, seed=seed)))
        cases.append(("GPF-paper", n, lambda model, seed, n=n: GeometricProjectionPF(model, n, seed=seed,
                                                                                 **PAPER_GPF)))
        cases.append(("GPF-mm", n, lambda model, seed, n=n: MultipleModelGPF(model, n, seed=seed)))
        cases.append(("SPF", n, lambda model, seed, n=n: BootstrapPF(model, n, seed=seed)))
    cases.append(("EKF", None, lambda model, seed: ExtendedKF(model, seed=seed)))
    cases.append(("UKF", None, lambda model, seed: UnscentedKF(model, seed=seed)))
    cases.append(("EnKF", ENSEMBLE_SIZE, lambda model, seed: EnsembleKF(model, ENSEMBLE_SIZE, seed=seed)))
    return cases


WARMUP = 3
"""Untimed steps before the first block."""
STEPS = 50
"""Steps per timed block (5 above N = 10 000)."""


def time_filter(make, scenario, model, steps: int, repeats: int, warmup: int = WARMUP) -> float:
    """Median seconds per predict+update step over ``repeats`` blocks of ``steps`` steps, each step on
    the scenario's next measurement (so the filter runs in its normal regime, tracking the truth)."""
    if warmup + repeats * steps > len(scenario.measurements):
        raise ValueError(f"the scenario has {len(scenario.measurements)} measurements, the timing needs "
                         f"{warmup + repeats * steps}")
    f = make(model, 0)
    f.initialize(scenario.prior_mean, scenario.prior_cov)
    dt = scenario.config.dt
    ys = scenario.measurements
    k = 0
    for _ in range(warmup):
        f.predict(dt)
        f.update(ys[k])
        k += 1
    blocks = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            f.predict(dt)
            f.update(ys[k])
            k += 1
        blocks.append((time.perf_counter() - start) / steps)
    return float(np.median(blocks))


def run(particle_counts=PARTICLE_COUNTS, repeats: int = 5, seed: int = 0) -> dict:
    """Benchmark every filter; returns ``{"results": [...], "ratios": {N: GPF/SPF}, "machine": ...}``."""
    default = ScenarioConfig()
    config = replace(default, duration=default.dt * (WARMUP + repeats * STEPS + 1))
    scenario = generate(config, seed)
    model = filter_model(config)
    results = []
    for name, n, make in _cases(particle_counts):
        steps = STEPS if n is None or n <= 10_000 else 5
        seconds = time_filter(make, scenario, model, steps, repeats)
        results.append({"filter": name, "particles": n, "us_per_step": seconds * 1e6})
    per = {(r["filter"], r["particles"]): r["us_per_step"] for r in results}
    ratios = {str(n): per[("GPF", n)] / per[("SPF", n)] for n in particle_counts}
    paper = {str(n): per[("GPF", n)] / per[("GPF-paper", n)] for n in particle_counts}
    return {"results": results, "gpf_over_spf": ratios, "gpf_over_paper_gpf": paper,
            "machine": {"python": platform.python_version(), "numpy": np.__version__,
                        "processor": platform.machine(),
                        "allocator": "retain_freed_memory" if allocator.retained else "default"}}


def format_table(report: dict) -> str:
    """A plain-text table of a :func:`run` report."""
    lines = [f"{'filter':<10} {'N':>8} {'per step':>12}"]
    for r in report["results"]:
        n = "-" if r["particles"] is None else str(r["particles"])
        us = r["us_per_step"]
        shown = f"{us:9.1f} us" if us < 1000 else f"{us / 1000:9.2f} ms"
        lines.append(f"{r['filter']:<10} {n:>8} {shown:>12}")
    lines.append("GPF/SPF: " + ", ".join(f"N={n}: {v:.2f}" for n, v in report["gpf_over_spf"].items()))
    lines.append("GPF/GPF-paper: " + ", ".join(f"N={n}: {v:.2f}"
                                              for n, v in report["gpf_over_paper_gpf"].items()))
    lines.append(f"allocator: {report['machine']['allocator']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(prog="gpf-nav bench", description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument("--particles", type=positive_int, nargs="+", default=list(PARTICLE_COUNTS),
                        help="particle counts for GPF and SPF (default: 500 10000 100000)")
    parser.add_argument("--repeats", type=positive_int, default=5, help="timed blocks per filter (median taken)")
    parser.add_argument("--node", action="store_true",
                        help="run the ROS node-latency benchmark instead (arguments after -- go to it)")
    args, rest = parser.parse_known_args(argv)
    if args.node:
        from gpf_nav.ros import latency
        return int(latency.main(rest + (["--json"] if args.json else [])) or 0)
    if rest:
        parser.error(f"unrecognised arguments: {' '.join(rest)}")
    report = run(tuple(args.particles), args.repeats)
    print(json.dumps(report, indent=2) if args.json else format_table(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
