"""Ground tracking alone against the descent's full sensor suite (``gpf-nav sensors``).

Each Monte Carlo run flies one scenario twice per filter: ``rae`` fuses the station's range, azimuth and
elevation only; ``full`` also fuses the suite of :mod:`gpf_nav.sim.sensor_suite` (altimeter, TRN position
fixes delivered late, velocimeter). A late TRN fix is fused at its stamp: the run keeps the filter as it
was at the fix's capture (a copy, random generator included) and, when the fix arrives, fuses it there
and re-applies what came after, as an estimator replaying its history does; the estimate scored at each
step is the one available then (before a fix arrives, without it). A fix far from the estimate at its
stamp (chi-square quantile ``--fix-gate``) is refused whole, as a navigation system checks a TRN fix
before it uses it; the filters' own gates act per component. The report gives the position and
velocity errors against time (and the mean altitude), their RMSE over the whole run and over its second
half, and the mean NEES of the six states.

    gpf-nav sensors --runs 20 --out sensors-results
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scipy.stats import chi2

from gpf_nav import registry
from gpf_nav.arguments import CommandParser, positive_float, positive_int
from gpf_nav.experiments import metrics, plots
from gpf_nav.experiments.montecarlo import git_commit, parse_filters, write_json
from gpf_nav.experiments.parallel import map_tasks
from gpf_nav.experiments.runner import make_filter, run_seeds
from gpf_nav.filters import SensorBiasFilter
from gpf_nav.filters.gating import OUTLIER_GATE_LIMIT
from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.models.lunar import MOON_RADIUS
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate
from gpf_nav.sim.sensor_suite import SuiteConfig, SuiteData, generate_suite, suite_sensors
from gpf_nav.sensors import ModelSensor, innovation_distance, random_constant_bias

SCHEMA = "gpf_nav.sensor_campaign/1"
MODES = ("rae", "full")
DEFAULT_FILTERS = (registry.label("gpf"), registry.label("ekf-comp-gated"))
FIX_GATE = 0.999
"""Default chi-square quantile of the campaign's whole-fix gate (:func:`fuse`)."""
_SAME_TIME = 1e-9  # s: a fix arriving within this of a step arrives at that step


