"""``gpf-nav bench``: per-step cost (one ``predict`` + one ``update``) of every filter on the lunar model.

The filters are :mod:`gpf_nav.registry` entries, by name (default :data:`FILTERS`): ``gpf`` is the
default (navigation-grade) configuration, the multiple-model GPF (a nominal and a compensated GPF of N
particles each, and a compensated EKF), ``gpf-paper`` the paper's, ``gpf-single`` one
navigation-grade GPF of N particles on the compensated model, ``spf`` the bootstrap PF without its
diagnostic co-state, and ``particles`` N. Chopin's bootstrap filter on the same model when that library is installed
(:mod:`gpf_nav.experiments.peer_particles`; skipped otherwise).
Each filter runs on the same seeded lunar-descent measurements, each step on the next measurement. A step is
timed over a block of steps; after each block, untimed, the estimate is compared with the truth, so a filter's
time comes with its position and velocity errors (RMS over the blocks' ends), its mean NEES and its worst
position error in the same steps: a speed bought with a wrong estimate shows. The filters of one group (the
particle filters of one N; the Gaussian filters and the EnKF) run their blocks in turn, round after round, the
order rotating each round, so a machine whose speed drifts (other work, CPU frequency) moves every filter of
the group alike. The reported figure is a filter's median block time per step over ``--repeats`` rounds, after
a warm-up; the ratios (:data:`RATIOS`: GPF/SPF, GPF/GPF-paper, GPF/particles, SPF/particles,
GPF-paper/particles) are the medians over the rounds of the ratio of the two blocks of a round. The warm-up is
:data:`WARMUP` steps: the blocks then time the descent's first minutes, where the navigation-grade GPF's
clouds are wide enough to be flattened at most updates; ``--warmup 300`` times the steady state that follows,
where most updates skip it (``docs/filters.md``). A filter's observability tracker runs its recursions when its
report is read (:class:`~gpf_nav.integrity.observability.ObservabilityTracker`): the default reads it at every update,
the others' are left queued and not timed unless ``--reports`` reads every filter's report after each step, as the
node's diagnostics and the campaigns do. ``--model-calls`` also times each filter's calls into the lunar model
(:mod:`gpf_nav.experiments.model_calls`): how much of its step is the model's and how much the filter's own.
``gpf-nav bench`` runs with the heap tuning of :mod:`gpf_nav.allocator` and OpenMP's passive waits
(:mod:`gpf_nav.openmp`; the report says whether each was applied); ``python -m gpf_nav.experiments.bench``
runs with the C library's default allocator and OpenMP's default policy, for comparison. ``--node`` runs the
ROS node-latency benchmark instead (``gpf_nav.tools.latency``).
"""
from __future__ import annotations

import contextlib
import json
import os
import platform
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from gpf_nav import allocator, registry
from gpf_nav.arguments import CommandParser, non_negative_int, positive_int
from gpf_nav.experiments import peer_particles
from gpf_nav.experiments.metrics import nees_step, rmse
from gpf_nav.experiments.model_calls import ModelCallTimer
from gpf_nav.experiments.peer_particles import ParticlesBootstrap
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

PARTICLE_COUNTS = (500, 10_000, 100_000)
LARGE = 1_000_000
"""The particle count ``--large`` adds."""
PEER = "particles"
"""The peer library's bootstrap filter, timed with the particle filters (not a registry entry)."""
FILTERS = ("gpf", "gpf-paper", "gpf-single", "spf", PEER, "ekf", "ukf", "enkf")
"""The filters timed by default (registry names and :data:`PEER`), in table order."""
ENSEMBLE_SIZE = 500
"""Members of an ensemble filter (the particle counts apply to the particle filters only)."""
RATIOS = (("gpf_over_spf", "gpf", "spf"), ("gpf_over_paper_gpf", "gpf", "gpf-paper"),
          ("gpf_over_particles", "gpf", PEER), ("spf_over_particles", "spf", PEER),
          ("paper_gpf_over_particles", "gpf-paper", PEER))
