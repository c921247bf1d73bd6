"""Soak test: simulator -> fault injector -> estimator over DDS for a long simulated run.

    python -m gpf_nav.tools.soak [--sim-minutes 30] [--rate-factor 10] [--seed 0] [--json]

The estimator runs in its own process on simulated time; between the simulator and it, an injector drops,
delays, duplicates and masks measurements, adds garbage, and optionally restarts the simulator, sends a
burst of late measurements or forces an integrity fault. At the end every message sent must be counted by
the estimator under the verdict its own rules predict, no output may carry NaN or inf, and the estimate
must follow the truth. See docs/soak.md. This module is the command line; the parts:

* :mod:`gpf_nav.tools.soak_ledger`: what was sent and the verdict the estimator must give each message;
* :mod:`gpf_nav.tools.soak_injector`: the node that tampers with the measurement stream;
* :mod:`gpf_nav.tools.soak_listener`: the node that checks every estimator output;
* :mod:`gpf_nav.tools.soak_run`: the estimator process, the simulator and the loop that drives them;
* :mod:`gpf_nav.tools.soak_report`: the checks (pass/fail) and the summary table.
"""
from __future__ import annotations

import argparse
import json
import sys

from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.tools.soak_report import format_summary
from gpf_nav.tools.soak_run import run


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m gpf_nav.tools.soak", description=__doc__.split("\n\n")[0])
    ap.add_argument("--sim-minutes", type=float, default=30.0, help="simulated minutes (default 30)")
    ap.add_argument("--rate-factor", type=float, default=10.0, help="simulated s per wall s (default 10)")
    ap.add_argument("--seed", type=int, default=0, help="injector and scenario seed (default 0)")
    ap.add_argument("--filter", default="gpf", help="estimator filter (default gpf)")
    ap.add_argument("--particles", type=int, default=N_PARTICLES, help=f"N (default {N_PARTICLES})")
    ap.add_argument("--epsilon", type=float, default=0.0,
                    help="scenario gravity mismatch (default 0: a consistent model, so an integrity alarm "
                         "would come from the injected disorder; 0.09 is the simulator's default)")
    ap.add_argument("--warmup", type=float, default=120.0,
                    help="simulated s before injection starts and the start RSS is read (default 120)")
    ap.add_argument("--drop", type=float, default=0.03, help="P(measurement dropped) (default 0.03)")
    ap.add_argument("--delay", type=float, default=0.03, help="P(measurement delayed/reordered) (default 0.03)")
    ap.add_argument("--duplicate", type=float, default=0.03, help="P(measurement sent twice) (default 0.03)")
    ap.add_argument("--mask", type=float, default=0.02, help="P(range replaced by NaN) (default 0.02)")
    ap.add_argument("--garbage", type=float, default=0.10, help="P(one garbage message after it) (default 0.1)")
    ap.add_argument("--burst", type=float, default=0.01, help="P(a garbage burst after it) (default 0.01)")
    ap.add_argument("--burst-size", type=int, default=20, help="messages per burst (default 20)")
    ap.add_argument("--queue-depth", type=int, default=100,
                    help="estimator queue_depth (default 100; the default 10 lets DDS shed part of a burst "
                         "before the node sees it, uncounted)")
    ap.add_argument("--rss-period", type=float, default=5.0, help="wall s between RSS samples (default 5)")
    ap.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: the environment's)")
    ap.add_argument("--timeout", type=float, default=None, help="wall-clock limit, s (default: generous)")
    ap.add_argument("--max-error", type=float, default=2000.0,
                    help="largest median position error over the second half of the run, m (default 2000)")
    ap.add_argument("--max-imu-loss", type=float, default=0.01,
                    help="largest fraction of the simulator's IMU samples the estimator may not count "
                         "(default 0.01: a node that keeps up loses none)")
    ap.add_argument("--keep-log", action="store_true",
                    help="keep the estimator's log file (it is kept anyway when the soak fails)")
    ap.add_argument("--restart-at", type=float, default=None, help="restart the simulator after S simulated s")
    ap.add_argument("--late-burst-at", type=float, default=None, help="simulated s of a burst of late measurements")
    ap.add_argument("--late-burst-size", type=int, default=20, help="messages in the late burst (default 20)")
    ap.add_argument("--fault-at", type=float, default=None, help="simulated s of a forced integrity fault")
    ap.add_argument("--fault-steps", type=int, default=20, help="biased measurements of the fault (default 20)")
    ap.add_argument("--publish-rate", type=float, default=None, help="estimator publish_rate (default its own)")
    ap.add_argument("--max-gap", type=float, default=3.0,
                    help="longest odometry gap after an event, wall s (default 3)")
    ap.add_argument("--json", action="store_true", help="print the summary as JSON")
    return ap


def command_line(args: argparse.Namespace) -> str:
    """The command that repeats the run of ``args``: the options that differ from their defaults (but
    those that do not change the run: output form, time limit, DDS domain, log keeping)."""
    out = []
    defaults = vars(parser().parse_args([]))
    for key, value in vars(args).items():
        if key in ("json", "timeout", "domain_id", "keep_log") or value == defaults.get(key):
            continue
        out += [f"--{key.replace('_', '-')}", f"{value:g}" if isinstance(value, float) else str(value)]
    return ("python -m gpf_nav.tools.soak " + " ".join(out)).rstrip()


def main(argv: list[str] | None = None) -> int:
    """Run the soak, print the table (or ``--json``); 0 when every check passed."""
    args = parser().parse_args(sys.argv[1:] if argv is None else argv)
    summary = run(args, command_line(args))
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0 if summary.get("passed") else 1


if __name__ == "__main__":
    sys.exit(main())
