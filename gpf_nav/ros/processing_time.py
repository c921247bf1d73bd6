"""How long the node takes over each measurement message: the wall time from its callback to the odometry
it publishes (the checks, the filter's prediction and update, the outputs), per ``/diagnostics`` period.

It is the node's real-time margin: at a sensor rate of ``f`` Hz the maximum must stay below ``1 / f`` s
(less whatever else the process runs), or the messages queue. It is the node's own share of the end-to-end
latency that ``gpf-nav bench --node`` measures from outside (transport and the subscriber's executor are
the rest)."""
from __future__ import annotations

import time
from typing import Callable


class ProcessingTime:
    """The wall times of the measurement messages handled since the last :meth:`period_values`.

    Args:
        clock: seconds of a monotonic wall clock (:func:`time.perf_counter`; a test's own).
    """

    def __init__(self, clock: Callable[[], float] = time.perf_counter):
        self._clock = clock
        self._count, self._total, self._longest = 0, 0.0, 0.0

    def start(self) -> float:
        """The clock now: hand it to :meth:`stop` when the message has been handled."""
        return self._clock()

    def stop(self, started: float) -> None:
        """Count one message handled since ``started``."""
        spent = self._clock() - started
        self._count += 1
        self._total += spent
        self._longest = max(self._longest, spent)

    def period_values(self) -> list[tuple[str, str]]:
        """The ``/diagnostics`` key/values of the period (``n/a`` without a message), then a new period."""
        count, mean, longest = self._count, self._total / max(self._count, 1), self._longest
        self._count, self._total, self._longest = 0, 0.0, 0.0
        figure = (lambda s: f"{s * 1e3:.3f}") if count else (lambda s: "n/a")
        return [("measurements timed", str(count)), ("measurement processing mean [ms]", figure(mean)),
                ("measurement processing max [ms]", figure(longest))]