"""The ratios a report gives per particle count, each ``(report key, numerator, denominator)`` (filter
names); a key is empty unless both filters ran."""


def _maker(name: str, n: int | None):
    """``constructor(model, seed)`` of registry filter ``name`` (or :data:`PEER`) with ``n`` particles or
    members."""
    if name == PEER:
        return lambda model, seed: ParticlesBootstrap(model, n, seed)
    return lambda model, seed: registry.make(name, model, n, seed)


def _particle_filter(name: str) -> bool:
    return name == PEER or registry.lookup(name).particles


def _groups(particle_counts, filters=FILTERS) -> list[list[tuple[str, int | None, object]]]:
    """Groups timed together, each a list of ``(filter name, N or None, constructor(model, seed))`` in table
    order: the particle filters of each N (:data:`PEER` among them when installed), then the others
    (Gaussian and ensemble filters)."""
    names = [name for name in filters if name != PEER or peer_particles.available()]
    groups = [[(name, n, _maker(name, n)) for name in names if _particle_filter(name)] for n in particle_counts]
    entries = [registry.lookup(name) for name in names if not _particle_filter(name)]
    others = [(e.name, None if e.min_particles is None else ENSEMBLE_SIZE,
               _maker(e.name, None if e.min_particles is None else ENSEMBLE_SIZE))
              for e in entries]
    return [group for group in (*groups, others) if group]


WARMUP = 3
"""Untimed steps before the first block."""
STEPS = 50
"""Steps per timed block (5 above N = 10 000, :data:`LARGE_STEPS` from :data:`LARGE`)."""
LARGE_STEPS = 2


def time_filters(makers, scenario, model, steps: int, repeats: int, warmup: int = WARMUP,
                 after_block: Callable[[int, object, int], None] | None = None,
                 reports: bool = False, timer: ModelCallTimer | None = None) -> list[list[float]]:
    """Seconds per predict+update step of each filter made by ``makers`` (``constructor(model, seed)``), one
    list of ``repeats`` block times each: the filters run blocks of ``steps`` steps in turn, round after
    round, the first of a round rotating. Each filter's step takes the scenario's next measurement (so it
    runs in its normal regime, tracking the truth); with ``reports`` it also reads the filter's
    observability report. ``after_block(i, filter, k)``, untimed, follows each block of
    filter ``i`` that ended with its estimate of ``scenario.truth[k]``. With ``timer`` (installed on
    ``model``), each block's seconds and calls per step inside the model go to ``timer.blocks[i]``."""
    if warmup + repeats * steps > len(scenario.measurements):
        raise ValueError(f"the scenario has {len(scenario.measurements)} measurements, the timing needs "
                         f"{warmup + repeats * steps}")
    dt, ys = scenario.config.dt, scenario.measurements
    filters = [make(model, 0) for make in makers]
    for f in filters:
        f.initialize(scenario.prior_mean, scenario.prior_cov)
        for k in range(warmup):
            f.predict(dt)
            f.update(ys[k])
    blocks: list[list[float]] = [[] for _ in filters]
    count = len(filters)
    for round_ in range(repeats):
        first = warmup + round_ * steps
        for i in [(round_ + j) % count for j in range(count)]:
            f = filters[i]
            if timer is not None:
                timer.start_block()
            start = time.perf_counter()
            for k in range(first, first + steps):
                f.predict(dt)
                f.update(ys[k])
                if reports:
                    f.observability
            blocks[i].append((time.perf_counter() - start) / steps)
            if timer is not None:
                timer.end_block(i, steps)
            if after_block is not None:
                after_block(i, f, first + steps)
    return blocks


def estimate_errors(f, truth: np.ndarray) -> tuple[float, float, float]:
    """``(position error m, velocity error m/s, NEES)`` of the filter ``f``'s estimate of ``truth`` ``(6,)``
    (the lunar state: position then velocity)."""
    error = np.asarray(f.mean, dtype=float)[:6] - truth
    return (float(np.linalg.norm(error[:3])), float(np.linalg.norm(error[3:6])),
            nees_step(error, np.asarray(f.covariance, dtype=float)[:6, :6]))


