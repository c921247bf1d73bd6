"""``gpf-nav demo``: simulator + estimator over ROS 2 in one process, with a summary against truth.

The lunar simulator publishes ``/clock`` at ``--rate-factor`` times real time over a shortened
scenario; the estimator runs on simulated time (``use_sim_time``); a third node subscribes to
``odometry/filtered``, ``truth/odometry``, ``gpf/ess`` and ``/diagnostics`` and, when the trajectory
has ended, prints position/velocity RMSE against truth (over the estimates whose stamp has a truth
message), mean ESS and the messages processed. All traffic goes over DDS, so set ``ROS_DOMAIN_ID`` /
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` to keep it private. Exit code 0 when the run completed.
"""
from __future__ import annotations

import json
import math
import time

import numpy as np

from gpf_nav.arguments import CommandParser, positive_float, positive_int
from gpf_nav.estimator.factory import FILTERS, make_filter
from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.sim.scenario import ScenarioConfig, filter_model


def _parser() -> CommandParser:
    ap = CommandParser(prog="gpf-nav demo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--filter", default="gpf", choices=FILTERS, help=" | ".join(FILTERS) + " (default gpf)")
    ap.add_argument("--particles", type=positive_int, default=N_PARTICLES, help=f"N (default {N_PARTICLES})")
    ap.add_argument("--duration", type=positive_float, default=300.0, help="simulated seconds (default 300)")
    ap.add_argument("--rate-factor", type=positive_float, default=20.0, help="simulated s per wall s (default 20)")
    ap.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    ap.add_argument("--case", default="full", choices=("full", "partial"), help="measurement case")
    ap.add_argument("--init", default="prior", choices=("prior", "measurements"),
                    help="initialise from the prior the simulator hands over (set_state) or from the first "
                         "measurements")
    ap.add_argument("--timeout", type=positive_float, default=None, help="wall-clock limit, s (default: generous)")
    ap.add_argument("--json", action="store_true", help="print the summary as JSON")
    return ap


