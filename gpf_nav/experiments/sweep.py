"""``gpf-nav sweep --param mismatch|noise``: position RMSE against model mismatch or measurement noise.

* ``mismatch``: the truth's gravity is ``mu (1 + epsilon)`` and the filters keep ``mu``; epsilon runs
  over ``--values`` (default 0, 0.02, 0.05, 0.09, 0.14, 0.2). The paper's Table 1 uses 0.09.
* ``noise``: both measurement standard deviations (30 m range, 0.03 deg angles) are multiplied by
  ``measurement_noise_scale`` over ``--values`` (default 0.5, 1, 2, 5, 10, 20); the filters know the
  scaled noise.

Each point is ``--runs`` Monte Carlo runs (default 20) of every filter, both cases. Run ``r`` uses the
same random numbers at every point (paired design), so the curves differ only by the swept parameter.
Writes ``sweep_<param>.json`` (``values``, and ``cases -> case -> filters -> filter -> metric -> list of
{mean, std, n}`` with one entry per value, the position's with its worst run, plus failures) and
``sweep_<param>.png`` into ``--out``.
The co-state / degeneracy figure comes from ``gpf-nav montecarlo`` (it needs the per-step series).

``--merge REPORT`` re-runs only ``--filters`` and puts their rows into an earlier report of the same
sweep (same values, runs, seed, particles and scenario; refused otherwise), keeping its other rows: the
paired design makes each row independent of the others, so a changed filter need not cost a whole
campaign. The merged report's ``meta`` names the rows it re-ran and keeps the earlier ``meta``. Rows of
filters this version no longer knows (a renamed row) are dropped, and ``meta`` names them.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from gpf_nav import registry
from gpf_nav.arguments import CommandParser
from gpf_nav.experiments import metrics
from gpf_nav.experiments.montecarlo import (add_common_arguments, base_config, git_commit, parse_cases,
                                            parse_filters,
                                            per_run_values, run_metadata, write_json)
from gpf_nav.experiments.parallel import map_tasks
from gpf_nav.experiments.runner import RunTask, run_task, select_oracle
from gpf_nav.sim.scenario import ScenarioConfig

SCHEMA = "gpf_nav.sweep/2"
COLUMNS = {"position_rmse_km": ("position_rmse", 1e-3), "velocity_rmse_mps": ("velocity_rmse", 1.0),
           "nees": ("nees", 1.0), "ess": ("ess", 1.0)}
"""Per-point statistics: JSON key -> (run summary key, scale)."""
WORST_OF = "position_rmse_km"
"""The statistic whose points also name their worst run."""
PARAMETERS = {
    "mismatch": ("epsilon", (0.0, 0.02, 0.05, 0.09, 0.14, 0.2),
                 "gravity mismatch epsilon (truth mu(1+epsilon), filters mu)"),
    "noise": ("measurement_noise_scale", (0.5, 1.0, 2.0, 5.0, 10.0, 20.0),
              "measurement noise scale (x 30 m range, x 0.03 deg angles)"),
}


def sweep(param: str, values, config, cases, runs: int, seed: int, filters, n_particles: int,
          divergence_km: float, workers=None, scheduler=None, progress=True) -> dict:
    """Run the sweep; returns the report (without ``meta``)."""
    field, _, label = PARAMETERS[param]
    values = [float(v) for v in values]
    tasks = []
    for value in values:
        for case in cases:
            point = dataclasses.replace(config, case=case, **{field: value})
            for run in range(runs):
                tasks.append(RunTask(index=len(tasks), run=run, seed=seed, config=point, filters=tuple(filters),
                                     n_particles=n_particles, divergence_bound=divergence_km * 1e3,
                                     tag={"value": value}))
    results = map_tasks(run_task, tasks, workers=workers, scheduler=scheduler, progress=progress,
                        description=f"{param} sweep runs")
    report = {"schema": SCHEMA, "param": param, "field": field, "label": label, "values": values,
              "settings": settings(runs, seed, filters, n_particles, divergence_km, config), "cases": {}}
    for case in cases:
        entry = {"filters": {name: {key: [] for key in COLUMNS} for name in filters},
                 "failures": {name: [] for name in filters}, "oracle_multiplier": {}}
        for value in values:
            chunk = [r for r in results if r["case"] == case and r["tag"]["value"] == value]
            for family, multiplier in select_oracle(chunk, tuple(filters)).items():
                entry["oracle_multiplier"].setdefault(family, []).append(multiplier)
            for name in filters:
                rows = entry["filters"][name]
                for key, (summary_key, scale) in COLUMNS.items():
                    if summary_key == "ess" and not registry.lookup(name).particles:
                        rows[key].append({"mean": None, "std": None, "n": 0})
                    else:
                        rows[key].append(_statistics(chunk, name, key))
                entry["failures"][name].append({
                    "diverged": sum(bool(r["filters"][name]["diverged"]) for r in chunk),
                    "nonfinite": sum(bool(r["filters"][name]["nonfinite"]) for r in chunk)})
        report["cases"][case] = entry
    return report


def _statistics(chunk: list[dict], name: str, key: str) -> dict:
    """``{mean, std, n}`` of :data:`COLUMNS` ``key`` over the runs ``chunk`` (in run order) of filter ``name``; the
    position's also ``worst``: ``{run, value}`` of the run with the largest RMSE (absent when no run is finite)."""
    summary_key, scale = COLUMNS[key]
    values = per_run_values(chunk, name, summary_key, scale)
    point = metrics.mean_std(values)
    if key == WORST_OF and point["n"]:
        worst = int(np.nanargmax(values))
        point["worst"] = {"run": chunk[worst]["run"], "value": float(values[worst])}
    return point


