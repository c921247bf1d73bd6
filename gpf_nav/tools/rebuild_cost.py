"""``python -m gpf_nav.tools.rebuild_cost``: time of a reanchoring's rebuild of the observability tracker.

A reanchoring (:meth:`gpf_nav.integrity.observability.ObservabilityTracker.reanchor`) rebuilds both
information recursions along the whole log of predictions and updates, inside the update that moved the
reference. This runs the EKF and the compensated EKF (one tracker each: the lunar model, and the lunar
model with its unmodelled-acceleration states) through a consistent orbit with rae every 2 s and the
scenario's specific force as input, then times the rebuild of their full log (the best of ``--repeats``).
Wall-clock figures: indicative on a loaded machine.
"""
from __future__ import annotations

import argparse
import time

from gpf_nav import registry
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate


def measure(name: str, measurements: int, repeats: int = 3) -> dict:
    """Log entries and the best rebuild time (ms) of filter ``name`` after ``measurements`` updates."""
    config = ScenarioConfig(epsilon=0.0, duration=2.0 * measurements)
    scenario = generate(config, 0)
    flt = registry.make(name, filter_model(config), 10, 0)
    flt.initialize(scenario.prior_mean, scenario.prior_cov)
    for k in range(scenario.times.size):
        flt.predict(config.dt, scenario.specific_force[k])
        flt.update(scenario.measurements[k])
    tracker = flt.observability_trackers()[0]
    best = float("inf")
    for _ in range(repeats + 1):  # (the first call may load the kernels)
        start = time.perf_counter()
        tracker.reanchor(tracker.reference)
        best = min(best, time.perf_counter() - start)
    return {"filter": name, "state": tracker.reference.size, "predictions": scenario.times.size,
            "updates": tracker.updates, "rebuild_ms": round(best * 1e3, 2)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gpf_nav.tools.rebuild_cost", description=__doc__.split("\n\n")[0])
    ap.add_argument("--measurements", type=int, default=10_000,
                    help="updates before the rebuild (two log entries each; default 10 000: the log's limit)")
    ap.add_argument("--repeats", type=int, default=3, help="timed rebuilds, the best reported (default 3)")
    args = ap.parse_args(argv)
    for name in ("ekf", "ekf-comp"):
        row = measure(name, args.measurements, args.repeats)
        print(f"{row['filter']:9s} state {row['state']}  log {row['predictions']} predictions + {row['updates']} "
              f"updates  rebuild {row['rebuild_ms']} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
