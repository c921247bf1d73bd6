"""``python -m gpf_nav.tools.history_cost``: memory and time of the estimator's late-measurement history.

Runs :class:`gpf_nav.estimator.engine.EstimatorEngine` (no ROS) on a 120 s descent with rae every 2 s
and the sensor suite (altimeter and velocimeter every 2 s, a TRN fix every 10 s delivered 4 s late) and
prints, per filter: inputs kept in the history and the snapshots among them (one per
:data:`~gpf_nav.estimator.history.SNAPSHOT_EVERY` inputs), the size of one snapshot (pickled filter, with the
models and sensors the snapshots share), the time of a snapshot copy, of an in-order measurement (snapshot
included) and of a late fix (restore, update and re-application of the inputs stamped after it). Wall-clock
figures: indicative on a loaded machine.
"""
from __future__ import annotations

import argparse
import pickle
import time

import numpy as np

from gpf_nav.estimator.engine import EngineConfig, EstimatorEngine
from gpf_nav.estimator.factory import make_filter
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate
from gpf_nav.sim.sensor_suite import SuiteConfig, generate_suite, suite_sensors

S = 1_000_000_000


def measure(name: str, n_particles: int, latency: float = 4.0, seed: int = 3) -> dict:
    """The figures of one filter (module docstring)."""
    scenario = generate(ScenarioConfig(duration=120.0), seed)
    suite = generate_suite(scenario, SuiteConfig(trn_outlier_probability=0.0, altimeter_max_altitude=1e9,
                                                 velocimeter_max_altitude=1e9), seed)
    sensors = suite_sensors(suite.config)
    model = filter_model(scenario.config)
    cfg = EngineConfig(initial_state=scenario.prior_mean, initial_std=np.sqrt(np.diag(scenario.prior_cov)),
                       initial_stamp=100.0)
    engine = EstimatorEngine(lambda: make_filter(name, model, n_particles=n_particles, seed=seed), model, cfg)
    events = []
    for k, t in enumerate(scenario.times):
        stamp = 100 * S + int(round(t * S))
        events.append((stamp, stamp, "rae", scenario.measurements[k]))
        for stream in ("altitude", "velocity", "position"):
            y = getattr(suite, stream)[k]
            if np.all(np.isfinite(y)):
                events.append((stamp + (int(latency * S) if stream == "position" else 0), stamp, stream, y))
    in_order, late, reapplied = [], [], []
    for _, stamp, stream, y in sorted(events, key=lambda e: e[0]):
        is_late = stamp < engine.t_ns
        before = engine.replayed_count
        start = time.perf_counter()
        engine.measurement(stamp, y, None, stream, sensors.get(stream))
        (late if is_late else in_order).append(time.perf_counter() - start)
        if is_late:
            reapplied.append(engine.replayed_count - before)
    sizes = [len(pickle.dumps(e.before)) for e in engine.history.entries if e.before is not None]
    start = time.perf_counter()
    for _ in range(20):
        engine.fusion.snapshot(engine.filter)
    return dict(filter=name, n=n_particles, inputs=len(engine.history), snapshots=len(sizes), snapshot_kb=np.mean(sizes) / 1e3,
                history_mb=sum(sizes) / 1e6, copy_ms=(time.perf_counter() - start) / 20 * 1e3,
                in_order_ms=np.median(in_order) * 1e3, late_ms=np.median(late) * 1e3,
                reapplied=float(np.median(reapplied)), late_fixes=len(late))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gpf_nav.tools.history_cost", description=__doc__.split("\n\n")[0])
    ap.add_argument("--filters", default="gpf:500,gpf:2000,ekf:1", help="name:N,... (default gpf:500,gpf:2000,ekf:1)")
    args = ap.parse_args(argv)
    for item in args.filters.split(","):
        name, n = item.split(":")
        r = measure(name, int(n))
        print(f"{r['filter']} N={r['n']}: {r['inputs']} inputs in the history, {r['snapshots']} snapshots of {r['snapshot_kb']:.0f} kB "
              f"(all {r['history_mb']:.2f} MB), copy {r['copy_ms']:.2f} ms; in-order measurement "
              f"{r['in_order_ms']:.2f} ms (median), late fix {r['late_ms']:.2f} ms re-applying "
              f"{r['reapplied']:.0f} inputs (median of {r['late_fixes']})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
