"""Bounded history of the inputs the filter took, every :data:`SNAPSHOT_EVERY`-th with a snapshot of what
it took it from.

A late measurement (stamped before the filter's time, within ``length_ns``) is fused at its own stamp
by restoring the last snapshot taken before the first input stamped after it, re-applying the inputs
between, applying the late one, and re-applying the inputs that came after
(:meth:`gpf_nav.estimator.measurements.LateFusion.fuse`). A snapshot is a deep copy of the filter,
so it holds everything an update depends on (particles, weights, the generator's state, gate streaks);
re-application therefore gives bit for bit the estimate of in-order delivery. The package's models and
sensors are configuration that filtering never changes (they keep pure caches only): the snapshots of a
filter that uses no others share them (:func:`configuration`), which halves the copy's cost. No ROS here.

While IMU samples come late (an IMU sample delivered after the measurement it precedes, re-applied from
the last snapshot before that measurement) the engine also keeps a snapshot of the newest input, dropped when
the next one comes (``extra``): the re-application then starts at that input instead of up to
:data:`SNAPSHOT_EVERY` - 1 inputs earlier.

Memory: one filter copy per :data:`SNAPSHOT_EVERY` inputs of the last ``length_ns`` (for the lunar GPF with
N particles about ``N * 9 * 8`` bytes of particles plus their weights and caches). Cost: a copy every
:data:`SNAPSHOT_EVERY` inputs; restoring is
free (the snapshot object becomes the filter); a late input stamped before ``k`` kept ones costs up to
``k + SNAPSHOT_EVERY`` predict/update steps.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.sensors.sensor import Sensor

SNAPSHOT_EVERY = 4
"""Inputs per snapshot: a late input re-applies at most ``SNAPSHOT_EVERY - 1`` more of them."""


@dataclass
class Entry:
    """One input the filter took: ``y`` ``(m,)`` stamped ``t_ns`` of ``stream`` with ``sensor`` (None:
    the model's own), and ``before``: the filter state it was applied to (None: not kept, see
    :data:`SNAPSHOT_EVERY`), at ``before_ns``, with the engine's per-stream gate streaks then; ``extra``: a
    snapshot kept only while the input is the newest."""

    t_ns: int
    stream: str
    y: np.ndarray
    sensor: object
    before: object
    before_ns: int
    streaks: dict
    extra: bool = False


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

    def wants_snapshot(self) -> bool:
        """Whether the next input should keep a snapshot: when none of the last :data:`SNAPSHOT_EVERY` - 1
        kept inputs has one (an ``extra`` one does not count)."""
        recent = self.entries[-(SNAPSHOT_EVERY - 1):] if SNAPSHOT_EVERY > 1 else []
        return all(e.before is None or e.extra for e in recent)

    def append(self, entry: Entry) -> None:
        """Add an input stamped at or after every other one, then drop those out of the window (but the
        last one with a snapshot before the first one kept, which restoring it needs). The previous input's
        ``extra`` snapshot is dropped."""
        if self.entries and self.entries[-1].extra:
            self.entries[-1].before, self.entries[-1].extra = None, False
        self.entries.append(entry)
        horizon = entry.t_ns - self.length_ns
        drop = 0
        while drop < len(self.entries) and self.entries[drop].t_ns < horizon:
            drop += 1
        while 0 < drop < len(self.entries) and self.entries[drop].before is None:
            drop -= 1
        del self.entries[:drop]

    def split(self, stamp_ns: int) -> tuple[int, int] | None:
        """``(i, j)``: the index ``i`` of the first input stamped after ``stamp_ns`` (a late input goes
        before it) and ``j <= i`` of the last input with a snapshot up to it (where re-application
        starts); None when ``stamp_ns`` is older than the window (before the time of the state kept for
        ``i``) or no snapshot precedes it."""
        stamps = [e.t_ns for e in self.entries]
        i = bisect.bisect_right(stamps, stamp_ns)
        if i == len(self.entries) or stamp_ns < self.entries[i].before_ns:
            return None
        if self.entries and stamp_ns < self.entries[-1].t_ns - self.length_ns:
            return None
        j = i
        while j >= 0 and self.entries[j].before is None:
            j -= 1
        return None if j < 0 else (i, j)

    def take(self, j: int) -> list[Entry]:
        """Remove and return the inputs from index ``j`` on (to be re-applied)."""
        out = self.entries[j:]
        del self.entries[j:]
        return out


def configuration(flt: object) -> dict[int, object]:
    """The models and sensors ``flt`` refers to, by ``id``: a memo for :func:`copy.deepcopy` under which
    copies of ``flt`` share them. Found by walking the attributes of ``gpf_nav``'s objects and their
    containers. Empty (every copy its own) when one of them is a user's class: this package's models and
    sensors keep nothing but pure caches, a user's may keep state that a snapshot must restore."""
    found, seen, stack = {}, set(), [flt]
    while stack:
        item = stack.pop()
        if id(item) in seen:
            continue
        seen.add(id(item))
        own = type(item).__module__.startswith("gpf_nav.")
        if isinstance(item, (StateSpaceModel, Sensor)):
            if not own:
                return {}
            found[id(item)] = item
        if isinstance(item, dict):
            stack.extend(item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend(item)
        elif own and hasattr(item, "__dict__"):
            stack.extend(vars(item).values())
    return found