def run(args) -> dict:
    """Run the demo; returns the summary dict (``completed`` False on a timeout)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64

    from gpf_nav.ros.conversions import odometry_state, stamp_to_ns
    from gpf_nav.ros.diagnostics import STATUS_NAME, parse_values
    from gpf_nav.ros.estimator_node import EstimatorNode
    from gpf_nav.ros.simulator_node import SimulatorNode

    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    executor = SingleThreadedExecutor(context=context)
    nodes = []
    try:
        sim = SimulatorNode(context=context, parameter_overrides=[
            Parameter("rate_factor", value=float(args.rate_factor)),
            Parameter("scenario.duration", value=float(args.duration)),
            Parameter("scenario.case", value=args.case),
            Parameter("seed", value=int(args.seed)),
            Parameter("start_delay", value=1.0),
            Parameter("hand_over_prior", value=args.init == "prior"),
            Parameter("truth_rate", value=0.0),  # truth at the measurement stamps only: what the summary uses
        ])
        nodes.append(sim)
        est = EstimatorNode(context=context, parameter_overrides=[
            Parameter("use_sim_time", value=True), Parameter("filter", value=args.filter),
            Parameter("n_particles", value=int(args.particles)),
            Parameter("queue_depth", value=1000)])  # one process: a slow spin delays messages, none is shed
        nodes.append(est)
        listener = rclpy.create_node("gpf_demo_summary", context=context)
        nodes.append(listener)
        estimates: dict[int, np.ndarray] = {}
        truth: dict[int, np.ndarray] = {}
        ess: list[float] = []
        last_diag: dict[str, str] = {}

        def on_diag(msg):
            for status in msg.status:
                if status.name == STATUS_NAME:
                    last_diag.clear()
                    last_diag.update(parse_values(status))

        listener.create_subscription(Odometry, "odometry/filtered",
                                     lambda m: estimates.__setitem__(stamp_to_ns(m.header.stamp),
                                                                     odometry_state(m)), 1000)
        listener.create_subscription(Odometry, "truth/odometry",
                                     lambda m: truth.__setitem__(stamp_to_ns(m.header.stamp),
                                                                 odometry_state(m)), 1000)
        listener.create_subscription(Float64, "gpf/ess", lambda m: ess.append(m.data), 1000)
        listener.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
        for node in nodes:
            executor.add_node(node)

        timeout = args.timeout or 60.0 + 3.0 * args.duration / args.rate_factor
        start = time.monotonic()
        deadline = start + timeout
        while time.monotonic() < deadline and not sim.finished:
            executor.spin_once(timeout_sec=0.05)
        counters = est.engine.counters

        def settled() -> bool:  # every measurement handled by the estimator, and reported
            handled = counters.accepted["rae"] + sum(n for (stream, _), n in counters.rejected_by_stream.items()
                                                     if stream == "rae")
            return (handled >= sim.published["measurement"]
                    and last_diag.get("measurements accepted") == str(counters.accepted["rae"]))

        linger = time.monotonic() + 30.0  # the last messages and one more /diagnostics (a busy machine is slow)
        while time.monotonic() < min(linger, deadline) and not (sim.finished and settled()):
            executor.spin_once(timeout_sec=0.05)
        wall = time.monotonic() - start

        common = sorted(set(estimates) & set(truth))
        err = np.array([estimates[k] - truth[k] for k in common]) if common else np.zeros((0, 6))
        pos = np.linalg.norm(err[:, :3], axis=1) if len(err) else np.zeros(0)
        vel = np.linalg.norm(err[:, 3:], axis=1) if len(err) else np.zeros(0)
        summary = {
            "completed": bool(sim.finished),
            "filter": args.filter,
            "particles": args.particles,
            "simulated_seconds": args.duration,
            "wall_seconds": round(wall, 2),
            "measurements_published": sim.published["measurement"],
            "measurements_processed": int(last_diag.get("measurements accepted",
                                                        counters.accepted["rae"] + counters.accepted["range"])),
            "measurements_rejected": int(last_diag.get("measurements rejected", 0)),
            "odometry_received": len(estimates),
            "compared_with_truth": len(common),
            "position_rmse_m": float(np.sqrt(np.mean(pos ** 2))) if len(pos) else math.nan,
            "velocity_rmse_mps": float(np.sqrt(np.mean(vel ** 2))) if len(vel) else math.nan,
            "final_position_error_m": float(pos[-1]) if len(pos) else math.nan,
            "mean_ess": float(np.mean(ess)) if ess else None,
            "diagnostics": last_diag.get("filter", "none received") and
            {k: last_diag[k] for k in ("initialized from", "ESS", "co-state norm", "reinitializations")
             if k in last_diag},
        }
        return summary
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def _print(summary: dict) -> None:
    print(f"gpf-nav demo: {summary['filter']} N={summary['particles']}, "
          f"{summary['simulated_seconds']:.0f} s simulated in {summary['wall_seconds']:.1f} s wall"
          + ("" if summary["completed"] else "  (TIMED OUT)"))
    print(f"  measurements published / processed / rejected : {summary['measurements_published']} / "
          f"{summary['measurements_processed']} / {summary['measurements_rejected']}")
    print(f"  odometry messages received                    : {summary['odometry_received']} "
          f"({summary['compared_with_truth']} at truth stamps)")
    print(f"  position RMSE vs truth                        : {summary['position_rmse_m']:.1f} m "
          f"(final {summary['final_position_error_m']:.1f} m)")
    print(f"  velocity RMSE vs truth                        : {summary['velocity_rmse_mps']:.2f} m/s")
    mean_ess = summary["mean_ess"]
    print(f"  mean ESS/N                                    : "
          f"{'n/a' if mean_ess is None else f'{mean_ess:.3f}'}")


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.case == "partial" and args.init == "measurements":
        parser.error("--init measurements needs range, azimuth and elevation (--case full); "
                     "the partial case never measures azimuth")
    try:  # the estimator's own check of the filter options, before anything starts
        make_filter(args.filter, filter_model(ScenarioConfig()), n_particles=args.particles)
    except ValueError as err:
        parser.error(str(err))
    summary = run(args)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        _print(summary)
    ok = summary["completed"] and summary["compared_with_truth"] > 0 \
        and math.isfinite(summary["position_rmse_m"])
    return 0 if ok else 1


if __name__ == "__main__":
    import sys
    sys.exit(main())
