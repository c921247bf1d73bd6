"""``python -m gpf_nav.tools.fault_policy``: what to do after a persistent integrity FAULT, measured.

Runs :class:`gpf_nav.estimator.engine.EstimatorEngine` (no ROS; the default GPF, rae every 2 s with the
IMU's specific force) on the lunar descent, for every ``fault_action`` and ``fault_updates`` K, with a
fault forced at ``--event`` s:

* ``clean``: none (re-initialisations here are false ones);
* ``jump``: from the event on the measurements (and truth) are those of ``--shift`` steps earlier, the
  state the filter holds then being off by kilometres: what a restarted simulator without a reset gave;
* ``bias``: a +3 km range bias on ``--bias-steps`` measurements from the event on (a faulty sensor).

Per run: re-initialisations after a FAULT, the simulated seconds after the event without an estimate,
and the position error against truth (median over 100-300 s after the event, and at the end). The
output carries the command and the commit.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from gpf_nav.estimator.engine import EngineConfig, EstimatorEngine
from gpf_nav.estimator.factory import make_filter
from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

S = 1_000_000_000
BIAS = 3000.0  # m, 100 range sigmas
FAULTS = ("clean", "jump", "bias")


def run(seed: int, fault: str, action: str, k_updates: int, args) -> dict:
    """One run; see the module docstring for the figures."""
    scenario = generate(ScenarioConfig(duration=args.duration), seed)
    model = filter_model(scenario.config)
    cfg = EngineConfig(initial_state=scenario.prior_mean, initial_std=np.sqrt(np.diag(scenario.prior_cov)),
                       initial_stamp=0.0, fault_action=action, fault_updates=k_updates)
    engine = EstimatorEngine(lambda: make_filter("gpf", model, n_particles=args.particles, seed=seed), model, cfg)
    dt = scenario.config.dt
    k0 = int(round(args.event / dt))
    errors, outage = [], 0.0
    for k, t in enumerate(scenario.times):
        src = k - args.shift if fault == "jump" and k >= k0 else k
        y = scenario.measurements[src].copy()
        if fault == "bias" and k0 <= k < k0 + args.bias_steps:
            y[0] += BIAS
        stamp = int(round(t * S))
        engine.imu(stamp - int(round(dt * S)) + 1, scenario.specific_force[src], None)
        engine.measurement(stamp, y, None)
        if k < k0:
            continue
        if not engine.initialized or engine.mean is None or engine.t_ns != stamp:
            outage += dt
            errors.append(np.nan)
        else:
            errors.append(float(np.linalg.norm(engine.mean[:3] - scenario.truth[src + 1][:3])))
    e = np.array(errors)
    window = e[int(100 / dt):int(300 / dt)]
    return {"seed": seed, "fault": fault, "action": action, "K": k_updates,
            "reinits": engine.fault_reinit_count, "outage_s": outage,
            "median_100_300_m": float(np.nanmedian(window)) if np.any(np.isfinite(window)) else None,
            "final_m": float(e[-1]) if np.isfinite(e[-1]) else None}


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).resolve().parents[2], check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gpf_nav.tools.fault_policy", description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--k", type=int, nargs="+", default=[3, 10, 30], help="fault_updates values")
    ap.add_argument("--particles", type=int, default=N_PARTICLES)
    ap.add_argument("--duration", type=float, default=1200.0, help="simulated s (default 1200)")
    ap.add_argument("--event", type=float, default=400.0, help="simulated s of the fault (default 400)")
    ap.add_argument("--shift", type=int, default=3, help="jump: measurement steps back (default 3, 6 s)")
    ap.add_argument("--bias-steps", type=int, default=20, help="bias: biased measurements (default 20)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    policies = [("none", 0)] + [(a, k) for a in ("measurements", "prior") for k in args.k]
    rows = [run(seed, fault, action, k, args) for fault in FAULTS for action, k in policies for seed in args.seeds]
    command = "python -m gpf_nav.tools.fault_policy " + " ".join(sys.argv[1:] if argv is None else argv)
    if args.json:
        print(json.dumps({"command": command, "commit": _commit(), "rows": rows}, indent=1))
        return 0
    print(f"{command.strip()}  (commit {_commit()}, N={args.particles}, seeds {args.seeds})")
    print(f"{'fault':6} {'policy':16} {'reinits':>8} {'outage s':>9} {'median 100-300 s [m]':>22} {'final [m]':>10}")
    for fault in FAULTS:
        for action, k in policies:
            rs = [r for r in rows if r["fault"] == fault and r["action"] == action and r["K"] == k]
            med = [r["median_100_300_m"] for r in rs]
            fin = [r["final_m"] for r in rs]
            print(f"{fault:6} {action + (f' K={k}' if k else ''):16} {sum(r['reinits'] for r in rs):>8} "
                  f"{np.mean([r['outage_s'] for r in rs]):>9.0f} {_fmt(med):>22} {_fmt(fin):>10}")
    return 0


def _fmt(values: list) -> str:
    """Median (max) over runs; ``-`` for runs without an estimate."""
    v = [x for x in values if x is not None]
    return f"{np.median(v):.0f} ({max(v):.0f})" if v else "-"


if __name__ == "__main__":
    sys.exit(main())
