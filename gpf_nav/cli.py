"""The ``gpf-nav`` command: one entry point, one module per sub-command.

    gpf-nav bench        per-step cost of every filter (``gpf_nav.experiments.bench``)
    gpf-nav montecarlo   the paper's Monte Carlo table (``gpf_nav.experiments.montecarlo``)
    gpf-nav sweep        mismatch / noise sweeps (``gpf_nav.experiments.sweep``)
    gpf-nav stress       large prior, range only, outliers, bias, prior size (``gpf_nav.experiments.stress``)
    gpf-nav integrity    co-state monitor false alarms and detection delays (``gpf_nav.experiments.integrity_campaign``)
    gpf-nav honesty      covariance honesty where the data cannot determine the state, observability
                         report and consistency monitor (``gpf_nav.experiments.honesty``)
    gpf-nav sensors      rae only against the full sensor suite (``gpf_nav.experiments.sensor_campaign``)
    gpf-nav demo         simulator + estimator over ROS 2, with a summary (``gpf_nav.tools.demo``)
    gpf-nav record       the simulator's scenario written as a rosbag2 bag (``gpf_nav.bags.record``)
    gpf-nav replay       the estimator run offline over a rosbag2 bag, with a summary (``gpf_nav.bags.replay``)
    gpf-nav parameters   docs/parameters.md and config/*.yaml from the parameter schemas (``gpf_nav.tools.parameter_docs``)

Sub-command modules are imported lazily, so e.g. ``bench`` needs neither ROS nor matplotlib. Every
sub-command runs with the heap tuning of :mod:`gpf_nav.allocator` and BLAS bounded to one thread
(:mod:`gpf_nav.blas`). Bad arguments, to ``gpf-nav`` or to any sub-command, end with one line on stderr
naming the problem and exit status 2 (:class:`gpf_nav.arguments.CommandParser`).
"""
from __future__ import annotations

import importlib
import sys

from gpf_nav.allocator import retain_freed_memory
from gpf_nav.arguments import USAGE_ERROR
from gpf_nav.blas import limit_blas_threads
from gpf_nav.openmp import passive_openmp_waits

COMMANDS = {
    "bench": "gpf_nav.experiments.bench",
    "montecarlo": "gpf_nav.experiments.montecarlo",
    "sweep": "gpf_nav.experiments.sweep",
    "stress": "gpf_nav.experiments.stress",
    "demo": "gpf_nav.tools.demo",
    "integrity": "gpf_nav.experiments.integrity_campaign",
    "honesty": "gpf_nav.experiments.honesty",
    "sensors": "gpf_nav.experiments.sensor_campaign",
    "record": "gpf_nav.bags.record",
    "replay": "gpf_nav.bags.replay",
    "parameters": "gpf_nav.tools.parameter_docs",
}
def main(argv: list[str] | None = None) -> int:
    """Dispatch ``gpf-nav <command> [args]`` to ``<module>.main(args)``; returns the exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        return 0
    if not argv or argv[0] not in COMMANDS:
        problem = f"unknown command {argv[0]!r}" if argv else "a command is required"
        print(f"gpf-nav: error: {problem}; choose one of {', '.join(COMMANDS)} (see gpf-nav --help)",
              file=sys.stderr)
        return USAGE_ERROR
    retain_freed_memory()
    limit_blas_threads()
    passive_openmp_waits()
    module = importlib.import_module(COMMANDS[argv[0]])
    return int(module.main(argv[1:]) or 0)


if __name__ == "__main__":
    sys.exit(main())
