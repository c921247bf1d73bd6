"""First odometry after a no-argument start: the wall seconds from starting the ``estimator`` and the
``simulator`` (each in its own process, as ``ros2 run`` starts them, with no parameters) to the first
``odometry/filtered`` message this process receives.

    python -m gpf_nav.tools.first_odometry [--domain-id N] [--timeout S] [--json]

The estimator warms its compiled kernels up before it subscribes (``docs/ros.md``, ``configure``): on an install's
first start numba compiles them ("cold"), later starts load them from the cache ("warm"). Run it on a fresh clone for
the first, and again for the second. Exit status 0 when an odometry message came, 1 when none came in ``--timeout`` s.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

from gpf_nav.arguments import CommandParser, positive_float

NODES = ("gpf_nav.ros.estimator_node", "gpf_nav.ros.simulator_node")
"""The modules started, the same code as the installed ``estimator`` and ``simulator``."""


def first_odometry(timeout: float) -> float | None:
    """Seconds from starting :data:`NODES` to the first ``odometry/filtered`` received, or None after
    ``timeout`` s; the nodes are stopped (SIGTERM, their clean shutdown) before it returns."""
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    rclpy.init()
    node = rclpy.create_node("first_odometry_probe")
    received: list[float] = []
    node.create_subscription(Odometry, "odometry/filtered", lambda _: received.append(time.monotonic()),
                             QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    start = time.monotonic()
    processes = [subprocess.Popen([sys.executable, "-m", module], stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL) for module in NODES]
    try:
        while not received and time.monotonic() - start < timeout:
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        for process in processes:
            process.terminate()
        for process in processes:
            try:
                process.wait(20)
            except subprocess.TimeoutExpired:
                process.kill()
        node.destroy_node()
        rclpy.shutdown()
    return received[0] - start if received else None


def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(prog="python -m gpf_nav.tools.first_odometry", description=__doc__.splitlines()[0])
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: the environment's)")
    parser.add_argument("--timeout", type=positive_float, default=300.0, help="seconds to wait (default 300)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    if args.domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)  # (before rclpy starts; the nodes inherit it)
    seconds = first_odometry(args.timeout)
    if args.json:
        print(json.dumps({"first_odometry_s": seconds, "timeout_s": args.timeout}))
    else:
        print(f"first odometry {seconds:.1f} s" if seconds is not None else f"no odometry in {args.timeout:g} s")
    return 0 if seconds is not None else 1


if __name__ == "__main__":
    raise SystemExit(main())