def settings(runs: int, seed: int, filters, n_particles: int, divergence_km: float, config) -> dict:
    """The ``settings`` of a report."""
    return {"runs": runs, "seed": seed, "n_particles": n_particles, "filters": list(filters),
            "divergence_km": divergence_km,
            "statistics": "runs with a non-finite estimate excluded; diverged runs kept; "
                          "std is the sample std (ddof=1) over runs",
            "base_config": config.to_dict()}


MERGE_KEYS = ("runs", "seed", "n_particles", "divergence_km")
"""Settings two reports must share for their rows to be merged (and the scenario, ``base_config``)."""


def check_same_sweep(earlier: dict, param: str, values: list[float], cases, update_settings: dict) -> None:
    """Raise ValueError unless rows of a sweep of ``param`` over ``values`` and ``cases`` with
    ``update_settings`` can be merged into the report ``earlier``."""
    def scenario(s: dict) -> ScenarioConfig:  # a field added since the earlier report has its default
        return ScenarioConfig.from_dict(s["base_config"])

    same = (earlier.get("schema") == SCHEMA and earlier.get("param") == param
            and earlier.get("values") == [float(v) for v in values]
            and all(earlier["settings"].get(k) == update_settings[k] for k in MERGE_KEYS)
            and scenario(earlier["settings"]) == scenario(update_settings)
            and set(cases) <= set(earlier["cases"]))
    if not same:
        raise ValueError("the report to merge into is not the same sweep (param, values, cases, runs, seed, "
                         "particles and scenario must agree)")


def merge(earlier: dict, update: dict) -> dict:
    """``earlier`` with the rows of ``update``'s filters replaced (or added); raises ValueError when the
    two are not the same sweep."""
    check_same_sweep(earlier, update["param"], update["values"], update["cases"], update["settings"])
    merged = json.loads(json.dumps(earlier))
    names = update["settings"]["filters"]
    known = {e.label for e in registry.ENTRIES.values()}
    dropped = [f for f in merged["settings"]["filters"] if f not in known and f not in names]
    merged["settings"]["filters"] = list(dict.fromkeys(
        [f for f in merged["settings"]["filters"] if f not in dropped] + list(names)))
    for case, entry in update["cases"].items():
        target = merged["cases"][case]
        for name in dropped:
            target["filters"].pop(name, None)
            target["failures"].pop(name, None)
        for name in names:
            target["filters"][name] = entry["filters"][name]
            target["failures"][name] = entry["failures"][name]
        target["oracle_multiplier"].update(entry["oracle_multiplier"])
    merged["meta"] = dict(update.get("meta", {}), rerun=list(names), dropped=dropped, earlier=earlier.get("meta"))
    return merged


TABLES = {"position_rmse_km": "position RMSE (km)", "velocity_rmse_mps": "velocity RMSE (m/s)",
          "nees": "mean NEES (6 states; consistent: 6)"}


