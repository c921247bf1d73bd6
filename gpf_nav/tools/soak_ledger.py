"""The soak's accounting: what the injector sent, and the verdict the estimator must give each message.

The prediction uses the estimator's own rules (docs/ros.md, *Bad input*): a garbage kind has exactly one
refusal reason (:data:`GARBAGE`); a message whose stamp is older than the newest one already accepted by at
most ``history_length`` (10 s, the estimator's default) is accepted and fused at its stamp, unless the
re-application budget (``reapply_budget``) is spent; an older one is ``older_than_history``; an equal stamp
is accepted (so a duplicate is accepted and used twice: the second copy is a ``dt = 0`` update, which the
integrity monitor skips). Pure bookkeeping, no ROS.
"""
from __future__ import annotations

from collections import Counter

from gpf_nav.estimator.input_checks import REASONS, ReapplyBudget
from gpf_nav.estimator.params import BY_NAME

NS = 1_000_000_000
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
HISTORY_S = BY_NAME["history_length"].default  # s: late stamps within it are fused
REAPPLY_BUDGET = BY_NAME["reapply_budget"].default  # s of lateness per s of filter time
STREAM_CATEGORIES = ("passed", "dropped", "delayed", "duplicated", "masked")


class Ledger:
    """What the injector did and what the estimator must say about it."""

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
