"""``gpf-nav honesty``: is each estimator's covariance honest where the data cannot determine the state?

Conditions (changes of the base scenario, ``docs/scenario.md``; exact gravity unless a condition says
otherwise):

* controls, where the data determine the state: the full case (``full``), the full case with the 9 %
  gravity mismatch (``full-mismatch``), range only (``range-only``; its three rotations about the Moon's
  centre are undetermined, but the prior is the usual 1 km / 1 m/s), no azimuth with the mismatch
  (``partial-mismatch``, Table 1's Case 2);
* undetermined: a 20 km / 20 m/s prior with range only (``large-prior-range``) or without azimuth
  (``large-prior-partial``), range only with the 9 % mismatch (``range-only-mismatch``), and an unmodelled
  force fixed in inertial space (0.1 m/s^2, ``docs/results.md``) without azimuth (``partial-force``).

Per condition and filter: position and velocity RMSE, mean NEES (6 states), the share of steps whose NEES
is above the chi-square 99.9 % bound of 6 dof (22.46), the worst run; the observability report's
verdicts after the first 100 s (share of updates with an undetermined direction, share where it named the
scenario's known undetermined subspace: the rotations about the centre, the rotation about the polar
axis, or none); and the consistency monitor's detections (:mod:`gpf_nav.integrity.consistency`: share of
updates at ``FAULT``, runs with one, median time of the first). Writes ``honesty.json`` and
``honesty.md`` into ``--out``.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from gpf_nav.arguments import CommandParser, positive_int
from gpf_nav.experiments.montecarlo import base_config, git_commit, parse_filters, run_metadata, write_json
from gpf_nav.experiments.parallel import add_campaign_arguments
from gpf_nav.experiments.runner import NEES_BOUND, REPORT_AFTER
from gpf_nav.experiments.stress import BEYOND, GRAVITY, _num, stress
from gpf_nav.filters.interface import N_PARTICLES

SCHEMA = "gpf_nav.honesty/1"
DEFAULT_FILTERS = "gpf,gpf-single,ekf-comp-gated,ekf,gpf-paper"
INERTIAL_FORCE = (0.0, 0.06, -0.08)
"""The unmodelled force of ``partial-force``, m/s^2 (the inertial-force campaign's, docs/results.md)."""
CONTROLS = {
    "full": ("full case (control)", {}),
    "full-mismatch": ("full case, 9 % gravity mismatch (control)", {"epsilon": 0.09}),
    "range-only": ("range only, usual prior (control)", {"case": "range"}),
    "partial-mismatch": ("no azimuth, 9 % mismatch (control: Case 2)", {"case": "partial", "epsilon": 0.09}),
}
UNDETERMINED = {
    "large-prior-range": BEYOND["large-prior-range"],
    "large-prior-partial": BEYOND["large-prior-partial"],
    "range-only-mismatch": BEYOND["range-only-mismatch"],
    "partial-force": ("no azimuth, unmodelled 0.1 m/s^2 inertial force",
                      {"case": "partial", "disturbance": INERTIAL_FORCE}),
}
CONDITIONS = {**CONTROLS, **UNDETERMINED, **GRAVITY}


def markdown(report: dict) -> str:
    """The campaign's table: a row per condition and filter."""
    s = report["settings"]
    lines = [f"# Honesty campaign: {s['runs']} runs per condition, N = {s['n_particles']}, seed {s['seed']}", ""]
    meta = report.get("meta")
    if meta:
        lines += [f"Command: `{meta['command']}`  ", f"Commit: `{meta['git_commit']}`; wall time "
                  f"{meta['wall_seconds']:.0f} s ({meta['workers'] or 'Dask'} workers).", ""]
    lines += ["| condition | filter | position RMSE (m) | velocity RMSE (m/s) | NEES | steps above bound | "
              "worst run: # (m) | undetermined after 100 s | named | monitor FAULT: updates / runs / "
              "median first (s) |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for entry in report["conditions"].values():
        for first, (name, row) in zip([True] + [False] * len(entry["filters"]), entry["filters"].items()):
            worst = row["worst_run"]
            worst = "n/a" if worst is None else f"{worst['run']} ({worst['position_rmse']:.3g})"
            lines.append(
                f"| {entry['label'] if first else ''} | {name} | {_num(row['position_rmse_mean'])} | "
                f"{_num(row['velocity_rmse_mean'])} | {_num(row['nees_mean'])} | "
                f"{_num(row['above_bound_mean'], 2)} | {worst} | {_num(row['undetermined_share_mean'], 3)} | "
                f"{_num(row['named_share_mean'], 3)} | {_num(row['consistency_fault_share'], 2)} / "
                f"{row['consistency_fault_runs']} / {_num(row['first_fault_median'], 4)} |")
    lines += ["", f"NEES: time average per run, then the mean over runs (consistent: 6). Steps above bound: "
                  f"share of steps with NEES above {NEES_BOUND} (chi-square 99.9 %, 6 dof; 0.001 when "
                  f"consistent). Undetermined: share of updates after {REPORT_AFTER:g} s whose observability "
                  "report has an undetermined direction; named: share where it is exactly the scenario's "
                  "undetermined subspace (the three rotations about the centre for range only, the rotation "
                  "about the polar axis without azimuth, none for the full case). Monitor: the consistency "
                  "monitor at a set false-alarm rate of 1e-3 per update."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = CommandParser(prog="gpf-nav honesty", description=__doc__.split("\n\n")[0],
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    add_campaign_arguments(parser, 20, "runs per condition")
    parser.add_argument("--config", type=Path, default=None,
                        help="base scenario YAML (default: the built-in defaults, epsilon set to 0)")
    parser.add_argument("--duration", type=float, default=None, help="override the duration (s)")
    parser.add_argument("--dt", type=float, default=None, help="override the filter step (s)")
    parser.add_argument("--particles", type=positive_int, default=N_PARTICLES,
                        help=f"particles per particle filter (default {N_PARTICLES})")
    parser.add_argument("--filters", default=DEFAULT_FILTERS,
                        help=f"comma-separated short names (default {DEFAULT_FILTERS})")
    parser.add_argument("--conditions", default=",".join(CONDITIONS),
                        help=f"comma-separated conditions (default all: {', '.join(CONDITIONS)})")
    parser.add_argument("--out", type=Path, default=Path("honesty-results"),
                        help="output directory (default ./honesty-results)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    try:
        config = dataclasses.replace(base_config(args), epsilon=0.0)
        filters = parse_filters(args.filters)
        names = [n.strip() for n in args.conditions.split(",") if n.strip()]
        unknown = [n for n in names if n not in CONDITIONS]
        if unknown or not names:
            raise ValueError(f"--conditions: unknown {unknown}; known: {', '.join(CONDITIONS)}")
        selected = {name: CONDITIONS[name] for name in names}
        for _, changes in selected.values():  # refused now, not after the campaign
            dataclasses.replace(config, **changes)
    except (ValueError, OSError) as err:
        parser.error(str(err))
    commit = git_commit()
    start = time.perf_counter()
    report = stress(config, selected, args.runs, args.seed, filters, args.particles, 10.0, args.workers,
                    args.scheduler, not args.no_progress)
    report["schema"] = SCHEMA
    wall = time.perf_counter() - start
    report["meta"] = run_metadata(args, wall, ["honesty"] + argv, commit)
    args.out.mkdir(parents=True, exist_ok=True)
    json_path, md_path = args.out / "honesty.json", args.out / "honesty.md"
    write_json(report, json_path)
    md_path.write_text(markdown(report))
    print(markdown(report))
    print(f"wall time {wall:.1f} s; wrote {json_path}, {md_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