def accuracy(ends: list[tuple[float, float, float]]) -> dict:
    """The figures of a filter's :func:`estimate_errors` at its block ends: position and velocity RMS, mean
    NEES, worst position error."""
    position, velocity, nees = (np.array(column) for column in zip(*ends))
    return {"position_rms_m": rmse(position), "velocity_rms_m_s": rmse(velocity),
            "nees_mean": float(np.mean(nees)), "position_worst_m": float(np.max(position))}


def time_filter(make, scenario, model, steps: int, repeats: int, warmup: int = WARMUP) -> float:
    """Median seconds per step of one filter (:func:`time_filters` of it alone)."""
    return float(np.median(time_filters([make], scenario, model, steps, repeats, warmup)[0]))


def run(particle_counts=PARTICLE_COUNTS, repeats: int = 15, seed: int = 0, filters=FILTERS,
        warmup: int = WARMUP, reports: bool = False, model_calls: bool = False) -> dict:
    """Benchmark ``filters`` (registry names) after ``warmup`` untimed steps, with ``reports`` each filter's
    observability report read after every step; returns ``{"results": [{"filter", "particles", "us_per_step",
    "blocks_us" (per round), and :func:`accuracy`'s keys}, ...], "gpf_over_spf": {N: ratio}, ... (one key per
    :data:`RATIOS` entry, each empty unless both of its filters ran: those against ``particles`` without that
    library), "warmup": steps, "reports": reports, "model_calls": model_calls, "machine": ...}`` (module
    docstring). With ``model_calls`` every result also has ``"model_us_per_step"`` and ``"model_calls_per_step"``,
    the medians over its blocks of the time and calls spent inside the lunar model
    (:class:`~gpf_nav.experiments.model_calls.ModelCallTimer`)."""
    default = ScenarioConfig()
    config = replace(default, duration=default.dt * (warmup + repeats * STEPS + 1))
    scenario = generate(config, seed)
    model = filter_model(config)
    results, ratios = [], {key: {} for key, _, _ in RATIOS}
    for group in _groups(particle_counts, filters):
        n = max(count or 0 for _, count, _ in group)
        steps = STEPS if n <= 10_000 else 5 if n < LARGE else LARGE_STEPS
        ends: list[list[tuple[float, float, float]]] = [[] for _ in group]
        timer = ModelCallTimer(model) if model_calls else None
        with timer or contextlib.nullcontext():
            blocks = time_filters([make for _, _, make in group], scenario, model, steps, repeats, warmup,
                                  lambda i, f, k: ends[i].append(estimate_errors(f, scenario.truth[k])), reports,
                                  timer)
        for i, ((name, count, _), times, errors) in enumerate(zip(group, blocks, ends)):
            results.append({"filter": name, "particles": count, "us_per_step": float(np.median(times)) * 1e6,
                            "blocks_us": [t * 1e6 for t in times], **accuracy(errors)})
            if timer is not None:
                inside, calls = np.median(np.array(timer.blocks[i]), axis=0)
                results[-1].update(model_us_per_step=float(inside) * 1e6, model_calls_per_step=float(calls))
        by_name = {name: np.asarray(times) for (name, _, _), times in zip(group, blocks)}
        if _particle_filter(group[0][0]):
            for key, numerator, denominator in RATIOS:
                if numerator in by_name and denominator in by_name:
                    ratios[key][str(n)] = float(np.median(by_name[numerator] / by_name[denominator]))
    return {"results": results, **ratios, "warmup": warmup, "reports": reports, "model_calls": model_calls,
            "machine": {"python": platform.python_version(), "numpy": np.__version__,
                        "processor": platform.machine(),
                        "allocator": "retain_freed_memory" if allocator.retained else "default",
                        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", "default")}}


_LABELS = {"gpf": "GPF", "spf": "SPF", "gpf-paper": "GPF-paper", PEER: "particles"}  # (in the table's ratios)


def _shown(us: float) -> str:
    return f"{us:9.1f} us" if us < 1000 else f"{us / 1000:9.2f} ms"


def format_table(report: dict) -> str:
    """A plain-text table of a :func:`run` report."""
    inside = report.get("model_calls", False)
    lines = [f"{'filter':<10} {'N':>8} {'per step':>12} {'position m':>10} {'velocity m/s':>12} {'NEES':>7} "
             f"{'worst m':>8}" + (f" {'in the model':>22}" if inside else "")]
    for r in report["results"]:
        n = "-" if r["particles"] is None else str(r["particles"])
        model = (f" {_shown(r['model_us_per_step'])} {r['model_us_per_step'] / r['us_per_step']:4.0%} "
                 f"{r['model_calls_per_step']:4.0f}x") if inside else ""
        lines.append(f"{r['filter']:<10} {n:>8} {_shown(r['us_per_step']):>12} {r['position_rms_m']:>10.4g} "
                     f"{r['velocity_rms_m_s']:>12.4g} {r['nees_mean']:>7.3g} {r['position_worst_m']:>8.4g}{model}")
    lines.append("position, velocity (RMS), NEES (mean) and worst position error: the estimates at the blocks' ends")
    if inside:
        lines.append("in the model: time per step inside the lunar model's methods, its share of the step and the "
                     "calls per step (every call timed: the steps are slower than without --model-calls)")
    read = ", every filter's observability report read at each step" if report.get("reports") else ""
    lines.append(f"ratios (medians over rounds of blocks timed in turn, after {report['warmup']} steps{read}):")
    for key, numerator, denominator in RATIOS:
        if report.get(key):
            lines.append(f"{_LABELS[numerator]}/{_LABELS[denominator]}: "
                         + ", ".join(f"N={n}: {v:.2f}" for n, v in report[key].items()))
    lines.append(f"allocator: {report['machine']['allocator']}, OpenMP wait policy: "
                 f"{report['machine']['omp_wait_policy']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(prog="gpf-nav bench", description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument("--particles", type=positive_int, nargs="+", default=list(PARTICLE_COUNTS),
                        help="particle counts for GPF and SPF (default: 500 10000 100000)")
    parser.add_argument("--filters", default=",".join(FILTERS),
                        help=f"comma-separated registry names, or {PEER} (default {','.join(FILTERS)})")
    parser.add_argument("--large", action="store_true",
                        help=f"also N = {LARGE:,} (blocks of {LARGE_STEPS} steps)".replace(",", " "))
    parser.add_argument("--repeats", type=positive_int, default=15,
                        help="rounds of timed blocks (medians taken; default 15)")
    parser.add_argument("--warmup", type=non_negative_int, default=WARMUP,
                        help=f"untimed steps before the first block (default {WARMUP}: the first minutes; "
                             "300: the steady state)")
    parser.add_argument("--reports", action="store_true",
                        help="read every filter's observability report after each step (as the node's diagnostics "
                             "and the campaigns do; otherwise only the default's update reads it)")
    parser.add_argument("--model-calls", action="store_true",
                        help="also time each filter's calls into the lunar model: how much of its step is the "
                             "model's and how much the filter's own (gpf_nav.experiments.model_calls)")
    parser.add_argument("--node", action="store_true",
                        help="run the ROS node-latency benchmark instead (arguments after -- go to it)")
    args, rest = parser.parse_known_args(argv)
    if args.node:
        from gpf_nav.tools import latency
        return int(latency.main(rest + (["--json"] if args.json else [])) or 0)
    if rest:
        parser.error(f"unrecognised arguments: {' '.join(rest)}")
    try:
        filters = tuple(name.strip() if name.strip() == PEER else registry.lookup(name.strip()).name
                        for name in args.filters.split(",") if name.strip())
    except ValueError as err:
        parser.error(str(err))
    report = run(tuple(args.particles) + ((LARGE,) if args.large else ()), args.repeats, filters=filters,
                 warmup=args.warmup, reports=args.reports, model_calls=args.model_calls)
    print(json.dumps(report, indent=2) if args.json else format_table(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
