"""The ``gpf-nav`` command: one entry point, one module per sub-command.

    gpf-nav bench        per-step cost of every filter (``gpf_nav.experiments.bench``)
    gpf-nav montecarlo   the paper's Monte Carlo table (``gpf_nav.experiments.montecarlo``)
    gpf-nav sweep        mismatch / noise sweeps (``gpf_nav.experiments.sweep``)
    gpf-nav integrity    co-state monitor false alarms and detection delays (``gpf_nav.experiments.integrity``)
    gpf-nav demo         simulator + estimator over ROS 2, with a summary (``gpf_nav.ros.demo``)
    gpf-nav record       the simulator's scenario written as a rosbag2 bag (``gpf_nav.ros.record``)
    gpf-nav replay       the estimator run offline over a rosbag2 bag, with a summary (``gpf_nav.ros.replay``)

Sub-command modules are imported lazily, so e.g. ``bench`` needs neither ROS nor matplotlib. Every
sub-command runs with the heap tuning of :mod:`gpf_nav.allocator`.
"""
from __future__ import annotations

import importlib
import sys

from gpf_nav.allocator import retain_freed_memory

COMMANDS = {
    "bench": "gpf_nav.experiments.bench",
    "montecarlo": "gpf_nav.experiments.montecarlo",
    "sweep": "gpf_nav.experiments.sweep",
    "demo": "gpf_nav.ros.demo",
    "integrity": "gpf_nav.experiments.integrity",
    "record": "gpf_nav.ros.record",
    "replay": "gpf_nav.ros.replay",
}


def main(argv: list[str] | None = None) -> int:
    """Dispatch ``gpf-nav <command> [args]`` to ``<module>.main(args)``; returns the exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in COMMANDS:
        print(__doc__.strip())
        return 0 if argv and argv[0] in ("-h", "--help") else 2
    retain_freed_memory()
    module = importlib.import_module(COMMANDS[argv[0]])
    return int(module.main(argv[1:]) or 0)


if __name__ == "__main__":
    sys.exit(main())