def markdown(report: dict) -> str:
    """Markdown tables (position, velocity, NEES): one row per filter, one column per value, per case."""
    lines = [f"# Sweep of {report['label']}: mean ± std over {report['settings']['runs']} runs", ""]
    for case, entry in report["cases"].items():
        for key, title in TABLES.items():
            lines += [f"## case `{case}`: {title}", "",
                      "| Filter | " + " | ".join(f"{v:g}" for v in report["values"]) + " |",
                      "|---|" + "---|" * len(report["values"])]
            for name, rows in entry["filters"].items():
                cells = []
                for r, f in zip(rows[key], entry["failures"][name]):
                    cell = "n/a" if r["mean"] is None else f"{r['mean']:.3g} ± {r['std']:.2g}"
                    if "worst" in r:  # (rows of reports before the worst run was kept have none)
                        cell += f"; worst {r['worst']['value']:.3g} (run {r['worst']['run']})"
                    if f["diverged"] or f["nonfinite"]:
                        cell += f" ({f['diverged']} div., {f['nonfinite']} NaN)"
                    cells.append(cell)
                lines.append(f"| {name} | " + " | ".join(cells) + " |")
            lines.append("")
        for family, multipliers in entry.get("oracle_multiplier", {}).items():
            lines.append(f"{family}: process-noise variance multiplier chosen per value: "
                         + ", ".join(f"{m:g}" for m in multipliers) + "  ")
        lines.append("")
    return "\n".join(lines)


def draw(report: dict, path: Path, reference_value: float | None = None) -> Path:
    """The sweep figure (position, velocity, NEES against the swept value) of a report."""
    from gpf_nav.experiments import plots

    tables = {title.split(" (")[0] if key == "nees" else title:
              {case: {name: rows[key] for name, rows in entry["filters"].items()}
               for case, entry in report["cases"].items()} for key, title in TABLES.items()}
    return plots.sweep(np.array(report["values"]), tables, report["label"], report["settings"]["runs"], path,
                       reference_value=reference_value)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = CommandParser(prog="gpf-nav sweep", description=__doc__.split("\n\n")[0],
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--param", required=True, choices=sorted(PARAMETERS), help="what to sweep")
    parser.add_argument("--values", default=None,
                        help="comma-separated values (default: see the description of --param)")
    add_common_arguments(parser, runs=20)
    parser.add_argument("--out", type=Path, default=Path("sweep-results"),
                        help="output directory (default ./sweep-results)")
    parser.add_argument("--merge", type=Path, default=None, metavar="REPORT",
                        help="an earlier sweep_<param>.json of the same sweep: re-run only --filters and "
                             "write that report with their rows replaced")
    args = parser.parse_args(argv)
    field, defaults, label = PARAMETERS[args.param]
    try:
        values = [float(v) for v in args.values.split(",")] if args.values else list(defaults)
    except ValueError:
        parser.error(f"--values must be comma-separated numbers, got {args.values!r}")
    try:
        config = base_config(args)
        cases, filters = parse_cases(args.cases), parse_filters(args.filters)
    except (ValueError, OSError) as err:
        parser.error(str(err))
    earlier = None
    if args.merge:  # checked before the campaign, not after it
        try:
            earlier = json.loads(args.merge.read_text())
            check_same_sweep(earlier, args.param, values, cases, json.loads(json.dumps(settings(
                args.runs, args.seed, filters, args.particles, args.divergence_km, config))))
        except (ValueError, OSError, KeyError, TypeError, AttributeError) as err:
            parser.error(f"--merge {args.merge}: {err}")
    commit = git_commit()  # the code this process runs; read before a long campaign
    start = time.perf_counter()
    report = sweep(args.param, values, config, cases, args.runs, args.seed, filters, args.particles,
                   args.divergence_km, args.workers, args.scheduler, not args.no_progress)
    wall = time.perf_counter() - start
    report["meta"] = run_metadata(args, wall, ["sweep"] + argv, commit)
    if earlier is not None:
        report = merge(earlier, json.loads(json.dumps(report)))
    args.out.mkdir(parents=True, exist_ok=True)
    json_path = args.out / f"sweep_{args.param}.json"
    md_path = args.out / f"sweep_{args.param}.md"
    write_json(report, json_path)
    md_path.write_text(markdown(report))
    written = [json_path, md_path]
    if not args.no_plots:
        written.append(draw(report, args.out / f"sweep_{args.param}.png", getattr(config, field)))
    print(markdown(report))
    print(f"wall time {wall:.1f} s; wrote " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
