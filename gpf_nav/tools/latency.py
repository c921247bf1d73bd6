"""Node-latency benchmark: measurement message published -> matching ``odometry/filtered`` received.

    gpf-nav bench --node [--json] [-- --rates 10,50,200 --particles 500,10000 --seconds 5]
    python -m gpf_nav.tools.latency ...

For each particle count the estimator runs as a separate process (``python -m
gpf_nav.ros.estimator_node``, the same code as the installed ``estimator``), initialised from the
scenario prior, with ``publish_rate: 0`` (no timer predictions, so the only odometry is the update's).
A publisher thread in this process sends the scenario's ``measurements/rae`` at each input rate
(best-effort QoS, as a sensor would) with stamps that advance by the scenario step but lie in the
past, so the filter sees the real 2 s dynamics while messages arrive at 10, 50 or 200 Hz. Latency is
the wall time from ``publish()`` to the reception of the odometry carrying the same stamp, both taken
in this process. Reported per rate: p50, p99, max, the fraction of measurements answered, and
``backlog_growth_ms`` = median latency of the last quarter minus that of the first quarter (a queue
that grows shows as a large positive value; a full best-effort queue sheds messages instead, which
shows as ``answered`` < 1). With ``--imu-per-measurement K`` each measurement is preceded by K ``imu``
samples (zero specific force, stamped in the 0.1 s before it), as an IMU-driven node receives them; the
estimator's ``late IMU samples applied`` and ``accepted imu`` counters are then reported too. ``node mean``
and ``node max`` are the estimator's own wall time per measurement (its ``measurement processing``
diagnostics, :mod:`gpf_nav.ros.processing_time`) over the rate's diagnostics periods: the share of the
latency that is the node's, the rest being transport and this process's executor.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time

import numpy as np

from gpf_nav.arguments import CommandParser, positive_float
from gpf_nav.estimator.factory import FILTERS

DEFAULT_RATES = (10.0, 50.0, 200.0)
DEFAULT_PARTICLES = (500, 10000)


def _positive_list(kind):
    """argparse type: a comma list of positive ``kind`` values."""
    def parse(text: str) -> tuple:
        try:
            values = tuple(kind(v) for v in text.split(","))
        except ValueError:
            values = ()
        if not values or min(values) <= 0:
            raise argparse.ArgumentTypeError(f"{text!r} is not a comma list of positive numbers")
        return values
    return parse


def _parser() -> CommandParser:
    ap = CommandParser(prog="gpf-nav bench --node", description=__doc__.split("\n\n")[0])
    ap.add_argument("--rates", type=_positive_list(float), default=",".join(f"{r:g}" for r in DEFAULT_RATES),
                    help="input rates in Hz, comma-separated (default 10,50,200)")
    ap.add_argument("--particles", type=_positive_list(int), default=",".join(str(n) for n in DEFAULT_PARTICLES),
                    help="particle counts, comma-separated (default 500,10000)")
    ap.add_argument("--seconds", type=positive_float, default=5.0, help="wall seconds of input per rate (default 5)")
    ap.add_argument("--filter", default="gpf", choices=FILTERS, help="estimator filter (default gpf)")
    ap.add_argument("--warmup", type=int, default=20, help="messages sent (at 10 Hz) and discarded first")
    ap.add_argument("--imu-per-measurement", type=int, default=0,
                    help="IMU samples published before each measurement (default 0: no IMU)")
    ap.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: the environment's)")
    ap.add_argument("--json", action="store_true", help="print the results as JSON")
    return ap


class _Bench:
    """A node that publishes measurements (each after ``imu_per_measurement`` IMU samples) and records reply
    latencies and the estimator's diagnostics."""

    def __init__(self, context, node, imu_per_measurement: int = 0):
        from geometry_msgs.msg import Vector3Stamped
        from nav_msgs.msg import Odometry
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        self.node = node
        self.sent: dict[int, float] = {}
        self.received: dict[int, float] = {}
        self._lock = threading.Lock()
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import Imu
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.pub = node.create_publisher(Vector3Stamped, "measurements/rae", qos)
        self.imu_pub = node.create_publisher(Imu, "imu", qos)
        node.create_subscription(Odometry, "odometry/filtered", self._on_odom, 100)
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.diagnostics: dict[str, str] = {}
        self.periods: list[tuple[int, float, float]] = []  # (measurements, mean ms, max ms) per diagnostics
        self.imu_per_measurement = imu_per_measurement
        self._imu = Imu()
        self._imu.header.frame_id = "base_link"
        self._imu.orientation.w = 1.0

    def _on_odom(self, msg) -> None:
        t = time.perf_counter()
        ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        with self._lock:
            self.received.setdefault(ns, t)

    def _on_diagnostics(self, msg) -> None:
        from gpf_nav.ros.diagnostics import STATUS_NAME, parse_values
        for status in msg.status:
            if status.name == STATUS_NAME:
                self.diagnostics = parse_values(status)
                timed = int(self.diagnostics.get("measurements timed", 0))
                if timed:
                    self.periods.append((timed, float(self.diagnostics["measurement processing mean [ms]"]),
                                         float(self.diagnostics["measurement processing max [ms]"])))

    def node_time(self, first: int) -> dict:
        """The estimator's own processing time per measurement over the diagnostics periods from ``first``
        (:mod:`gpf_nav.ros.processing_time`): mean and max, ms."""
        periods = self.periods[first:]
        count = sum(n for n, _, _ in periods)
        if not count:
            return {}
        return {"node_mean_ms": round(sum(n * mean for n, mean, _ in periods) / count, 3),
                "node_max_ms": round(max(longest for _, _, longest in periods), 3)}

    def send(self, stamp_ns: int, y) -> None:
        from gpf_nav.ros.conversions import ns_to_stamp, vector3_stamped
        k = self.imu_per_measurement
        for j in range(k):
            self._imu.header.stamp = ns_to_stamp(stamp_ns - (k - j) * 100_000_000 // k)
            self.imu_pub.publish(self._imu)
        msg = vector3_stamped(y, stamp_ns, "station")
        with self._lock:
            self.sent[stamp_ns] = time.perf_counter()
        self.pub.publish(msg)


def _pace(bench: _Bench, items, rate: float, stop: threading.Event) -> None:
    """Publish ``items`` ``[(stamp_ns, y)]`` at ``rate`` Hz (absolute schedule, no drift)."""
    period = 1.0 / rate
    start = time.perf_counter()
    for i, (stamp, y) in enumerate(items):
        if stop.is_set():
            return
        delay = start + i * period - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        bench.send(stamp, y)


def _stats(bench: _Bench, stamps: list[int]) -> dict:
    lat = []
    for s in stamps:
        if s in bench.received and s in bench.sent:
            lat.append((bench.received[s] - bench.sent[s]) * 1e3)
    out = {"sent": len(stamps), "answered": round(len(lat) / max(1, len(stamps)), 4)}
    if lat:
        a = np.array(lat)
        q = max(1, len(a) // 4)
        out.update(p50_ms=round(float(np.percentile(a, 50)), 3), p99_ms=round(float(np.percentile(a, 99)), 3),
                   max_ms=round(float(a.max()), 3),
                   backlog_growth_ms=round(float(np.median(a[-q:]) - np.median(a[:q])), 3))
    return out


def run(args) -> list[dict]:
    """Benchmark every particle count and rate of ``args``; one result row per pair."""
    import rclpy

    from gpf_nav.sim.scenario import ScenarioConfig, generate

    rates = [float(r) for r in args.rates]
    particles = [int(n) for n in args.particles]
    env = dict(os.environ)
    if args.domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(args.domain_id)
    counts = [max(10, int(round(r * args.seconds))) for r in rates]
    total = args.warmup + sum(counts)
    config = ScenarioConfig(duration=min(3000.0, 2.0 * (total + 5)))
    scenario = generate(config, 0)
    if len(scenario.times) < total:
        raise SystemExit(f"too many messages for one scenario ({total} > {len(scenario.times)}); "
                         "lower --seconds or the rates")

    context = rclpy.Context()
    rclpy.init(args=[], context=context, domain_id=args.domain_id)
    results = []
    try:
        for n in particles:
            results.extend(_run_one(context, env, scenario, n, rates, counts, args))
    finally:
        rclpy.try_shutdown(context=context)
    return results


def _run_one(context, env, scenario, n, rates, counts, args) -> list[dict]:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    # stamps in the past: the estimator's future-stamp check never triggers and its clock is irrelevant
    now_ns = time.time_ns()
    base = now_ns - int((scenario.times[-1] + 60.0) * 1e9)
    stamps = [base + int(round(t * 1e9)) for t in scenario.times]
    prior_std = np.sqrt(np.diag(scenario.prior_cov))
    cmd = [sys.executable, "-m", "gpf_nav.ros.estimator_node", "--ros-args",
           "-p", f"filter:={args.filter}", "-p", f"n_particles:={n}", "-p", "publish_rate:=0.0",
           "-p", "initial_state:=[" + ",".join(repr(float(v)) for v in scenario.prior_mean) + "]",
           "-p", "initial_std:=[" + ",".join(repr(float(v)) for v in prior_std) + "]",
           "-p", f"initial_stamp:={base * 1e-9!r}", "-p", "max_measurement_rate:=0.0",
           "-p", "max_published_particles:=0", "-p", "diagnostics_period:=0.5", "--log-level", "warn"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    node = rclpy.create_node("gpf_latency_bench", context=context)
    bench = _Bench(context, node, args.imu_per_measurement)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    stop = threading.Event()
    results = []
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and (bench.pub.get_subscription_count() == 0
                                               or node.count_publishers("odometry/filtered") == 0):
            if proc.poll() is not None:
                raise RuntimeError(f"estimator exited early: {proc.stderr.read()}")
            executor.spin_once(timeout_sec=0.1)
        time.sleep(0.5)
        cursor = 0
        plan = [("warmup", 10.0, args.warmup)] + [(r, r, c) for r, c in zip(rates, counts)]
        for label, rate, count in plan:
            items = [(stamps[cursor + i], scenario.measurements[cursor + i]) for i in range(count)
                     if np.any(np.isfinite(scenario.measurements[cursor + i]))]
            cursor += count
            first_period = len(bench.periods)
            thread = threading.Thread(target=_pace, args=(bench, items, rate, stop), daemon=True)
            thread.start()
            while thread.is_alive():
                executor.spin_once(timeout_sec=0.01)
            drain = time.monotonic() + 1.0 + 0.05 * n / 500
            while time.monotonic() < drain:
                executor.spin_once(timeout_sec=0.01)
            if label != "warmup":
                row = {"filter": args.filter, "particles": n, "rate_hz": rate}
                row.update(_stats(bench, [s for s, _ in items]))
                row.update(bench.node_time(first_period))
                if args.imu_per_measurement:  # the counters so far (cumulative over the rates)
                    row.update(imu_per_measurement=args.imu_per_measurement,
                               imu_accepted=int(bench.diagnostics.get("accepted imu", -1)),
                               late_imu_applied=int(bench.diagnostics.get("late IMU samples applied", -1)))
                results.append(row)
    finally:
        stop.set()
        executor.shutdown()
        node.destroy_node()
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
    return results


def format_table(results: list[dict]) -> str:
    head = f"{'filter':6} {'N':>6} {'rate':>6} {'sent':>5} {'answered':>8} {'p50 ms':>8} {'p99 ms':>8} " \
           f"{'max ms':>8} {'growth ms':>9} {'node mean':>9} {'node max':>8}"
    lines = [head, "-" * len(head)]
    for r in results:
        lines.append(f"{r['filter']:6} {r['particles']:>6} {r['rate_hz']:>6g} {r['sent']:>5} "
                     f"{r['answered']:>8.3f} {r.get('p50_ms', float('nan')):>8.2f} "
                     f"{r.get('p99_ms', float('nan')):>8.2f} {r.get('max_ms', float('nan')):>8.2f} "
                     f"{r.get('backlog_growth_ms', float('nan')):>9.2f} {r.get('node_mean_ms', float('nan')):>9.2f} "
                     f"{r.get('node_max_ms', float('nan')):>8.2f}"
                     + (f"   IMU {r['imu_per_measurement']}/measurement: {r['imu_accepted']} accepted, "
                        f"{r['late_imu_applied']} late" if "imu_per_measurement" in r else ""))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the latency table (or JSON); ``gpf-nav bench --node -- <these options>`` lands here too."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--"]:  # forwarded verbatim by gpf-nav bench --node -- ...
        argv = argv[1:]
    args = _parser().parse_args(argv)
    results = run(args)
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        print(format_table(results))
    return 0 if results and all(r["answered"] > 0 for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
