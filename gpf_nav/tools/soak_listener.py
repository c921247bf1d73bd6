"""The soak's listener: checks every estimator output and keeps what the report compares.

It subscribes to ``odometry/filtered``, ``gpf/ess``, ``gpf/costate``, ``gpf/particles`` and
``/diagnostics`` and counts every message whose numbers are not all finite; it keeps the last diagnostics
values (the estimator's counters), the diagnostics levels and causes, the estimates and the truth by
stamp (per simulator run) and the wall time of every odometry message (for the gaps after an event).
"""
from __future__ import annotations

import math
import re
import time
from collections import Counter

import numpy as np


class Listener:
    """Checks every estimator output for non-finite numbers; keeps the last diagnostics and the errors
    against truth at the estimate stamps that have a truth message."""

    def __init__(self, node):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseArray, Vector3Stamped
        from nav_msgs.msg import Odometry
        from std_msgs.msg import Float64
        self.counts = Counter()
        self.non_finite = Counter()
        self.first_non_finite: dict[str, str] = {}
        self.levels = Counter()
        self.messages = Counter()
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
            self.last_values = values

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
        """Position error (m) at every stamp with both an estimate and a truth message, in stamp order."""
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
