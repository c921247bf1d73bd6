"""``gpf-nav stress``: the estimators on conditions a descent navigation filter meets in service.

Conditions (each a change of the scenario, ``docs/scenario.md``; the truth flies the exact two-body model,
``epsilon = --epsilon``, default 0, unless a condition says otherwise):

* ``large-prior``: prior position sigma 20 km, velocity sigma 20 m/s (the mean drawn from it), full case;
* ``range-only``: azimuth and elevation never measured (``case: range``);
* ``outliers``: 3 % of the measurement components are 20-sigma outliers;
* ``range-bias``: a constant range bias of +2 sigma (60 m);
* beyond the envelope, only when named in ``--conditions`` (:data:`BEYOND`): ``large-prior-range``,
  ``large-prior-partial``, ``large-prior-mismatch`` (the large prior with range only, without azimuth,
  or with the 9 % gravity mismatch), ``range-only-mismatch`` (range only, 9 % mismatch), ``dropouts``
  (30 % of the measurement vectors lost) and ``noisy-outliers`` (noise x10 and 3 % outliers);
* surface stations, only when named (:data:`gpf_nav.experiments.surface.SURFACE`): ``surface-gaps`` (one
  beacon on the rotating Moon, seen 27 % of the run) and ``surface-two`` (two beacons) replace the station
  at the centre;
* ``prior-x<s>``: the prior-size sweep, position sigma ``s`` km and velocity sigma ``s`` m/s for each
  ``s`` of ``--prior-scales`` (default 1, 3, 10; ``large-prior`` is the point ``s = 20``).

Filters (``--filters``, default): the default GPF (``gpf``, the multiple-model GPF), the single
compensated GPF (``gpf-single``), the compensated EKF with the
GPF's innovation gate (``ekf-comp-gated``), the nominal EKF (``ekf``) and the oracle-tuned EKF
(``ekf-oracle``: per condition, the process-noise multiplier with the lowest mean position RMSE over the
same runs). Run ``r`` of every condition uses the same random numbers (paired: the conditions differ
only by what they change), and every filter of a run sees the same truth, measurements and prior.

Per condition and filter: mean and median position RMSE, mean velocity RMSE, mean NEES (6 states; time
average per run over the steps with a positive definite covariance, then mean over runs), the
divergences (final position error above ``--divergence-km``, default 10 km, or a non-finite
estimate), the worst run (its index and position RMSE), ESS/N after the first update (particle
filters) and the number of published covariances that were singular or indefinite (a Cholesky of each
step's covariance, :func:`~gpf_nav.experiments.metrics.not_positive_definite`). Writes ``stress.json``,
``stress.md`` and ``stress.png`` into ``--out``.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path

import numpy as np

from gpf_nav import registry
from gpf_nav.arguments import CommandParser, positive_float, positive_int
from gpf_nav.experiments.montecarlo import base_config, git_commit, parse_filters, run_metadata, write_json
from gpf_nav.experiments.parallel import add_campaign_arguments, map_tasks
from gpf_nav.experiments.runner import RunTask, run_task, select_oracle
from gpf_nav.experiments.surface import SURFACE
from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.sim.scenario import ScenarioConfig

SCHEMA = "gpf_nav.stress/1"
DEFAULT_FILTERS = "gpf,gpf-single,ekf-comp-gated,ekf,ekf-oracle"
PRIOR_SCALES = (1.0, 3.0, 10.0)
"""Default prior-size sweep: position sigma ``s`` km, velocity sigma ``s`` m/s."""
CONDITIONS = {
    "large-prior": ("large prior (20 km, 20 m/s), full case",
                    {"prior_position_std": 20e3, "prior_velocity_std": 20.0}),
    "range-only": ("range only (no azimuth, no elevation)", {"case": "range"}),
    "outliers": ("outliers: 3 % of components at 20 sigma",
                 {"outlier_probability": 0.03, "outlier_size": 20.0}),
    "range-bias": ("constant range bias +2 sigma (60 m)", {"measurement_bias_sigma": (2.0, 0.0, 0.0)}),
}
"""The fixed conditions: name -> (label, changes of the base scenario)."""
_LARGE_PRIOR = CONDITIONS["large-prior"][1]
BEYOND = {
    "large-prior-range": ("large prior + range only", {**_LARGE_PRIOR, "case": "range"}),
    "large-prior-partial": ("large prior + no azimuth", {**_LARGE_PRIOR, "case": "partial"}),
    "large-prior-mismatch": ("large prior + 9 % gravity mismatch", {**_LARGE_PRIOR, "epsilon": 0.09}),
    "range-only-mismatch": ("range only + 9 % gravity mismatch", {"case": "range", "epsilon": 0.09}),
    "dropouts": ("30 % of measurements lost", {"dropout_probability": 0.3}),
    "noisy-outliers": ("noise x10 + 3 % outliers at 20 sigma",
                       {"measurement_noise_scale": 10.0, "outlier_probability": 0.03, "outlier_size": 20.0}),
}
"""Conditions beyond the envelope the default was built for (combinations), run only when named."""
THRUST_DRIFT = (0.005, 2.0 * math.pi / 2400.0)
"""``thrust-drift``: an unmodelled 5 mm/s^2 thrust whose direction turns once in the orbit plane over the
2400 s descent, m/s^2 and rad/s."""
GRAVITY = {
    "j2-full": ("J2 unmodelled, full case", {"truth_gravity": "j2"}),
    "j2-partial": ("J2 unmodelled, no azimuth", {"truth_gravity": "j2", "case": "partial"}),
    "j2-modelled": ("J2 in the truth and the model, full case", {"truth_gravity": "j2", "filter_gravity": "j2"}),
    "degree4-j2": ("degree-4 field, J2-modelled filter, full case",
                   {"truth_gravity": "degree4", "filter_gravity": "j2"}),
    "thrust-drift": ("unmodelled 5 mm/s^2 thrust turning once in the orbit plane",
                     {"thrust": THRUST_DRIFT[0], "thrust_known": False, "thrust_drift_rate": THRUST_DRIFT[1]}),
}
"""The Moon's own gravity field and slowly varying forces, small against the 9 % mismatch (``J2`` adds
about 4.6e-4 m/s^2 at 100 km; :mod:`gpf_nav.models.gravity`), run only when named."""
KNOWN = {**CONDITIONS, **BEYOND, **GRAVITY, **SURFACE}


def prior_condition(scale: float) -> tuple[str, tuple[str, dict]]:
    """``(name, (label, changes))`` of the prior-size sweep point ``scale``."""
    return f"prior-x{scale:g}", (f"prior {scale:g} km, {scale:g} m/s",
                                 {"prior_position_std": 1e3 * scale, "prior_velocity_std": 1.0 * scale})


def conditions(names, prior_scales) -> dict:
    """``{name: (label, changes)}`` of the fixed conditions ``names`` and the prior-size sweep."""
    out = {name: KNOWN[name] for name in names}
    out.update(prior_condition(float(s)) for s in prior_scales)
    return out


def stress(config: ScenarioConfig, selected: dict, runs: int, seed: int, filters, n_particles: int,
           divergence_km: float, workers=None, scheduler=None, progress=True) -> dict:
    """Run every condition of ``selected`` (as :func:`conditions` returns) on ``config``; returns the
    report (without ``meta``)."""
    tasks = []
    for name, (_, changes) in selected.items():
        point = dataclasses.replace(config, **changes)
        for run in range(runs):
            tasks.append(RunTask(index=len(tasks), run=run, seed=seed, config=point, filters=tuple(filters),
                                 n_particles=n_particles, divergence_bound=divergence_km * 1e3,
                                 tag={"condition": name}))
    results = map_tasks(run_task, tasks, workers=workers, scheduler=scheduler, progress=progress,
                        description="stress runs")
    report = {"schema": SCHEMA,
              "settings": {"runs": runs, "seed": seed, "n_particles": n_particles, "filters": list(filters),
                           "divergence_km": divergence_km, "base_config": config.to_dict(),
                           "statistics": "per condition and filter over the same runs; a run with a "
                                         "non-finite estimate counts as diverged and has no RMSE"},
              "conditions": {}}
    for name, (label, changes) in selected.items():
        chunk = [r for r in results if r["tag"]["condition"] == name]
        oracle = select_oracle(chunk, tuple(filters))
        report["conditions"][name] = {
            "label": label, "changes": changes, "oracle_multiplier": oracle,
            "filters": {f: summarise(chunk, f, divergence_km * 1e3) for f in filters}}
    return report


def summarise(chunk: list[dict], name: str, bound: float) -> dict:
    """The statistics of filter ``name`` over the runs ``chunk`` (in run order)."""
    rows = [r["filters"][name] for r in chunk]
    position = np.array([np.nan if s["nonfinite"] else s["position_rmse"] for s in rows])
    finite = np.isfinite(position)
    diverged = [r["run"] for r, s in zip(chunk, rows)
                if s["nonfinite"] or not s["final_position_error"] <= bound]

    def stat(key: str, reduce) -> float | None:
        values = np.array([np.nan if s["nonfinite"] else s[key] for s in rows], dtype=float)
        values = values[np.isfinite(values)]
        return float(reduce(values)) if values.size else None

    worst = int(np.argmax(np.where(finite, position, -np.inf))) if finite.any() else None
    particle = registry.lookup(name).particles
    return {
        "position_rmse_mean": stat("position_rmse", np.mean),
        "position_rmse_median": stat("position_rmse", np.median),
        "velocity_rmse_mean": stat("velocity_rmse", np.mean),
        "nees_mean": stat("nees", np.mean),
        "nees_defined_mean": stat("nees_defined", np.mean),
        "runs": len(rows),
        "diverged": len(diverged), "diverged_runs": diverged,
        "nonfinite": sum(bool(s["nonfinite"]) for s in rows),
        "worst_run": None if worst is None else {"run": chunk[worst]["run"],
                                                 "position_rmse": float(position[worst]),
                                                 "final_position_error": rows[worst]["final_position_error"]},
        "first_ess_mean": stat("first_ess", np.mean) if particle else None,
        "first_ess_min": stat("first_ess", np.min) if particle else None,
        "covariance_failures": int(sum(s["covariance_failures"] for s in rows)),
        "covariance_failure_runs": sum(s["covariance_failures"] > 0 for s in rows),
        "above_bound_mean": stat("above_bound", np.mean),
        "undetermined_share_mean": stat("undetermined_share", np.mean),
        "named_share_mean": stat("named_share", np.mean),
        "consistency_fault_share": stat("consistency_faults", np.mean),
        "consistency_fault_runs": sum(s["consistency_faults"] > 0 for s in rows),
        "first_fault_median": stat("first_fault", np.median),
        "per_run_position_rmse": position,
    }


def _num(value, digits: int = 3) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}g}"


def markdown(report: dict) -> str:
    """One Markdown table: a row per condition and filter."""
    s = report["settings"]
    lines = [f"# Stress campaign: {s['runs']} runs per condition, N = {s['n_particles']}, seed {s['seed']}", ""]
    meta = report.get("meta")
    if meta:
        lines += [f"Command: `{meta['command']}`  ", f"Commit: `{meta['git_commit']}`; wall time "
                  f"{meta['wall_seconds']:.0f} s ({meta['workers'] or 'Dask'} workers).", ""]
    lines += ["| condition | filter | position RMSE mean / median (m) | velocity RMSE (m/s) | NEES | "
              f"diverged (> {s['divergence_km']:g} km) | worst run: # (m) | ESS/N after 1st update: "
              "mean (min) | singular / indefinite covariances: steps (runs) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for entry in report["conditions"].values():
        for first, (name, row) in zip([True] + [False] * len(entry["filters"]), entry["filters"].items()):
            worst = row["worst_run"]
            worst = "n/a" if worst is None else f"{worst['run']} ({worst['position_rmse']:.3g})"
            ess = ("" if row["first_ess_mean"] is None
                   else f"{row['first_ess_mean']:.3g} ({row['first_ess_min']:.2g})")
            lines.append(
                f"| {entry['label'] if first else ''} | {name} | {_num(row['position_rmse_mean'])} / "
                f"{_num(row['position_rmse_median'])} | {_num(row['velocity_rmse_mean'])} | "
                f"{_num(row['nees_mean'])} | {row['diverged']} of {row['runs']} | {worst} | {ess} | "
                f"{row['covariance_failures']} ({row['covariance_failure_runs']}) |")
    lines += ["", "NEES: time average per run over the steps with a positive definite covariance, then the "
                  "mean over runs (consistent: 6). Diverged: final position error above the bound, or a "
                  "non-finite estimate (no RMSE then). Covariances: steps whose published covariance "
                  "failed a Cholesky factorisation, summed over runs (runs with any)."]
    for entry in report["conditions"].values():
        for family, multiplier in entry["oracle_multiplier"].items():
            lines.append(f"{family}, {entry['label']}: process-noise variance multiplier {multiplier:g}.  ")
    return "\n".join(lines) + "\n"


def draw(report: dict, path: Path) -> Path:
    """The campaign's figure: position RMSE and NEES per condition and filter, and the prior sweep."""
    from gpf_nav.experiments import plots

    entries = report["conditions"]
    prior = sorted((float(c["changes"]["prior_position_std"]) / 1e3, name) for name, c in entries.items()
                   if set(c["changes"]) == {"prior_position_std", "prior_velocity_std"})
    return plots.stress({name: (c["label"], c["filters"]) for name, c in entries.items()},
                        [(scale, entries[name]["filters"]) for scale, name in prior],
                        report["settings"]["runs"], path)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = CommandParser(prog="gpf-nav stress", description=__doc__.split("\n\n")[0],
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    add_campaign_arguments(parser, 20, "runs per condition")
    parser.add_argument("--config", type=Path, default=None,
                        help="base scenario YAML (default: the built-in defaults = config/scenario.yaml)")
    parser.add_argument("--epsilon", type=float, default=0.0,
                        help="gravity mismatch of the truth in every condition (default 0: exact dynamics)")
    parser.add_argument("--duration", type=positive_float, default=None, help="override the duration (s)")
    parser.add_argument("--dt", type=positive_float, default=None, help="override the filter step (s)")
    parser.add_argument("--particles", type=positive_int, default=N_PARTICLES,
                        help=f"particles per particle filter (default {N_PARTICLES})")
    parser.add_argument("--filters", default=DEFAULT_FILTERS,
                        help=f"comma-separated short names (default {DEFAULT_FILTERS}); known: "
                             + ", ".join(registry.short_names()))
    parser.add_argument("--conditions", default=",".join(CONDITIONS),
                        help=f"comma-separated fixed conditions (default: {', '.join(CONDITIONS)}; "
                             f"beyond the envelope, when named: {', '.join(BEYOND)})")
    parser.add_argument("--prior-scales", default=",".join(f"{s:g}" for s in PRIOR_SCALES),
                        help="prior-size sweep: position sigma s km, velocity sigma s m/s per value "
                             "(default 1,3,10; empty: no sweep)")
    parser.add_argument("--divergence-km", type=positive_float, default=10.0,
                        help="final position error counted as divergence (km, default 10)")
    parser.add_argument("--out", type=Path, default=Path("stress-results"),
                        help="output directory (default ./stress-results)")
    parser.add_argument("--no-plots", action="store_true", help="do not draw the figure")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    try:
        config = dataclasses.replace(base_config(args), epsilon=args.epsilon)
        filters = parse_filters(args.filters)
        names = [n.strip() for n in args.conditions.split(",") if n.strip()]
        unknown = [n for n in names if n not in KNOWN]
        if unknown:
            raise ValueError(f"--conditions: unknown {unknown}; known: {', '.join(KNOWN)}")
        scales = [float(v) for v in args.prior_scales.split(",") if v.strip()]
        if not all(0.0 < v < math.inf for v in scales):
            raise ValueError(f"--prior-scales must be positive numbers, got {args.prior_scales!r}")
        selected = conditions(names, scales)
        if not selected:
            raise ValueError("no condition selected")
        for _, changes in selected.values():  # refused now, not after the campaign
            dataclasses.replace(config, **changes)
    except (ValueError, OSError) as err:
        parser.error(str(err))
    commit = git_commit()  # the code this process runs; read before a long campaign
    start = time.perf_counter()
    report = stress(config, selected, args.runs, args.seed, filters, args.particles, args.divergence_km,
                    args.workers, args.scheduler, not args.no_progress)
    wall = time.perf_counter() - start
    report["meta"] = run_metadata(args, wall, ["stress"] + argv, commit)
    args.out.mkdir(parents=True, exist_ok=True)
    json_path, md_path = args.out / "stress.json", args.out / "stress.md"
    write_json(report, json_path)
    md_path.write_text(markdown(report))
    written = [json_path, md_path]
    if not args.no_plots:
        written.append(draw(report, args.out / "stress.png"))
    print(markdown(report))
    print(f"wall time {wall:.1f} s; wrote " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