def fuse(flt, scenario, suite: SuiteData | None, fix_gate: float = 0.0) -> dict:
    """Run ``flt`` from the scenario's prior over its steps, with the suite's data when ``suite`` is given.

    At each step ``k``: ``predict``, the range/azimuth/elevation, then the altitude and the velocity when
    measured; TRN fixes are fused at their stamp when they arrive (module docstring). ``fix_gate`` in
    [0, 1): a fix whose squared Mahalanobis distance from the estimate at its stamp
    (:func:`~gpf_nav.sensors.sensor.innovation_distance`) is beyond this quantile of the chi-square law
    with three degrees of freedom is refused, unless the previous ``OUTLIER_GATE_LIMIT`` fixes were (then
    the estimate, not the fix, is taken to be off); 0 fuses every fix. Returns the per-step
    ``position_error`` (m), ``velocity_error`` (m/s), ``nees`` (six states), ``fixes`` (TRN fixes fused),
    ``refused`` (fixes refused by ``fix_gate``), ``gated`` (components the filter's own gate refused),
    ``seconds``, ``error`` (a message if the filter raised or went non-finite, else None) and
    ``range_bias`` (the final estimate of a range bias and its sigma, m, when ``flt`` estimates one).
    """
    steps, dt = scenario.times.shape[0], scenario.config.dt
    sensors = suite_sensors(suite.config) if suite is not None else {}
    captured = (np.flatnonzero(np.isfinite(suite.position_arrival)) if suite is not None
                else np.zeros(0, int))
    errors = np.full((steps, 6), np.nan)
    covariances = np.full((steps, 6, 6), np.nan)
    pending: dict[int, object] = {}  # capture step -> the filter as it was then (fix not yet delivered)
    fused = 0
    refused: dict[int, bool] = {}  # capture step -> refused by fix_gate (a replay decides again)
    limit = chi2.ppf(fix_gate, 3) if fix_gate > 0.0 else math.inf
    error = None

    def step(f, k: int) -> None:
        f.predict(dt, scenario.specific_force[k])
        f.update(scenario.measurements[k])
        if suite is not None:
            for name, y in (("altitude", suite.altitude[k]), ("velocity", suite.velocity[k])):
                if np.isfinite(y).any():
                    f.update(y, sensors[name])

    def deliver(f, k: int, now: float):
        """After step ``k``'s own measurements: fuse a fix captured at ``k`` that has arrived by ``now``,
        else keep the filter for when it does. Returns the number of fixes fused."""
        if k not in capture_set:
            return 0
        if suite.position_arrival[k] <= now + _SAME_TIME:
            pending.pop(k, None)
            earlier = [refused[c] for c in sorted(refused) if c < k][-OUTLIER_GATE_LIMIT:]
            d2 = innovation_distance(sensors["position"], suite.position[k], f.mean, f.covariance)[0]
            refused[k] = d2 > limit and not (len(earlier) == OUTLIER_GATE_LIMIT and all(earlier))
            if refused[k]:
                return 0
            f.update(suite.position[k], sensors["position"])
            return 1
        pending[k] = copy.deepcopy(f)
        return 0

    capture_set = set(captured.tolist())
    start = time.perf_counter()
    try:
        flt.initialize(scenario.prior_mean, scenario.prior_cov)
        for k in range(steps):
            now = float(scenario.times[k])
            step(flt, k)
            fused += deliver(flt, k, now)
            due = [c for c in pending if suite.position_arrival[c] <= now + _SAME_TIME]
            if due:  # replay from the oldest fix that arrived
                first = min(due)
                flt = pending.pop(first)
                fused += deliver(flt, first, now)
                for i in range(first + 1, k + 1):
                    step(flt, i)
                    fused += deliver(flt, i, now)
            mean = np.asarray(flt.mean)
            if not np.isfinite(mean).all():
                error = f"non-finite estimate at step {k}"
                break
            errors[k] = mean - scenario.truth[k + 1]
            covariances[k] = flt.covariance
    except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        error = f"{type(exc).__name__}: {exc}"
    return {"position_error": np.linalg.norm(errors[:, :3], axis=1),
            "velocity_error": np.linalg.norm(errors[:, 3:], axis=1),
            "nees": metrics.nees(errors, covariances), "fixes": fused, "refused": sum(refused.values()),
            "gated": int(flt.gated), "seconds": time.perf_counter() - start, "error": error,
            "range_bias": (tuple(float(v[0]) for v in flt.sensor_bias("rae"))
                           if "rae" in flt.sensor_names else None)}


@dataclass(frozen=True)
class SuiteTask:
    """One run: scenario ``config`` and ``suite`` settings, run ``run`` of a campaign seeded ``seed``;
    ``fix_gate`` as :func:`fuse`'s; ``range_bias_std`` > 0: every filter estimates a constant range
    bias of that prior std (m) as a state (:class:`~gpf_nav.filters.SensorBiasFilter`)."""

    index: int
    run: int
    seed: int
    config: ScenarioConfig
    suite: SuiteConfig
    filters: tuple[str, ...] = DEFAULT_FILTERS
    n_particles: int = N_PARTICLES
    fix_gate: float = FIX_GATE
    range_bias_std: float = 0.0


def run_task(task: SuiteTask) -> dict:
    """Both modes of every filter on the run's scenario: ``{"index", "run", "times", "altitude",
    "outliers", "filters": {name: {mode: fuse(...)}}}``. Both modes and all filters share the scenario,
    the suite's data and the filters' seed (common random numbers)."""
    scenario_seed, filter_seed = run_seeds(task.seed, task.run)
    scenario = generate(task.config, scenario_seed)
    suite = generate_suite(scenario, task.suite, scenario_seed)
    out = {"index": task.index, "run": task.run, "times": scenario.times,
           "altitude": np.linalg.norm(scenario.truth[1:, :3], axis=1) - MOON_RADIUS,
           "outliers": int(suite.position_outlier.sum()), "filters": {}}
    model = filter_model(task.config)
    for name in task.filters:
        out["filters"][name] = {
            mode: fuse(_build(name, model, task, filter_seed), scenario, suite if mode == "full" else None,
                       task.fix_gate)
            for mode in MODES}
    return out


