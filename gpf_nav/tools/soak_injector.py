"""The soak's injector node: forwards the simulator's measurements to the estimator and tampers with them.

After ``--warmup`` simulated seconds each measurement from the simulator (its ``measurements/rae``
remapped to :data:`RAW_TOPIC`), with a seeded random stream, is

* ``dropped`` (never sent), ``delayed`` (held back until 1-3 later measurements have been sent: a
  reorder), ``duplicated`` (sent twice back to back), ``masked`` (sent with its range NaN: "not
  measured") or passed on unchanged, one of these with probabilities ``--drop --delay --duplicate
  --mask``; and independently
* followed by one ``garbage`` message (``--garbage``) and by a ``burst`` of ``--burst-size`` garbage
  messages back to back (``--burst``). Garbage kinds are taken in turn from
  :data:`gpf_nav.tools.soak_ledger.GARBAGE`: all-NaN, inf range, negative range, azimuth beyond pi,
  ``nanosec >= 1e9``, a stamp 1e6 s in the future, a stamp 600 s old (beyond the estimator's
  ``history_length``), a wrong ``frame_id``.

Two timing events are injected here, each followed by a quiet span of :data:`QUIET_S` in which every
measurement is passed on unchanged: ``--late-burst-at S`` sends ``--late-burst-size`` copies of the
measurement three periods (6 s) old back to back (the estimator's re-application budget takes what it can
and refuses the rest as ``reapply_budget``); ``--fault-at S`` adds a +3 km range bias to ``--fault-steps``
measurements (the co-state monitor goes to a persistent FAULT and the estimator's
``integrity_fault_action`` acts). A simulator restart (``--restart-at``) is announced by
:meth:`Injector.restart`. Every message sent is entered in the :class:`~gpf_nav.tools.soak_ledger.Ledger`.
"""
from __future__ import annotations

import argparse
import math
import random
import time

import numpy as np

from gpf_nav.tools.soak_ledger import GARBAGE, NS, Ledger

RAW_TOPIC = "soak/raw/rae"
FUTURE_S = 1_000_000   # s ahead of the stamp for future_stamp (far beyond max_future)
OLD_S = 600            # s behind the stamp for old_stamp
BIAS = 3000.0          # m, the range bias of --fault-at
QUIET_S = 150.0        # simulated s after a late burst or a fault without other tampering


class Injector:
    """Forwards :data:`RAW_TOPIC` to ``measurements/rae`` with the tampering described in the module
    docstring. It turns ``active`` from the first measurement stamped at or after ``start_ns`` on;
    before that everything is passed on."""

    def __init__(self, node, args: argparse.Namespace, frame: str):
        from geometry_msgs.msg import Vector3Stamped
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
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
