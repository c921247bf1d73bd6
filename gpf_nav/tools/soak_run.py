"""The soak's run: the estimator process, the simulator, injector and listener nodes, and the loop that
drives them.

The estimator runs as its own process (``python -m gpf_nav.ros.estimator_node``, the code of the installed
``estimator``) on simulated time; its resident memory is read from ``/proc/<pid>/status``. This process
runs the simulator (its ``measurements/rae`` remapped to the injector's input), the
:class:`~gpf_nav.tools.soak_injector.Injector` and the :class:`~gpf_nav.tools.soak_listener.Listener`.
With ``--restart-at S`` the simulator is stopped after S simulated s and started again, its clock back at
the start (the estimator must reset and re-initialise; the injector starts again after ``--warmup``, and
the other events happen in the second run). Times are of the (last) simulator's trajectory; space the
events at least 150 s apart.
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

from gpf_nav.tools.soak_injector import RAW_TOPIC, Injector
from gpf_nav.tools.soak_ledger import NS
from gpf_nav.tools.soak_listener import Listener
from gpf_nav.tools.soak_report import summarise


def rss_kib(pid: int | str = "self") -> dict[str, int]:
    """``VmRSS`` and ``VmHWM`` (peak) of a process in KiB, from ``/proc/<pid>/status`` ({} if gone)."""
    out = {}
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key in ("VmRSS", "VmHWM"):
                    out[key] = int(value.split()[0])
    except OSError:
        pass
    return out


def _estimator_command(args: argparse.Namespace) -> list[str]:
    return [sys.executable, "-m", "gpf_nav.ros.estimator_node", "--ros-args",
            "-p", "use_sim_time:=true", "-p", f"filter:={args.filter}", "-p", f"n_particles:={args.particles}",
            "-p", f"queue_depth:={args.queue_depth}", "-p", "diagnostics_period:=1.0",
            *(["-p", f"publish_rate:={args.publish_rate}"] if args.publish_rate is not None else []),
            "--log-level", "warn"]


def run(args: argparse.Namespace, command: str) -> dict:
    """Run the soak given by ``args`` (``command``: its command line, for the summary); returns the
    summary (:func:`gpf_nav.tools.soak_report.summarise`)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from gpf_nav.ros.simulator_node import SimulatorNode

    env = dict(os.environ)
    if args.domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(args.domain_id)
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    domain = int(env.get("ROS_DOMAIN_ID", "0") or 0)
    sim_seconds = args.sim_minutes * 60.0
    timeout = args.timeout or 90.0 + 2.0 * sim_seconds / args.rate_factor

    log = tempfile.NamedTemporaryFile("w+", prefix="gpf_soak_estimator_", suffix=".log", delete=False)
    wall_start = time.monotonic()
    proc = subprocess.Popen(_estimator_command(args), env=env, stdout=log, stderr=subprocess.STDOUT, text=True)
    context = rclpy.Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    executor = SingleThreadedExecutor(context=context)
    nodes = []
    summary: dict = {"completed": False}
    try:
        node = rclpy.create_node("gpf_soak", context=context)
        nodes.append(node)
        executor.add_node(node)
        injector = Injector(node, args, "station")
        listener = Listener(node)

        # the estimator is up (subscribed, publishing diagnostics) before the simulator starts
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and not (injector.pub.get_subscription_count() and listener.last_values):
            if proc.poll() is not None:
                raise RuntimeError(f"estimator exited early (code {proc.returncode}): {_tail(log.name)}")
            executor.spin_once(timeout_sec=0.1)
        if not listener.last_values:
            raise RuntimeError("estimator did not come up within 60 s")

        def start_simulator(events: bool = True) -> SimulatorNode:
            node = SimulatorNode(context=context, cli_args=["--ros-args", "-r", f"measurements/rae:={RAW_TOPIC}"],
                                 parameter_overrides=[
                                     Parameter("rate_factor", value=float(args.rate_factor)),
                                     Parameter("scenario.duration", value=float(sim_seconds)),
                                     Parameter("scenario.epsilon", value=float(args.epsilon)),
                                     Parameter("seed", value=int(args.seed)), Parameter("start_delay", value=1.5),
                                     Parameter("hand_over_prior", value=False)])  # it learns from the measurements
            nodes.append(node)
            executor.add_node(node)
            injector.start_ns = node.stamp_ns(int(args.warmup * NS))
            for name, at in (("burst_ns", args.late_burst_at), ("fault_ns", args.fault_at)):
                setattr(injector, name, None if at is None or not events else node.stamp_ns(int(at * NS)))
            return node

        sim = start_simulator(events=args.restart_at is None)  # with a restart, the events are in the second run
        retired: Counter = Counter()  # what the simulators before the running one published
        restart_pending = args.restart_at is not None
        measuring = False

        rss_samples: list[tuple[float, float, int]] = []
        rss_start = own_start = None
        next_sample = 0.0
        run_start = time.monotonic()
        deadline = run_start + timeout
        sim_now = 0.0
        alive = True
        while time.monotonic() < deadline and not sim.finished:
            executor.spin_once(timeout_sec=0.02)
            if proc.poll() is not None:
                alive = False
                break
            sim_now = sim.trajectory_ns * 1e-9
            if restart_pending and sim_now >= args.restart_at:
                restart_pending = False
                sim = _restart(sim, retired, injector, listener, executor, nodes, start_simulator)
                continue
            if injector.active and not measuring:
                measuring = True
                rss_start, own_start = rss_kib(proc.pid), rss_kib()
                rss_samples.append((time.monotonic() - run_start, sim_now, rss_start.get("VmRSS", 0)))
                next_sample = time.monotonic() + args.rss_period
            elif measuring and time.monotonic() >= next_sample:
                rss_samples.append((time.monotonic() - run_start, sim_now, rss_kib(proc.pid).get("VmRSS", 0)))
                next_sample += args.rss_period
        sim_wall = time.monotonic() - run_start
        drain = time.monotonic() + 10.0  # the simulator's last messages reach the injector, then the held ones go
        while time.monotonic() < drain and \
                sum(injector.ledger.stream.values()) < retired["measurement"] + sim.published["measurement"]:
            executor.spin_once(timeout_sec=0.05)
        injector.flush()

        # let the estimator count everything, then one more diagnostics message
        drain = time.monotonic() + 20.0
        while time.monotonic() < drain and proc.poll() is None and listener.seen() < injector.ledger.sent:
            executor.spin_once(timeout_sec=0.05)
        n_diag = listener.counts["/diagnostics"]
        drain = time.monotonic() + 3.0
        while time.monotonic() < drain and listener.counts["/diagnostics"] <= n_diag:
            executor.spin_once(timeout_sec=0.05)
        alive = alive and proc.poll() is None
        rss_end, own_end = rss_kib(proc.pid), rss_kib()
        if rss_end:
            rss_samples.append((time.monotonic() - run_start, sim_now, rss_end.get("VmRSS", 0)))

        exit_code = _stop(proc)
        wall = time.monotonic() - wall_start
        ran = SimpleNamespace(finished=sim.finished, published=retired + Counter(sim.published))
        summary = summarise(args, command, ran, injector, listener, alive, exit_code, _tail(log.name, 100_000),
                             rss_start or {}, rss_end, rss_samples, own_start or {}, own_end,
                             sim_wall, wall)
        summary["estimator_log"] = log.name if (args.keep_log or not summary["passed"]) else None
        return summary
    finally:
        if proc.poll() is None:
            _stop(proc)
        executor.shutdown()
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown(context=context)
        log.close()
        if not summary.get("estimator_log"):  # kept when the soak failed or --keep-log
            Path(log.name).unlink(missing_ok=True)


def _restart(sim, retired: Counter, injector: Injector, listener: Listener, executor, nodes: list,
             start_simulator):
    """Stop ``sim`` once its measurements reached the injector, let the estimator take what was sent, then
    start a new simulator (its clock back at the start); returns it."""
    drain = time.monotonic() + 5.0
    while time.monotonic() < drain and sum(injector.ledger.stream.values()) < retired["measurement"] \
            + sim.published["measurement"]:
        executor.spin_once(timeout_sec=0.05)
    retired.update(sim.published)
    executor.remove_node(sim)
    nodes.remove(sim)
    sim.destroy_node()
    injector.restart(0)
    drain = time.monotonic() + 1.0
    while time.monotonic() < drain:
        executor.spin_once(timeout_sec=0.05)
    listener.epoch += 1
    return start_simulator()


def _stop(proc) -> int:
    """SIGINT (what Ctrl-C sends), then wait; the estimator's exit code (-9 if it had to be killed)."""
    if proc.poll() is not None:
        return proc.returncode
    proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return -9


def _tail(path: str, lines: int = 20) -> str:
    try:
        return "\n".join(Path(path).read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""