def _build(name: str, model, task: SuiteTask, seed: int):
    """Filter ``name`` on ``model``, with a range-bias state when ``task.range_bias_std`` > 0."""
    if not task.range_bias_std:
        return make_filter(name, model, task.n_particles, seed)
    rae = ModelSensor(model, "rae", bias=random_constant_bias([task.range_bias_std, 0.0, 0.0]))
    return SensorBiasFilter(lambda m: make_filter(name, m, task.n_particles, seed), model, [rae])


def _rmse(series: np.ndarray) -> float:
    return metrics.rmse(series) if np.isfinite(series).all() else math.nan


def summarise(results: list[dict], filters: tuple[str, ...]) -> dict:
    """Per filter and mode: mean and std over runs of the position RMSE (m) over the run and its second
    half, the velocity RMSE (m/s) over the second half, the mean NEES, fixes fused and outliers gated;
    and per filter the ratio full / rae of the second-half position RMSE (of the means, and the largest
    per run). Runs whose estimate went non-finite are counted and left out."""
    steps = results[0]["times"].shape[0]
    second = slice(steps // 2, steps)
    out = {}
    for name in filters:
        entry = {}
        for mode in MODES:
            runs = [r["filters"][name][mode] for r in results]
            good = [s for s in runs if s["error"] is None]
            entry[mode] = {
                "position_rmse_m": metrics.mean_std([_rmse(s["position_error"]) for s in good]),
                "position_rmse_second_half_m": metrics.mean_std([_rmse(s["position_error"][second])
                                                                 for s in good]),
                "velocity_rmse_second_half_mps": metrics.mean_std([_rmse(s["velocity_error"][second])
                                                                   for s in good]),
                "nees": metrics.mean_std([metrics.time_average(s["nees"]) for s in good]),
                "fixes": metrics.mean_std([s["fixes"] for s in good]),
                "refused": metrics.mean_std([s["refused"] for s in good]),
                "gated": metrics.mean_std([s["gated"] for s in good]),
                "range_bias_m": metrics.mean_std([s["range_bias"][0] for s in good if s["range_bias"]]),
                "range_bias_sigma_m": metrics.mean_std([s["range_bias"][1] for s in good if s["range_bias"]]),
                "failed_runs": len(runs) - len(good),
                "seconds": float(np.mean([s["seconds"] for s in runs])),
            }
        pairs = [(_rmse(r["filters"][name]["full"]["position_error"][second]),
                  _rmse(r["filters"][name]["rae"]["position_error"][second])) for r in results]
        ratios = [a / b for a, b in pairs if math.isfinite(a) and math.isfinite(b) and b > 0]
        entry["second_half_position_ratio"] = {
            "of_means": (entry["full"]["position_rmse_second_half_m"]["mean"]
                         / entry["rae"]["position_rmse_second_half_m"]["mean"]),
            "largest_per_run": max(ratios) if ratios else math.nan}
        out[name] = entry
    return out


def campaign(config: ScenarioConfig, suite: SuiteConfig, runs: int = 20, seed: int = 0,
             filters: tuple[str, ...] = DEFAULT_FILTERS, n_particles: int = N_PARTICLES,
             workers: int | None = None, progress: bool = True, fix_gate: float = FIX_GATE,
             range_bias_std: float = 0.0) -> tuple[dict, dict]:
    """Run the campaign; returns ``(report, per-step data for the figure)``."""
    tasks = [SuiteTask(i, i, seed, config, suite, tuple(filters), n_particles, fix_gate, range_bias_std)
             for i in range(runs)]
    results = map_tasks(run_task, tasks, workers=workers, progress=progress, description="sensor-suite runs")
    report = {"schema": SCHEMA,
              "settings": {"runs": runs, "seed": seed, "n_particles": n_particles, "filters": list(filters),
                           "fix_gate": fix_gate, "range_bias_std_m": range_bias_std,
                           "scenario_range_bias_m": config.measurement_bias_sigma[0] * config.range_noise_std
                                                    * config.measurement_noise_scale,
                           "scenario": config.to_dict(), "suite": dataclasses.asdict(suite),
                           "second_half_from_s": float(results[0]["times"][results[0]["times"].shape[0] // 2]),
                           "outlier_fixes_mean": float(np.mean([r["outliers"] for r in results]))},
              "filters": summarise(results, tuple(filters))}
    series = {name: {mode: {key: np.vstack([r["filters"][name][mode][key] for r in results])
                            for key in ("position_error", "velocity_error")} for mode in MODES}
              for name in filters}
    figure = {"times": results[0]["times"], "altitude": np.mean([r["altitude"] for r in results], axis=0),
              "series": series}
    return report, figure


def markdown(report: dict) -> str:
    """The campaign's table (Markdown)."""
    s = report["settings"]
    gate = f"TRN fix gate at the {s['fix_gate']} chi-square quantile" if s["fix_gate"] else "no TRN fix gate"
    if s["range_bias_std_m"]:
        gate += (f"; range bias {s['scenario_range_bias_m']:.0f} m, estimated (a constant of prior std "
                 f"{s['range_bias_std_m']:.0f} m)")
    lines = [f"{s['runs']} runs, seed {s['seed']}, {s['n_particles']} particles, {gate}; second half from "
             f"t = {s['second_half_from_s']:.0f} s; {s['outlier_fixes_mean']:.1f} outlier TRN fixes per run "
             f"on average.", "",
             "| filter | sensors | position RMSE (m) | 2nd half position RMSE (m) | 2nd half velocity RMSE "
             "(m/s) | mean NEES (6 states) | TRN fixes fused / refused | components gated |",
             "|---|---|---|---|---|---|---|---|"]
    for name, entry in report["filters"].items():
        for mode in MODES:
            e = entry[mode]
            pm = lambda d, f="{:.0f}": f"{f.format(d['mean'])} ± {f.format(d['std'])}"  # noqa: E731
            sensors = "rae only" if mode == "rae" else "full suite"
            lines.append(f"| {name} | {sensors} | {pm(e['position_rmse_m'])} "
                         f"| {pm(e['position_rmse_second_half_m'])} "
                         f"| {pm(e['velocity_rmse_second_half_mps'], '{:.3f}')} | {pm(e['nees'], '{:.1f}')} "
                         f"| {e['fixes']['mean']:.0f} / {e['refused']['mean']:.1f} | {e['gated']['mean']:.1f} |")
    lines.append("")
    for name, entry in report["filters"].items():
        ratio = entry["second_half_position_ratio"]
        lines.append(f"- {name}: second-half position RMSE, full suite / rae only = {ratio['of_means']:.3f} "
                     f"(of the means; largest single run {ratio['largest_per_run']:.3f}).")
        for mode in MODES if s["range_bias_std_m"] else ():
            bias, sigma = entry[mode]["range_bias_m"], entry[mode]["range_bias_sigma_m"]
            lines.append(f"  - {'rae only' if mode == 'rae' else 'full suite'}: final range-bias estimate "
                         f"{bias['mean']:.1f} ± {bias['std']:.1f} m over the runs, its sigma "
                         f"{sigma['mean']:.1f} m (the truth's: {s['scenario_range_bias_m']:.0f} m).")
    return "\n".join(lines) + "\n"


def draw_figure(report: dict, figure: dict, path: Path) -> Path:
    """Position and velocity error against time (RMS over runs), rae only and full suite, with the mean
    altitude on the top axis."""
    plt = plots.pyplot()
    times, altitude = figure["times"], figure["altitude"]
    fig, axes = plt.subplots(1, 2, figsize=(13.0, 5.0), layout="constrained")
    colours = ["#000000", "#bcbd22", "#1f77b4", "#d62728"]
    for (name, modes), colour in zip(figure["series"].items(), colours):
        for mode, style in zip(MODES, (":", "-")):
            label = f"{name}, {'rae only' if mode == 'rae' else 'full suite'}"
            for ax, key in zip(axes, ("position_error", "velocity_error")):
                rms = np.sqrt(np.nanmean(modes[mode][key] ** 2, axis=0))
                ax.plot(times, rms, style, color=colour, lw=1.3, label=label)
    for ax, unit in zip(axes, ("position error (m)", "velocity error (m/s)")):
        ax.set_yscale("log")
        ax.set_xlabel("time since apolune (s)")
        ax.set_ylabel(f"RMS over runs of the {unit}")
        ax.axvline(report["settings"]["second_half_from_s"], color="grey", lw=0.8, alpha=0.6)
        ax.grid(True, which="both", alpha=0.3)
        top = ax.secondary_xaxis("top", functions=(lambda t: np.interp(t, times, altitude) / 1e3,
                                                   lambda a: np.interp(a * 1e3, altitude[::-1], times[::-1])))
        top.set_xticks(np.arange(10.0 * math.ceil(altitude.min() / 1e4), altitude.max() / 1e3 + 1e-9, 10.0))
        top.set_xlabel("mean altitude (km)")
    axes[0].legend(fontsize=8)
    s = report["settings"]
    fig.suptitle(f"Range/azimuth/elevation only against the full sensor suite: RMS of {s['runs']} runs "
                 f"(the grey line starts the second half)", fontsize=10)
    return plots.save(fig, path)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = CommandParser(prog="gpf-nav sensors", description=__doc__.split("\n\n")[0],
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=positive_int, default=20, help="Monte Carlo runs (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    parser.add_argument("--workers", type=positive_int, default=None, help="worker processes (default: cores)")
    parser.add_argument("--duration", type=positive_float, default=None, help="run length, s (default 2400)")
    parser.add_argument("--case", default="full", help="scenario case of the rae data (full, partial, range)")
    parser.add_argument("--particles", type=positive_int, default=N_PARTICLES,
                        help=f"particles / ensemble members (default {N_PARTICLES})")
    parser.add_argument("--filters", default=None,
                        help="comma-separated filters, short names as montecarlo's (default gpf,ekf-comp-gated)")
    parser.add_argument("--suite", action="append", default=[], metavar="KEY=VALUE",
                        help="a sensor-suite setting (gpf_nav.sim.sensor_suite.SuiteConfig), e.g. trn_latency=4")
    parser.add_argument("--fix-gate", type=float, default=FIX_GATE, metavar="P",
                        help="refuse a TRN fix beyond this chi-square (3 dof) quantile of its Mahalanobis "
                             f"distance; 0 fuses every fix (default {FIX_GATE})")
    parser.add_argument("--range-bias", type=float, default=0.0, metavar="SIGMAS",
                        help="a constant range bias in the data, in range sigmas (the scenario's "
                             "measurement_bias_sigma)")
    parser.add_argument("--estimate-range-bias", type=float, default=0.0, metavar="STD",
                        help="every filter estimates a constant range bias of this prior std, m (0: none)")
    parser.add_argument("--out", type=Path, default=Path("sensors-results"), help="output directory")
    parser.add_argument("--no-plots", action="store_true", help="do not draw the figure")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    try:
        overrides = ({"case": args.case, "measurement_bias_sigma": (args.range_bias, 0.0, 0.0)}
                     | ({"duration": args.duration} if args.duration else {}))
        if not (math.isfinite(args.estimate_range_bias) and args.estimate_range_bias >= 0.0):
            raise ValueError(f"--estimate-range-bias must be a non-negative std, got {args.estimate_range_bias}")
        config = dataclasses.replace(ScenarioConfig(), **overrides)
        bad = [item for item in args.suite if "=" not in item]
        if bad:
            raise ValueError(f"--suite: expected KEY=VALUE, got {bad[0]!r}")
        suite = SuiteConfig.from_dict(dict(item.split("=", 1) for item in args.suite))
        suite.check_grid(config.dt)
        if not 0.0 <= args.fix_gate < 1.0:
            raise ValueError(f"--fix-gate must lie in [0, 1), got {args.fix_gate}")
        filters = parse_filters(args.filters) if args.filters else DEFAULT_FILTERS
    except (ValueError, TypeError) as err:
        parser.error(str(err))
    commit = git_commit()
    start = time.perf_counter()
    report, figure = campaign(config, suite, args.runs, args.seed, filters, args.particles, args.workers,
                              not args.no_progress, args.fix_gate, args.estimate_range_bias)
    report["meta"] = {"command": "gpf-nav sensors " + " ".join(argv), "commit": commit,
                      "wall_seconds": time.perf_counter() - start}
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(report, args.out / "results.json")
    (args.out / "results.md").write_text(markdown(report))
    written = [args.out / "results.json", args.out / "results.md"]
    if not args.no_plots:
        written.append(draw_figure(report, figure, args.out / "sensor_suite.png"))
    print(markdown(report))
    print(f"wall time {report['meta']['wall_seconds']:.1f} s; wrote " + ", ".join(str(p) for p in written))
    return 0
