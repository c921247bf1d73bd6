"""Bounded history of the inputs the filter took, each with a snapshot of what it took them from.

A late measurement (stamped before the filter's time, within ``length_ns``) is fused at its own stamp
by restoring the snapshot taken before the first input stamped after it, applying it, and re-applying
the inputs that came after (:meth:`gpf_nav.estimator.engine.EstimatorEngine.measurement`). A snapshot
is a deep copy of the filter, so it holds everything an update depends on (particles, weights, the
generator's state, gate streaks); re-application therefore gives bit for bit the estimate of in-order
delivery. No ROS here.

Memory: one filter copy per input of the last ``length_ns`` (for the lunar GPF with N particles about
``N * 9 * 8`` bytes of particles plus their weights and caches). Cost: restoring is free (the
snapshot object becomes the filter); re-applying ``k`` inputs costs ``k + 1`` predict/update steps
and ``k + 1`` copies.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np


@dataclass
class Entry:
    """One input the filter took: ``y`` ``(m,)`` stamped ``t_ns`` of ``stream`` with ``sensor`` (None:
    the model's own), and ``before``: the filter state it was applied to, at ``before_ns``, with the
    engine's per-stream gate streaks then."""

    t_ns: int
    stream: str
    y: np.ndarray
    sensor: object
    before: object
    before_ns: int
    streaks: dict


class History:
    """Inputs sorted by stamp (equal stamps in arrival order), the oldest dropped past ``length_ns``.

    Args:
        length_ns: how far back (ns, from the newest stamp) a late input may be fused; 0 keeps nothing.
    """

    def __init__(self, length_ns: int):
        self.length_ns = int(length_ns)
        self.entries: list[Entry] = []

    def __len__(self) -> int:
        return len(self.entries)

    def clear(self) -> None:
        self.entries = []

    def append(self, entry: Entry) -> None:
        """Add an input stamped at or after every other one, then drop those out of the window."""
        self.entries.append(entry)
        horizon = entry.t_ns - self.length_ns
        drop = 0
        while drop < len(self.entries) and self.entries[drop].t_ns < horizon:
            drop += 1
        del self.entries[:drop]

    def split(self, stamp_ns: int) -> int | None:
        """Index of the first input stamped after ``stamp_ns`` (a late input goes before it), or None
        when ``stamp_ns`` is older than the window: before the oldest kept snapshot's time."""
        stamps = [e.t_ns for e in self.entries]
        i = bisect.bisect_right(stamps, stamp_ns)
        if i == len(self.entries) or stamp_ns < self.entries[i].before_ns:
            return None
        if self.entries and stamp_ns < self.entries[-1].t_ns - self.length_ns:
            return None
        return i

    def take(self, i: int) -> list[Entry]:
        """Remove and return the inputs from index ``i`` on (to be re-applied)."""
        out = self.entries[i:]
        del self.entries[i:]
        return out
