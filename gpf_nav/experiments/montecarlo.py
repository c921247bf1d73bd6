"""``gpf-nav montecarlo``: the paper's Monte Carlo comparison (Table 1 and Section 7 figures).

Runs every filter on ``--runs`` realisations of the lunar-descent scenario for Case 1 (``full``) and
Case 2 (``partial``) and writes, into ``--out``:

* ``results.json``: ``cases -> case -> filters -> filter -> metric -> {mean, std, n}``, and per case
  ``wilcoxon -> other filter -> p`` (paired Wilcoxon signed-rank test of the per-run position RMSE of
  the reference GPF against each other filter), ``failures``, the NEES band, correlations; ``per_run``
  position and velocity RMSE; ``settings`` (everything that determines the numbers) and ``meta`` (wall
  time, workers, git commit: everything that does not);
* ``results.md``: the tables in Markdown;
* PNG figures (unless ``--no-plots``): error evolution, ESS, NEES, per-run RMSE, co-state/degeneracy.

Statistics policy: a run in which a filter raised or produced a non-finite estimate has no error value
and is excluded from that filter's statistics (it counts as a ``nonfinite`` failure); a run whose
position error ever exceeded ``--divergence-km`` counts as a ``diverged`` failure and stays in the
statistics, so a diverging filter is not flattered. The std is the sample std (ddof = 1) over runs.

The random numbers of run ``r`` depend only on ``(--seed, r)``: the output is the same for any
``--workers`` and with ``--scheduler``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from gpf_nav.arguments import CommandParser, positive_float, positive_int
from gpf_nav.experiments import metrics
from gpf_nav.experiments.parallel import add_campaign_arguments, default_workers, map_tasks
from gpf_nav import registry
from gpf_nav.experiments.runner import FILTERS, RunTask, run_task, select_oracle
from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.sim.scenario import CASES, ScenarioConfig

SCHEMA = "gpf_nav.montecarlo/1"
CASE_NAMES = {"full": "Case 1 (full observability)", "partial": "Case 2 (partial observability)",
              "range": "Range only (azimuth and elevation never measured)"}
NEES_PROBABILITY = 0.95

# metric name in the JSON -> (key of the run summary, scale applied, description with unit)
METRICS = {
    "position_rmse_km": ("position_rmse", 1e-3, "position RMSE over the run (km)"),
    "velocity_rmse_mps": ("velocity_rmse", 1.0, "velocity RMSE over the run (m/s)"),
    "ess": ("ess", 1.0, "time-averaged ESS/N after weighting (particle filters)"),
    "costate_norm": ("costate_norm", 1.0, "time-averaged mean co-state norm (whitened units / s)"),
    "nees": ("nees", 1.0, "time-averaged NEES (6 dof; steps with a positive definite covariance)"),
    "nees_defined": ("nees_defined", 1.0, "fraction of steps with a positive definite covariance"),
    "resample_rate": ("resample_rate", 1.0, "fraction of steps that resampled"),
    "max_position_error_km": ("max_position_error", 1e-3, "largest position error of the run (km)"),
}


# --- command line shared with the sweep -------------------------------------------------------------
def add_common_arguments(parser: argparse.ArgumentParser, runs: int) -> None:
    """Options shared by ``montecarlo`` and ``sweep``."""
    add_campaign_arguments(parser, runs, "Monte Carlo runs")
    parser.add_argument("--config", type=Path, default=None,
                        help="scenario YAML (default: the built-in defaults = config/scenario.yaml)")
    parser.add_argument("--duration", type=positive_float, default=None,
                        help="override the scenario duration (s); default 2400 s")
    parser.add_argument("--dt", type=positive_float, default=None, help="override the filter step (s); default 2 s")
    parser.add_argument("--particles", type=positive_int, default=N_PARTICLES,
                        help=f"particles / ensemble members (default {N_PARTICLES})")
    parser.add_argument("--filters", default=None,
                        help="comma-separated short names (default: gpf, ekf-comp, ekf-oracle, "
                             "ukf-oracle and the paper's seven rows gpf-paper, gpf-printed, gpf-exact, spf, "
                             "ekf, ukf, enkf); also available: " + ", ".join(
                             f"{e.name} = {e.label}" for e in registry.ENTRIES.values() if e.table == "extra"))
    parser.add_argument("--cases", default="full,partial", help="comma-separated cases (full,partial)")
    parser.add_argument("--divergence-km", type=positive_float, default=1000.0,
                        help="position error counted as divergence (km, default 1000)")
    parser.add_argument("--no-plots", action="store_true", help="do not draw figures")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def base_config(args) -> ScenarioConfig:
    config = ScenarioConfig.from_yaml(args.config) if args.config else ScenarioConfig()
    changes = {}
    if args.duration is not None:
        changes["duration"] = args.duration
    if args.dt is not None:
        changes["dt"] = args.dt
    return dataclasses.replace(config, **changes) if changes else config


def parse_filters(text: str | None) -> tuple[str, ...]:
    if not text:
        return FILTERS
    keys = [n.strip().lower() for n in text.split(",") if n.strip()]
    names = registry.short_names()
    unknown = [k for k in keys if k not in names]
    if unknown or not keys:
        raise ValueError(f"--filters: unknown filter(s) {unknown}; known: "
                         + ", ".join(f"{e.name} = {e.label}" for e in registry.ENTRIES.values()))
    return tuple(dict.fromkeys(registry.label(k) for k in keys))


def parse_cases(text: str) -> tuple[str, ...]:
    cases = tuple(c.strip() for c in text.split(",") if c.strip())
    bad = [c for c in cases if c not in CASES]
    if bad or not cases:
        raise ValueError(f"--cases must be among {CASES}, got {text!r}")
    return cases


def git_commit() -> str | None:
    """Commit of the source tree running (``+dirty`` if it has uncommitted changes), or None."""
    root = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "gpf_nav"],
                               cwd=root, capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("+dirty" if dirty else "")


def run_metadata(args, wall: float, argv, commit: str | None = None) -> dict:
    """Facts about the execution that do not change the numbers (wall time, engine, commit, ...)."""
    return {"wall_seconds": round(wall, 2), "workers": None if args.scheduler else
            (args.workers or default_workers()), "scheduler": args.scheduler,
            "git_commit": commit or git_commit(), "command": "gpf-nav " + " ".join(argv),
            "python": platform.python_version(), "numpy": np.__version__, "machine": platform.machine(),
            "started": time.strftime("%Y-%m-%d %H:%M:%S %Z", time.localtime(time.time() - wall))}


def write_json(data: dict, path: Path, indent: int | None = 1) -> None:
    """Write ``data`` (numpy values allowed) as strict JSON: a non-finite float is written as null."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(data), indent=indent, allow_nan=False) + "\n")


