"""Soak test: simulator -> fault injector -> estimator over DDS for a long simulated run.

    python -m gpf_nav.tools.soak [--sim-minutes 30] [--rate-factor 10] [--seed 0] [--json]

The estimator runs as its own process (``python -m gpf_nav.ros.estimator_node``, the code of the
installed ``estimator``) on simulated time; its resident memory is read from ``/proc/<pid>/status``.
This process runs the simulator (its ``measurements/rae`` remapped to ``soak/raw/rae``), an *injector*
node that forwards those measurements to the estimator's ``measurements/rae`` while it tampers with
them, and a listener that checks every estimator output for NaN/inf and compares odometry with truth.

After ``--warmup`` simulated seconds (the estimator initialises from its first measurements meanwhile;
the start RSS is read then) each measurement from the simulator, with a seeded random stream, is

* ``dropped`` (never sent), ``delayed`` (held back until 1-3 later measurements have been sent: a
  reorder), ``duplicated`` (sent twice back to back), ``masked`` (sent with its range NaN: "not
  measured") or passed on unchanged, one of these with probabilities ``--drop --delay --duplicate
  --mask``; and independently
* followed by one ``garbage`` message (``--garbage``) and by a ``burst`` of ``--burst-size`` garbage
  messages back to back (``--burst``). Garbage kinds are taken in turn from :data:`GARBAGE`:
  all-NaN, inf range, negative range, azimuth beyond pi, ``nanosec >= 1e9``, a stamp 1e6 s in the
  future, a stamp 600 s old (beyond the estimator's ``history_length``), a wrong ``frame_id``.

The injector predicts the estimator's verdict on every message it sends with the estimator's own rules
(docs/ros.md, *Bad input*): a garbage kind has exactly one refusal reason; a message whose stamp is older
than the newest one already accepted by at most ``history_length`` (10 s, the estimator's default) is
accepted and fused at its stamp (so a delayed message, released after 1-3 newer ones, is accepted),
an older one is ``older_than_history``; an equal stamp is accepted (so a duplicate is accepted and used twice: the second
copy is a ``dt = 0`` update, which the integrity monitor skips). At the end the predicted counts are
compared with the ``rejected <reason>`` and ``accepted rae`` counters of the estimator's last
``/diagnostics``: every message sent must be accounted for, reason by reason.

Three timing events can be injected, each followed by a quiet span in which the injector passes every
measurement on unchanged (the estimator re-initialises meanwhile):

* ``--restart-at S``: the simulator is stopped after S simulated s and started again, its clock back at
  the start (the estimator must reset and re-initialise from the new measurements; the injector starts
  again after ``--warmup``);
* ``--late-burst-at S``: ``--late-burst-size`` copies of the measurement three periods (6 s) old, sent
  back to back: the estimator's re-application budget (``reapply_budget``) takes what it can and refuses
  the rest as ``reapply_budget``;
* ``--fault-at S``: a +3 km range bias on ``--fault-steps`` measurements, which drives the co-state
  monitor to a persistent FAULT and the estimator's ``integrity_fault_action``.

Times are of the (last) simulator's trajectory; space the events at least 150 s apart. For each event the
summary gives the longest gap between two odometry messages over the quiet span after it (from the
event, or for the restart from the new simulator's first measurement), in wall and in simulated seconds;
each must be at most ``--max-gap`` wall s.

Pass/fail (exit code 0/1): the run completed, the estimator process was alive to the end and exited
cleanly on SIGINT, counters match the prediction exactly, the estimator counted all but at most
``--max-imu-loss`` of the simulator's IMU samples (they are not injected into: a node that keeps up loses
none; one that falls behind loses the overflow of its queue), no ``internal_error`` or ``filter_error``, no
non-finite number on any output, no ERROR/FATAL line or traceback in the estimator's log, and the
estimate follows the truth: the median position error over the second half of the compared estimates
is at most ``--max-error`` (a diverged filter ends thousands of kilometres off). RSS figures are
reported, not judged. See docs/soak.md.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from gpf_nav.estimator.input_checks import REASONS, ReapplyBudget
from gpf_nav.estimator.params import BY_NAME
from gpf_nav.filters.interface import N_PARTICLES

NS = 1_000_000_000
RAW_TOPIC = "soak/raw/rae"
GARBAGE = (  # kind -> the single reason the estimator must give
    ("nan_all", "no_measured_component"),
    ("inf_range", "non_finite"),
    ("negative_range", "non_positive_range"),
    ("bad_azimuth", "angle_out_of_range"),
    ("bad_nanosec", "bad_stamp"),
    ("future_stamp", "future_stamp"),
    ("old_stamp", "older_than_history"),
    ("wrong_frame", "wrong_frame"),
)
FUTURE_S = 1_000_000   # s ahead of the stamp for future_stamp (far beyond max_future)
OLD_S = 600            # s behind the stamp for old_stamp
HISTORY_S = BY_NAME["history_length"].default  # s: late stamps within it are fused
REAPPLY_BUDGET = BY_NAME["reapply_budget"].default  # s of lateness per s of filter time
BIAS = 3000.0          # m, the range bias of --fault-at
QUIET_S = 150.0        # simulated s after a late burst or a fault without other tampering
STREAM_CATEGORIES = ("passed", "dropped", "delayed", "duplicated", "masked")


def _parser() -> argparse.ArgumentParser:
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


# --- memory ----------------------------------------------------------------------------------------------
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


def _second_half_growth(samples: list[tuple[float, float, int]]) -> int | None:
    """RSS change [KiB] from the sample nearest the middle of the simulated span to the last one."""
    if len(samples) < 3:
        return None
    middle = 0.5 * (samples[0][1] + samples[-1][1])
    mid = min(samples, key=lambda s: abs(s[1] - middle))
    return samples[-1][2] - mid[2]


def _slope_per_hour(samples: list[tuple[float, float, int]]) -> float | None:
    """Least-squares RSS growth [KiB per simulated hour] of ``(wall_s, sim_s, rss_kib)`` samples."""
    if len(samples) < 3:
        return None
    sim = np.array([s[1] for s in samples])
    rss = np.array([s[2] for s in samples], dtype=float)
    if np.ptp(sim) <= 0:
        return None
    return float(np.polyfit(sim, rss, 1)[0] * 3600.0)


# --- the injector ------------------------------------------------------------------------------------------
class Ledger:
    """What the injector did and what the estimator must say about it (pure bookkeeping, no ROS)."""

    def __init__(self, history_s: float = HISTORY_S):
        self.history_ns = int(round(history_s * NS))
        self.stream = Counter({c: 0 for c in STREAM_CATEGORIES})   # per simulator measurement
        self.garbage = Counter({k: 0 for k, _ in GARBAGE})         # garbage messages by kind
        self.singles = 0                                           # garbage messages sent alone
        self.bursts = 0                                            # bursts sent
        self.late_burst = 0                                        # late copies sent (--late-burst-at)
        self.burst_messages = 0
        self.expected_rejected = Counter({r: 0 for r in REASONS})
        self.expected_accepted = 0
        self.expected_masked = 0
        self.sent = 0                                              # messages published to the estimator
        self.delayed_outcomes = Counter()                          # verdicts predicted for delayed messages
        self.duplicate_outcomes = Counter()
        self.restart()

    def restart(self) -> None:
        """The estimator starts again (a reset): no stamp accepted yet, the budget full."""
        self.newest_ns: int | None = None                          # newest stamp predicted accepted
        self.budget = ReapplyBudget(REAPPLY_BUDGET, self.history_ns * 1e-9, 0)

    def verdict(self, stamp_ns: int, reason: str = "") -> str:
        """Record one message sent: ``reason`` for garbage, else the timing rules (history, budget) decide."""
        self.sent += 1
        newest = self.newest_ns
        if not reason and newest is not None and stamp_ns < newest - self.history_ns:
            reason = "older_than_history"
        elif not reason and newest is not None and stamp_ns < newest \
                and not self.budget.spend(newest, (newest - stamp_ns) * 1e-9):
            reason = "reapply_budget"
        if reason:
            self.expected_rejected[reason] += 1
            return reason
        self.expected_accepted += 1
        self.newest_ns = stamp_ns if newest is None else max(newest, stamp_ns)
        return "accepted"


class Injector:
    """Forwards ``soak/raw/rae`` to ``measurements/rae`` with the tampering described in the module
    docstring. It turns ``active`` from the first measurement stamped at or after ``start_ns`` on;
    before that everything is passed on."""

    def __init__(self, node, args, frame: str):
        from geometry_msgs.msg import Vector3Stamped
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        self.node = node
        self.args = args
        self.frame = frame
        self.rng = random.Random(args.seed * 7919 + 17)
        self.ledger = Ledger()
        self.active = False
        self.start_ns: int | None = None
        self.burst_ns: int | None = None          # stamp from which the late burst goes out (then None)
        self.fault_ns: int | None = None          # stamp from which the fault's biased measurements go out
        self.fault_left = args.fault_steps
        self.quiet_until_ns = 0                   # no tampering before this stamp (after an event)
        self.events: list[dict] = []              # {"event", "wall", "stamp_ns"}
        self._recent: list[tuple[int, list]] = []  # the last four measurements from the simulator
        self._restarted = False                   # the next measurement is the restarted simulator's first
        self._kind = 0
        self._held: list[list] = []   # [countdown, message, stamp_ns]
        qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=1000)
        self.pub = node.create_publisher(Vector3Stamped, "measurements/rae", qos)
        node.create_subscription(Vector3Stamped, RAW_TOPIC, self._on_raw, qos)

    # messages
    def _msg(self, stamp_ns: int, values, frame: str | None = None):
        from gpf_nav.ros.conversions import vector3_stamped
        return vector3_stamped(values, stamp_ns, self.frame if frame is None else frame)

    def _send(self, msg, stamp_ns: int, reason: str = "") -> str:
        verdict = self.ledger.verdict(stamp_ns, reason)
        self.pub.publish(msg)
        return verdict

    def _garbage(self, stamp_ns: int, values) -> None:
        kind, reason = GARBAGE[self._kind % len(GARBAGE)]
        self._kind += 1
        r, a, e = values
        if not math.isfinite(r):
            r = 1.0e6
        stamp, frame, v = stamp_ns, None, [r, a, e]
        if kind == "nan_all":
            v = [math.nan, math.nan, math.nan]
        elif kind == "inf_range":
            v = [math.inf, a, e]
        elif kind == "negative_range":
            v = [-r, a, e]
        elif kind == "bad_azimuth":
            v = [r, 4.0, e]
        elif kind == "future_stamp":
            stamp = stamp_ns + FUTURE_S * NS
        elif kind == "old_stamp":
            stamp = max(0, stamp_ns - OLD_S * NS)
        elif kind == "wrong_frame":
            frame = "map"
        msg = self._msg(stamp, v, frame)
        if kind == "bad_nanosec":
            msg.header.stamp.nanosec = 1_500_000_000
        self.ledger.garbage[kind] += 1
        self._send(msg, stamp, reason)

    def _release(self, force: bool = False) -> None:
        keep = []
        for item in self._held:
            item[0] -= 1
            if item[0] <= 0 or force:
                self.ledger.delayed_outcomes[self._send(item[1], item[2])] += 1
            else:
                keep.append(item)
        self._held = keep

    def _event(self, name: str, stamp_ns: int) -> None:
        self.events.append({"event": name, "wall": time.monotonic(), "stamp_ns": stamp_ns})
        self.quiet_until_ns = max(self.quiet_until_ns, stamp_ns + int(QUIET_S * NS))

    def _late_burst(self, stamp_ns: int) -> None:
        """``--late-burst-size`` copies of the measurement three periods old, back to back."""
        self.burst_ns = None
        self._event("late burst", stamp_ns)
        old_stamp, values = self._recent[0]
        for _ in range(self.args.late_burst_size):
            self.ledger.late_burst += 1
            self._send(self._msg(old_stamp, values), old_stamp)

    def restart(self, start_ns: int) -> None:
        """The simulator starts again: the held messages go out now, the estimator is predicted to reset,
        and tampering starts again at ``start_ns``."""
        self.flush()
        self.ledger.restart()
        self.active, self.start_ns, self.quiet_until_ns, self._recent = False, start_ns, 0, []
        self._restarted = True

    def flush(self) -> None:
        """Send every message still held back (end of the run)."""
        self._held = [[1, m, s] for _, m, s in self._held]
        self._release(force=True)

    def _on_raw(self, msg) -> None:
        from gpf_nav.ros.conversions import stamp_to_ns
        stamp = stamp_to_ns(msg.header.stamp)
        values = [msg.vector.x, msg.vector.y, msg.vector.z]
        ledger = self.ledger
        if self._restarted:
            self._restarted = False
            self.events.append({"event": "restart", "wall": time.monotonic(), "stamp_ns": stamp})
        self._recent = (self._recent + [(stamp, values)])[-4:]
        if not self.active and self.start_ns is not None and stamp >= self.start_ns:
            self.active = True
        if self.fault_ns is not None and stamp >= self.fault_ns and self.fault_left > 0:
            if self.fault_left == self.args.fault_steps:
                self._event("fault", stamp)
            self.fault_left -= 1
            ledger.stream["passed"] += 1
            self._send(self._msg(stamp, [values[0] + BIAS, values[1], values[2]]), stamp)
            return
        burst = self.burst_ns is not None and stamp >= self.burst_ns and len(self._recent) == 4
        if not self.active or stamp < self.quiet_until_ns or burst:
            ledger.stream["passed"] += 1
            self._send(msg, stamp)
            if burst:
                self._late_burst(stamp)
            return
        a = self.args
        u = self.rng.random()
        edges = np.cumsum([a.drop, a.delay, a.duplicate, a.mask])
        sent_now = False
        if u < edges[0]:
            ledger.stream["dropped"] += 1
        elif u < edges[1]:
            ledger.stream["delayed"] += 1
            self._held.append([self.rng.randint(1, 3), msg, stamp])
        elif u < edges[2]:
            ledger.stream["duplicated"] += 1
            self._send(msg, stamp)
            ledger.duplicate_outcomes[self._send(self._msg(stamp, values), stamp)] += 1
            sent_now = True
        elif u < edges[3]:
            ledger.stream["masked"] += 1
            ledger.expected_masked += 1
            self._send(self._msg(stamp, [math.nan, values[1], values[2]]), stamp)
            sent_now = True
        else:
            ledger.stream["passed"] += 1
            self._send(msg, stamp)
            sent_now = True
        if sent_now:
            self._release()
        if self.rng.random() < a.garbage:
            ledger.singles += 1
            self._garbage(stamp, values)
        if self.rng.random() < a.burst:
            ledger.bursts += 1
            for _ in range(a.burst_size):
                ledger.burst_messages += 1
                self._garbage(stamp, values)


# --- the listener ------------------------------------------------------------------------------------------
class Listener:
    """Checks every estimator output for non-finite numbers; keeps the last diagnostics and the errors
    against truth at the estimate stamps that have a truth message."""

    def __init__(self, node):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseArray, Vector3Stamped
        from nav_msgs.msg import Odometry
        from std_msgs.msg import Float64
        self.node = node
        self.counts = Counter()
        self.non_finite = Counter()
        self.first_non_finite: dict[str, str] = {}
        self.levels = Counter()
        self.messages = Counter()
        self.last_status = None
        self.last_values: dict[str, str] = {}
        self.epoch = 0                          # simulator runs so far (estimates and truth are kept per run)
        self.truth: dict[tuple[int, int], np.ndarray] = {}
        self.estimates: dict[tuple[int, int], np.ndarray] = {}
        self.odometry_times: list[tuple[float, int]] = []  # (wall s, stamp ns) of every odometry message
        node.create_subscription(Odometry, "odometry/filtered", self._on_odom, 1000)
        node.create_subscription(Odometry, "truth/odometry", self._on_truth, 1000)
        node.create_subscription(Float64, "gpf/ess", lambda m: self._check("gpf/ess", [m.data]), 1000)
        node.create_subscription(Vector3Stamped, "gpf/costate",
                                 lambda m: self._check("gpf/costate", [m.vector.x, m.vector.y, m.vector.z]), 1000)
        node.create_subscription(PoseArray, "gpf/particles", self._on_particles, 100)
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)

    def _check(self, topic: str, values) -> bool:
        self.counts[topic] += 1
        arr = np.asarray(values, dtype=float)
        if arr.size and not np.all(np.isfinite(arr)):
            self.non_finite[topic] += 1
            self.first_non_finite.setdefault(topic, repr(arr.tolist())[:200])
            return False
        return True

    @staticmethod
    def _odom_values(m) -> np.ndarray:
        p, q, v, w = m.pose.pose.position, m.pose.pose.orientation, m.twist.twist.linear, m.twist.twist.angular
        return np.concatenate([[p.x, p.y, p.z, q.x, q.y, q.z, q.w, v.x, v.y, v.z, w.x, w.y, w.z],
                               np.asarray(m.pose.covariance, dtype=float), np.asarray(m.twist.covariance, dtype=float)])

    def _on_odom(self, m) -> None:
        from gpf_nav.ros.conversions import odometry_state, stamp_to_ns
        self.odometry_times.append((time.monotonic(), stamp_to_ns(m.header.stamp)))
        if self._check("odometry/filtered", self._odom_values(m)):
            self.estimates[(self.epoch, stamp_to_ns(m.header.stamp))] = odometry_state(m)

    def _on_truth(self, m) -> None:
        from gpf_nav.ros.conversions import odometry_state, stamp_to_ns
        self.truth[(self.epoch, stamp_to_ns(m.header.stamp))] = odometry_state(m)

    def _on_particles(self, m) -> None:
        values = [c for p in m.poses for c in (p.position.x, p.position.y, p.position.z)]
        self._check("gpf/particles", values)

    def _on_diag(self, msg) -> None:
        from gpf_nav.ros.diagnostics import STATUS_NAME, parse_values
        for status in msg.status:
            if status.name != STATUS_NAME:
                continue
            self.counts["/diagnostics"] += 1
            values = parse_values(status)
            bad = [f"{k}={v}" for k, v in values.items() if _non_finite_text(v)]
            if bad:
                self.non_finite["/diagnostics"] += 1
                self.first_non_finite.setdefault("/diagnostics", ", ".join(bad)[:200])
            level = int.from_bytes(status.level, "little") if isinstance(status.level, bytes) else int(status.level)
            self.levels[("OK", "WARN", "ERROR", "STALE")[min(level, 3)]] += 1
            for part in status.message.split("; "):  # causes, e.g. "integrity WARN 2.1 s ago: ..."
                self.messages[re.sub(r" [0-9.]+ s ago$", "", part.split(":")[0].split(" (")[0])] += 1
            self.last_status, self.last_values = status, values

    def seen(self) -> int:
        """Measurements the estimator has counted (accepted + rejected), from the last diagnostics."""
        v = self.last_values
        if not v:
            return -1
        return int(v["accepted rae"]) + int(v["measurements rejected"])

    def gap_after(self, wall: float, span: float) -> dict:
        """The longest wait for odometry over ``span`` wall s from ``wall``: in wall s, and in stamps between
        consecutive odometry messages of that span (s)."""
        after = [(w, t) for w, t in self.odometry_times if wall < w <= wall + span]
        walls = [wall] + [w for w, _ in after]
        stamps = [t for _, t in after]
        return {"first_odometry_wall_s": round(after[0][0] - wall, 2) if after else None,
                "max_gap_wall_s": round(max(np.diff(walls)), 2) if after else None,
                "max_gap_stamp_s": round(max(np.diff(stamps)) * 1e-9, 2) if len(stamps) > 1 else None}

    def errors(self) -> np.ndarray:
        common = sorted(set(self.estimates) & set(self.truth))
        if not common:
            return np.zeros(0)
        return np.array([np.linalg.norm(self.estimates[k][:3] - self.truth[k][:3]) for k in common])


def _non_finite_text(text: str) -> bool:
    """A diagnostics value that reads as NaN or inf."""
    try:
        return not math.isfinite(float(text))
    except ValueError:
        return False


# --- the run -----------------------------------------------------------------------------------------------
def _estimator_command(args) -> list[str]:
    return [sys.executable, "-m", "gpf_nav.ros.estimator_node", "--ros-args",
            "-p", "use_sim_time:=true", "-p", f"filter:={args.filter}", "-p", f"n_particles:={args.particles}",
            "-p", f"queue_depth:={args.queue_depth}", "-p", "diagnostics_period:=1.0",
            *(["-p", f"publish_rate:={args.publish_rate}"] if args.publish_rate is not None else []),
            "--log-level", "warn"]


def run(args) -> dict:
    """Run the soak; returns the summary dict (see :func:`format_summary`)."""
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
        summary = _summarise(args, ran, injector, injector.ledger, listener, alive, exit_code, _tail(log.name, 100_000),
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


def _summarise(args, sim, injector: Injector, ledger: Ledger, listener: Listener, alive: bool, exit_code: int, log_text: str,
               rss_start, rss_end, rss_samples, own_start, own_end, sim_wall: float,
               wall: float) -> dict:
    v = listener.last_values
    counted = {r: int(v.get(f"rejected {r}", -1)) for r in REASONS}
    accepted = int(v.get("accepted rae", -1))
    masked = int(v.get("masked components", -1))
    reasons = []
    for r in REASONS:
        reasons.append({"reason": r, "expected": ledger.expected_rejected[r], "counted": counted[r],
                        "match": ledger.expected_rejected[r] == counted[r]})
    accounted = (all(row["match"] for row in reasons) and accepted == ledger.expected_accepted
                 and masked == ledger.expected_masked)
    seen = accepted + int(v.get("measurements rejected", 0)) if v else -1
    errors = listener.errors()
    late = errors[errors.size // 2:]
    late_median = float(np.median(late)) if late.size else math.nan
    imu_published, imu_accepted = sim.published["imu"], int(v.get("accepted imu", -1))
    imu_loss = 1.0 - imu_accepted / imu_published if imu_published else 0.0
    non_finite = sum(listener.non_finite.values())
    events = [{"event": e["event"], "stamp_s": round(e["stamp_ns"] * 1e-9, 3), **listener.gap_after(e["wall"], QUIET_S / args.rate_factor)}
              for e in injector.events]
    wanted = [name for name, at in (("restart", args.restart_at), ("late burst", args.late_burst_at),
                                    ("fault", args.fault_at)) if at is not None]
    log_problems = [line for line in log_text.splitlines() if "Traceback" in line or "internal_error" in line
                    or "[ERROR]" in line or "[FATAL]" in line]
    checks = {
        "run completed": bool(sim.finished),
        "estimator alive to the end": alive,
        "estimator exited cleanly on SIGINT": exit_code == 0,
        "every message accounted for": accounted,
        f"IMU samples counted (at most {args.max_imu_loss:.0%} lost)": imu_loss <= args.max_imu_loss,
        "no internal_error or filter_error": counted["internal_error"] == 0 and counted["filter_error"] == 0,
        "no non-finite output": non_finite == 0 and listener.counts["odometry/filtered"] > 0,
        "no ERROR, FATAL or traceback in the estimator log": not log_problems,
        f"estimate follows truth (second-half median error <= {args.max_error:g} m)": late_median <= args.max_error,
    }
    if wanted:
        checks[f"events injected ({', '.join(wanted)}), odometry back within {args.max_gap:g} wall s of each"] = (
            sorted(e["event"] for e in events) == sorted(wanted)
            and all(e["max_gap_wall_s"] is not None and e["max_gap_wall_s"] <= args.max_gap for e in events))
    growth = None
    if rss_start.get("VmRSS") and rss_end.get("VmRSS"):
        growth = rss_end["VmRSS"] - rss_start["VmRSS"]
    return {
        "completed": bool(sim.finished),
        "passed": all(checks.values()),
        "checks": checks,
        "command": ("python -m gpf_nav.tools.soak " + " ".join(_argv(args))).rstrip(),
        "filter": args.filter,
        "particles": args.particles,
        "seed": args.seed,
        "epsilon": args.epsilon,
        "rate_factor": args.rate_factor,
        "simulated_minutes": args.sim_minutes,
        "warmup_s": args.warmup,
        "wall_seconds": round(wall, 1),
        "wall_seconds_simulation": round(sim_wall, 1),
        "simulator_measurements": sim.published["measurement"],
        "imu_published": imu_published,
        "imu_accepted": imu_accepted,
        "stream": dict(ledger.stream),
        "garbage": dict(ledger.garbage),
        "garbage_single": ledger.singles,
        "bursts": ledger.bursts,
        "burst_messages": ledger.burst_messages,
        "late_burst_messages": ledger.late_burst,
        "events": events,
        "delayed_verdicts": dict(ledger.delayed_outcomes),
        "duplicate_verdicts": dict(ledger.duplicate_outcomes),
        "sent_to_estimator": ledger.sent,
        "seen_by_estimator": seen,
        "expected_accepted": ledger.expected_accepted,
        "accepted": accepted,
        "expected_masked": ledger.expected_masked,
        "masked": masked,
        "reasons": reasons,
        "accounted": accounted,
        "rss_kib": {
            "estimator_start": rss_start.get("VmRSS"), "estimator_end": rss_end.get("VmRSS"),
            "estimator_growth": growth, "estimator_peak": rss_end.get("VmHWM"),
            "estimator_max_sampled": max((s[2] for s in rss_samples), default=None),
            "estimator_slope_per_sim_hour": _round(_slope_per_hour(rss_samples)),
            "estimator_second_half_growth": _second_half_growth(rss_samples),
            "soak_process_start": own_start.get("VmRSS"), "soak_process_end": own_end.get("VmRSS"),
            "samples": len(rss_samples),
        },
        "rss_series": [(round(w, 1), round(s, 1), r) for w, s, r in rss_samples],
        "outputs_checked": dict(listener.counts),
        "non_finite_outputs": dict(listener.non_finite),
        "first_non_finite": listener.first_non_finite,
        "diagnostics_levels": dict(listener.levels),
        "diagnostics_causes": {k: n for k, n in listener.messages.items() if k != "tracking"},
        "final_diagnostics": {k: v.get(k) for k in (
            "initialized from", "reinitializations", "ESS", "integrity level", "integrity samples",
            "integrity components", "integrity fault updates", "integrity warn updates", "integrity skipped updates",
            "integrity resets", "integrity fault reinitializations", "node clock jumps back", "accepted imu",
            "messages rejected")},
        "position_error_m": {"median": _round(float(np.median(errors))) if errors.size else None,
                             "p95": _round(float(np.percentile(errors, 95))) if errors.size else None,
                             "final": _round(float(errors[-1])) if errors.size else None,
                             "second_half_median": _round(late_median),
                             "compared": int(errors.size)},
        "estimator_log_problems": log_problems[:10],
    }


def _round(x, digits=1):
    return None if x is None or not math.isfinite(x) else round(x, digits)


def _argv(args) -> list[str]:
    out = []
    defaults = vars(_parser().parse_args([]))
    for key, value in vars(args).items():
        if key in ("json", "timeout", "domain_id", "keep_log") or value == defaults.get(key):
            continue
        out += [f"--{key.replace('_', '-')}", f"{value:g}" if isinstance(value, float) else str(value)]
    return out


def format_summary(s: dict) -> str:
    """The summary as a text table."""
    L = []
    L.append(f"gpf_nav soak: {s['filter']} N={s['particles']}, {s['simulated_minutes']:g} simulated min at "
             f"{s['rate_factor']:g}x in {s['wall_seconds']:.0f} s wall (seed {s['seed']}, epsilon {s['epsilon']:g})"
             + ("" if s["completed"] else "  ** DID NOT COMPLETE **"))
    L.append(f"  command: {s['command']}")
    r = s["rss_kib"]

    def mib(x):
        return "n/a" if x is None else f"{x / 1024:.1f} MiB"
    L.append(f"  estimator RSS: start {mib(r['estimator_start'])} (after {s['warmup_s']:g} s warm-up), "
             f"end {mib(r['estimator_end'])}, peak {mib(r['estimator_peak'])}")
    L.append(f"    growth {r['estimator_growth']} KiB ({r['estimator_second_half_growth']} KiB in the second half), "
             f"least-squares trend {r['estimator_slope_per_sim_hour']} KiB per simulated hour, {r['samples']} samples")
    L.append(f"  soak process RSS: start {mib(r['soak_process_start'])}, end {mib(r['soak_process_end'])}")
    L.append("")
    L.append(f"  {'measurements from the simulator':34} {s['simulator_measurements']:>7}")
    for c in STREAM_CATEGORIES:
        note = {"passed": "sent unchanged", "dropped": "never sent",
                "delayed": f"sent after 1-3 newer ones: {_verdicts(s['delayed_verdicts'])}",
                "duplicated": f"sent twice; 2nd copy: {_verdicts(s['duplicate_verdicts'])}",
                "masked": "range NaN: accepted, masked"}[c]
        L.append(f"    {c:32} {s['stream'][c]:>7}   {note}")
    L.append(f"  {'garbage messages':34} {sum(s['garbage'].values()):>7}   "
             f"({s['garbage_single']} single, {s['burst_messages']} in {s['bursts']} bursts)")
    reason_of = dict(GARBAGE)
    for kind, n in s["garbage"].items():
        L.append(f"    {kind:32} {n:>7}   -> {reason_of[kind]}")
    if s["late_burst_messages"]:
        L.append(f"  {'late burst (6 s late copies)':34} {s['late_burst_messages']:>7}")
    for e in s["events"]:
        L.append(f"  event {e['event']:12} at {e['stamp_s']:.1f} s: first odometry after {e['first_odometry_wall_s']} "
                 f"wall s, longest gap {e['max_gap_wall_s']} wall s ({e['max_gap_stamp_s']} s of stamps)")
    L.append(f"  {'sent to the estimator':34} {s['sent_to_estimator']:>7}   counted by it: {s['seen_by_estimator']}")
    L.append(f"  {'imu (simulator -> estimator)':34} {s['imu_published']:>7}   accepted: {s['imu_accepted']}")
    L.append("")
    L.append(f"  {'verdict':32} {'expected':>9} {'counted':>9}")
    L.append(f"  {'accepted rae':32} {s['expected_accepted']:>9} {s['accepted']:>9}"
             + ("" if s["expected_accepted"] == s["accepted"] else "   MISMATCH"))
    L.append(f"  {'masked components':32} {s['expected_masked']:>9} {s['masked']:>9}"
             + ("" if s["expected_masked"] == s["masked"] else "   MISMATCH"))
    for row in s["reasons"]:
        if row["expected"] or row["counted"]:
            L.append(f"  {'rejected ' + row['reason']:32} {row['expected']:>9} {row['counted']:>9}"
                     + ("" if row["match"] else "   MISMATCH"))
    L.append(f"  (every other reason: expected 0, counted "
             f"{sum(r['counted'] for r in s['reasons'] if not r['expected'])})")
    L.append("")
    L.append("  outputs checked: " + ", ".join(f"{k} {n}" for k, n in sorted(s["outputs_checked"].items()))
             + f"; non-finite: {sum(s['non_finite_outputs'].values())}")
    e = s["position_error_m"]
    L.append(f"  position error vs truth: median {e['median']} m, p95 {e['p95']} m, final {e['final']} m, "
             f"second-half median {e['second_half_median']} m ({e['compared']} estimates)")
    L.append("  diagnostics levels: " + ", ".join(f"{k} {n}" for k, n in s["diagnostics_levels"].items())
             + ("; causes: " + ", ".join(f"{k} {n}" for k, n in s["diagnostics_causes"].items())
                if s["diagnostics_causes"] else ""))
    L.append("  final diagnostics: " + ", ".join(f"{k} {v}" for k, v in s["final_diagnostics"].items()))
    for line in s["estimator_log_problems"]:
        L.append(f"  estimator log: {line[:200]}")
    if s.get("estimator_log"):
        L.append(f"  estimator log file: {s['estimator_log']}")
    L.append("")
    for name, ok in s["checks"].items():
        L.append(f"  [{'PASS' if ok else 'FAIL'}] {name}")
    L.append(f"  soak {'PASSED' if s['passed'] else 'FAILED'}")
    return "\n".join(L)


def _verdicts(d: dict) -> str:
    return ", ".join(f"{k} {n}" for k, n in sorted(d.items())) or "none"


def main(argv: list[str] | None = None) -> int:
    """Run the soak, print the table (or ``--json``); 0 when every check passed."""
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    summary = run(args)
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0 if summary.get("passed") else 1


__all__ = ["main", "run", "rss_kib", "Ledger", "GARBAGE", "format_summary"]

if __name__ == "__main__":
    sys.exit(main())