def read_json(path: Path):
    """The data of a file :func:`write_json` wrote, each null back to NaN."""
    return _nan_for_none(json.loads(Path(path).read_text()))


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    return value


def _nan_for_none(value):
    if isinstance(value, dict):
        return {k: _nan_for_none(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_nan_for_none(v) for v in value]
    return math.nan if value is None else value


# --- aggregation -------------------------------------------------------------------------------------
def per_run_values(results: list[dict], name: str, key: str, scale: float = 1.0) -> np.ndarray:
    """``(runs,)`` of summary ``key`` of filter ``name`` (NaN for a non-finite run), in run order."""
    out = np.array([r["filters"][name][key] for r in results], dtype=float) * scale
    nonfinite = np.array([r["filters"][name]["nonfinite"] for r in results], dtype=bool)
    out[nonfinite] = np.nan
    return out


def summarise_case(results: list[dict], filters: tuple[str, ...], reference: str | None) -> dict:
    """Statistics of one case from its run results (ordered by run)."""
    case = {"filters": {}, "failures": {}, "wilcoxon": {}}
    for name in filters:
        row = {}
        for metric, (key, scale, _) in METRICS.items():
            if key in ("ess", "costate_norm", "resample_rate") and not registry.lookup(name).particles:
                row[metric] = {"mean": None, "std": None, "n": 0}
            else:
                row[metric] = metrics.mean_std(per_run_values(results, name, key, scale))
        diverged = sum(bool(r["filters"][name]["diverged"]) for r in results)
        nonfinite = sum(bool(r["filters"][name]["nonfinite"]) for r in results)
        row["failure_rate"] = metrics.mean_std(
            [float(r["filters"][name]["diverged"] or r["filters"][name]["nonfinite"]) for r in results])
        case["filters"][name] = row
        errors = sorted({r["filters"][name]["error"] for r in results if r["filters"][name]["error"]})
        case["failures"][name] = {"diverged": diverged, "nonfinite": nonfinite, "runs": len(results),
                                  "in_statistics": len(results) - nonfinite, "errors": errors[:5]}
    if reference in filters:
        ref = per_run_values(results, reference, "position_rmse")
        for name in filters:
            if name != reference:
                case["wilcoxon"][name] = metrics.wilcoxon_p(ref, per_run_values(results, name, "position_rmse"))
    return case


def stack_series(results: list[dict], name: str, key: str) -> np.ndarray:
    """``(runs, K)`` per-step series ``key`` of filter ``name``."""
    return np.stack([r["filters"][name]["series"][key] for r in results])


def series_statistics(results: list[dict], filters: tuple[str, ...], runs: int, dof: int = 6,
                      subsample: int = 10) -> dict:
    """NEES band and coverage, co-state / ESS / error correlations and scatter points of one case."""
    band = metrics.chi2_band(dof, runs, NEES_PROBABILITY)
    out = {"nees_band": {"lower": band[0], "upper": band[1], "probability": NEES_PROBABILITY,
                         "dof": dof, "runs": runs},
           "nees_in_band": {}, "correlations": {}, "points": {}}
    for name in filters:
        nees = stack_series(results, name, "nees")
        out["nees_in_band"][name] = metrics.fraction_in_band(np.mean(nees, axis=0), band)
        if not registry.lookup(name).particles:
            continue
        ess = stack_series(results, name, "ess")
        costate = stack_series(results, name, "costate_norm")
        error = stack_series(results, name, "position_error")
        out["correlations"][name] = {
            "costate_vs_ess": {"pearson": metrics.correlation(costate, ess),
                               "spearman": metrics.rank_correlation(costate, ess)},
            "ess_vs_error": {"pearson": metrics.correlation(ess, error),
                             "spearman": metrics.rank_correlation(ess, error)},
        }
        out["points"][name] = {"ess": ess[:, ::subsample].ravel(), "costate": costate[:, ::subsample].ravel(),
                               "error": error[:, ::subsample].ravel()}
    return out


# --- Markdown ----------------------------------------------------------------------------------------
def table1(report: dict) -> list[str]:
    """Markdown lines of the position-RMSE table (filters by cases)."""
    cases = list(report["cases"])
    lines = ["| Filter | " + " | ".join(CASE_NAMES[c] for c in cases) + " |", "|---|" + "---|" * len(cases)]
    for name in report["settings"]["filters"]:
        lines.append(f"| {name} | " + " | ".join(
            _pm(report["cases"][c]["filters"][name]["position_rmse_km"]) for c in cases) + " |")
    return lines


def _pm(entry: dict | None, digits: int = 2) -> str:
    if not entry or entry.get("mean") is None:
        return "n/a"
    return f"{entry['mean']:.{digits}f} ± {entry['std']:.{digits}f}"


def _sig(entry: dict | None) -> str:
    if not entry or entry.get("mean") is None:
        return "n/a"
    return f"{entry['mean']:.3g} ± {entry['std']:.2g}"


def _p(value) -> str:
    return "n/a" if value is None else (f"{value:.1e}" if value < 1e-3 else f"{value:.3f}")


def markdown(report: dict) -> str:
    """The Markdown tables of a Monte Carlo report (as written to ``results.md``)."""
    s = report["settings"]
    cases = list(report["cases"])
    filters = s["filters"]
    lines = [f"# Monte Carlo results: {s['runs']} runs, N = {s['n_particles']}, seed {s['seed']}", ""]
    lines += [f"Command: `{report['meta']['command']}`  ",
              f"Commit: `{report['meta']['git_commit']}`; wall time {report['meta']['wall_seconds']:.0f} s "
              f"({report['meta']['workers'] or 'Dask'} workers).", "",
              "## Position RMSE (km), mean ± std over runs (the paper's Table 1)", ""]
    lines += table1(report)
    for c in cases:
        case = report["cases"][c]
        band = case.get("nees_band")
        lines += ["", f"## {CASE_NAMES[c]}", "",
                  "| Filter | vel. RMSE (m/s) | ESS/N | co-state norm | NEES | NEES in 95 % band | "
                  "failures (diverged / non-finite) | Wilcoxon p vs reference GPF |",
                  "|---|---|---|---|---|---|---|---|"]
        for name in filters:
            row = case["filters"][name]
            fail = case["failures"][name]
            in_band = case.get("nees_in_band", {}).get(name)
            lines.append(
                f"| {name} | {_pm(row['velocity_rmse_mps'])} | {_pm(row['ess'], 3)} | "
                f"{_sig(row['costate_norm'])} | {_sig(row['nees'])} | "
                f"{'n/a' if in_band is None or not np.isfinite(in_band) else f'{100 * in_band:.0f} %'} | "
                f"{fail['diverged']} / {fail['nonfinite']} of {fail['runs']} | "
                f"{'reference' if name == s['reference_filter'] else _p(case['wilcoxon'].get(name))} |")
        if band:
            lines += ["", f"NEES: time average per run, then mean ± std over runs. \"In band\": share of time "
                          f"steps at which the NEES averaged over the {band['runs']} runs lies in the 95 % "
                          f"chi-square band [{band['lower']:.2f}, {band['upper']:.2f}] of a consistent "
                          f"filter (6 dof)."]
        corr = case.get("correlations")
        if corr:
            lines += ["", "Per-step correlations (Pearson / Spearman, all steps of all runs):", "",
                      "| Filter | co-state norm vs ESS/N | ESS/N vs position error |", "|---|---|---|"]
            for name, cc in corr.items():
                lines.append(f"| {name} | {_r(cc['costate_vs_ess'])} | {_r(cc['ess_vs_error'])} |")
    lines += ["", f"Failures: position error above {s['divergence_km']:g} km at any step (diverged, kept in "
                  "the statistics) or a non-finite estimate / exception (non-finite, excluded). "
                  "Wilcoxon: paired signed-rank test, two-sided, on per-run position RMSE.", ""]
    return "\n".join(lines)


def _r(pair: dict) -> str:
    fmt = (lambda v: "n/a" if v is None else f"{v:+.2f}")
    return f"{fmt(pair['pearson'])} / {fmt(pair['spearman'])}"


# --- main ---------------------------------------------------------------------------------------------
def build_tasks(config: ScenarioConfig, cases, runs: int, seed: int, filters, n_particles: int,
                divergence_bound: float, series: bool) -> list[RunTask]:
    tasks = []
    for case in cases:
        case_config = dataclasses.replace(config, case=case)
        for run in range(runs):
            tasks.append(RunTask(index=len(tasks), run=run, seed=seed, config=case_config, filters=filters,
                                 n_particles=n_particles, series=series, divergence_bound=divergence_bound))
    return tasks


def campaign(config: ScenarioConfig, cases=("full", "partial"), runs: int = 100, seed: int = 0,
             filters=FILTERS, n_particles: int = N_PARTICLES, divergence_km: float = 1000.0,
             workers: int | None = None, scheduler: str | None = None, progress: bool = True,
             series: bool = True) -> tuple[dict, dict]:
    """Run the campaign; returns ``(report without meta, per-step data for the figures)``."""
    tasks = build_tasks(config, cases, runs, seed, tuple(filters), n_particles, divergence_km * 1e3, series)
    results = map_tasks(run_task, tasks, workers=workers, scheduler=scheduler, progress=progress,
                        description="Monte Carlo runs")
    reference = next((f for f in map(registry.label, ("gpf", "gpf-paper")) if f in filters), None)
    report = {"schema": SCHEMA,
              "settings": {"runs": runs, "seed": seed, "n_particles": n_particles, "filters": list(filters),
                           "reference_filter": reference, "divergence_km": divergence_km,
                           "ess_threshold": 0.5, "resampling": "systematic",
                           "statistics": "runs with a non-finite estimate excluded; diverged runs kept; "
                                         "std is the sample std (ddof=1) over runs",
                           "cases": {c: dataclasses.replace(config, case=c).to_dict() for c in cases}},
              "cases": {}, "per_run": {}}
    figures = {"times": None, "cases": {}}
    timing = {}
    for case in cases:
        case_results = [r for r in results if r["case"] == case]
        oracle = select_oracle(case_results, tuple(filters))
        summary = summarise_case(case_results, tuple(filters), reference)
        summary["oracle_multiplier"] = oracle
        summary["label"] = CASE_NAMES[case]
        report["per_run"][case] = {
            name: {"position_rmse_km": per_run_values(case_results, name, "position_rmse", 1e-3),
                   "velocity_rmse_mps": per_run_values(case_results, name, "velocity_rmse")}
            for name in filters}
        timing[case] = {name: float(np.mean([r["filters"][name]["seconds"] for r in case_results]))
                        for name in filters}
        if series:
            extra = series_statistics(case_results, tuple(filters), runs)
            figures["cases"][case] = {
                "position_error": {n: stack_series(case_results, n, "position_error") for n in filters},
                "ess": {n: stack_series(case_results, n, "ess") for n in filters if registry.lookup(n).particles},
                "nees": {n: stack_series(case_results, n, "nees") for n in filters},
                "points": extra.pop("points"), "correlations": extra["correlations"],
                "band": (extra["nees_band"]["lower"], extra["nees_band"]["upper"])}
            figures["times"] = case_results[0]["times"]
            summary.update(extra)
        report["cases"][case] = summary
    figures["seconds_per_run"] = timing
    return report, figures


def draw_figures(report: dict, figures: dict, out: Path) -> list[Path]:
    """Write the Monte Carlo figures into ``out``; returns their paths."""
    from gpf_nav.experiments import plots

    runs = report["settings"]["runs"]
    times = figures["times"]
    cases = figures["cases"]
    paths = [
        plots.error_evolution(times, {c: d["position_error"] for c, d in cases.items()}, runs,
                              out / "error_evolution.png"),
        plots.rmse_boxplot({c: {n: v["position_rmse_km"] for n, v in report["per_run"][c].items()}
                            for c in report["per_run"]}, out / "rmse_per_run.png"),
        plots.nees_evolution(times, {c: d["nees"] for c, d in cases.items()},
                             next(iter(cases.values()))["band"], runs, out / "nees.png"),
    ]
    if any(d["ess"] for d in cases.values()):
        paths.append(plots.ess_evolution(times, {c: d["ess"] for c, d in cases.items()}, runs,
                                         report["settings"]["ess_threshold"], out / "ess.png"))
    shown = tuple(map(registry.label, ("spf", "gpf", "gpf-paper", "gpf-printed")))
    degeneracy = {c: {n: p for n, p in d["points"].items() if n in shown}
                  for c, d in cases.items()}
    if any(degeneracy.values()):
        paths.append(plots.costate_degeneracy(degeneracy, {c: d["correlations"] for c, d in cases.items()},
                                              runs, out / "costate_degeneracy.png"))
    return paths


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = CommandParser(prog="gpf-nav montecarlo", description=__doc__.split("\n\n")[0],
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    add_common_arguments(parser, runs=100)
    parser.add_argument("--out", type=Path, default=Path("montecarlo-results"),
                        help="output directory (default ./montecarlo-results)")
    args = parser.parse_args(argv)
    try:
        config = base_config(args)
        filters = parse_filters(args.filters)
        cases = parse_cases(args.cases)
    except (ValueError, OSError) as err:
        parser.error(str(err))
    commit = git_commit()  # the code this process runs; read before a long campaign
    start = time.perf_counter()
    report, figures = campaign(config, cases, args.runs, args.seed, filters, args.particles,
                               args.divergence_km, args.workers, args.scheduler, not args.no_progress)
    wall = time.perf_counter() - start
    report["meta"] = run_metadata(args, wall, ["montecarlo"] + argv, commit)
    report["meta"]["seconds_per_run"] = figures["seconds_per_run"]
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(report, args.out / "results.json")
    (args.out / "results.md").write_text(markdown(report))
    written = [args.out / "results.json", args.out / "results.md"]
    if not args.no_plots:
        written += draw_figures(report, figures, args.out)
    print("Position RMSE (km), mean ± std over runs:")
    print("\n".join(table1(report)))
    print(f"\nwall time {wall:.1f} s; wrote " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
