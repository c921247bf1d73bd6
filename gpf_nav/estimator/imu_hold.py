"""IMU hold: the input the filter's predictions take from the IMU, and the IMU samples that come late.

* A prediction to a stamp ``t`` takes the world-frame specific force of the latest IMU sample stamped
  strictly before ``t`` (zero-order hold); none when there is no such sample within ``imu_timeout`` s
  before ``t``.
* An IMU sample delivered after a measurement stamped after it (the topics arrive in any order) that
  should have been that measurement's input is late: the history is re-applied from it in the same way as
  for a late measurement (:mod:`gpf_nav.estimator.measurements`), so the estimate does not depend on the
  order of the two topics. The re-application waits until the IMU has caught up with the filter's time (a
  sample stamped at or after it) or the next measurement, whichever comes first, and runs once from the
  earliest such sample: an IMU stream lagging by many samples (a backlog after a stall) costs one
  re-application, not one per sample, which would keep the node too busy to catch up. Predictions between
  measurements (:mod:`gpf_nav.estimator.extrapolation`) meanwhile hold the inputs known so far.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from gpf_nav.estimator.engine_config import EngineConfig
from gpf_nav.estimator.history import History

LATE_IMU_MEMORY = 50
"""Inputs after a late IMU sample during which the newest input keeps a snapshot too
(:mod:`gpf_nav.estimator.history`): a measurement whose IMU sample comes after it then re-applies one input,
not up to ``SNAPSHOT_EVERY`` of them, for a copy of the filter per input (a sixth of an update)."""
IMU_SAMPLES = 4096
"""IMU samples kept (the zero-order hold looks them up, also when re-applying the history)."""


class ImuHold:
    """The last :data:`IMU_SAMPLES` IMU samples and the late ones not yet re-applied.

    Attributes:
        samples: ``(stamp_ns, specific_force)`` in stamp order, the specific force ``(3,)`` [m/s^2] in the
            world frame.
        late_count: samples that came after a measurement that needed them.
    """

    def __init__(self, config: EngineConfig):
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget every sample (the engine's start-up state)."""
        self.samples: deque[tuple[int, np.ndarray]] = deque(maxlen=IMU_SAMPLES)
        self.late_count = 0
        self._late_ns: int | None = None  # the earliest late sample not yet re-applied
        self._late_recent = 0             # inputs to come that keep an extra snapshot (LATE_IMU_MEMORY)

    @property
    def newest_ns(self) -> int | None:
        """The newest sample's stamp (None before the first one)."""
        return self.samples[-1][0] if self.samples else None

    def hold(self, stamp_ns: int, specific_force: np.ndarray) -> None:
        """Keep ``specific_force`` ``(3,)`` as the input from ``stamp_ns`` on (stamped at or after the newest)."""
        self.samples.append((stamp_ns, specific_force))

    def input_at(self, stamp_ns: int) -> np.ndarray | None:
        """The input ``(3,)`` of a prediction to ``stamp_ns``: the latest sample stamped before it, None when
        there is none or it is older than ``imu_timeout``."""
        for t, u in reversed(self.samples):
            if t < stamp_ns:
                return u if (stamp_ns - t) * 1e-9 <= self.config.imu_timeout else None
        return None

    def note_late(self, stamp_ns: int, specific_force: np.ndarray, history: History) -> None:
        """A sample, just held, stamped before the filter's time: when it is the input the prediction of an
        input of ``history`` should have held, the history is to be re-applied from it (:meth:`take_late`).
        Beyond the history, or too old to be that input (``imu_timeout``), nothing changes."""
        split = history.split(stamp_ns)
        if split is None or self.input_at(history.entries[split[0]].t_ns) is not specific_force:
            return
        self.late_count += 1
        self._late_recent = LATE_IMU_MEMORY
        if self._late_ns is None:  # (samples come in stamp order: the first is the earliest)
            self._late_ns = stamp_ns

    def take_late(self) -> int | None:
        """The stamp of the earliest late sample not yet re-applied, now taken (None if there is none)."""
        stamp_ns, self._late_ns = self._late_ns, None
        return stamp_ns

    def forget_late(self) -> None:
        """Drop the late sample not yet re-applied (the filter starts again)."""
        self._late_ns = None

    def extra_snapshot_due(self) -> bool:
        """Whether the input about to be applied comes within :data:`LATE_IMU_MEMORY` inputs of a late
        sample (its snapshot is then kept while it is the newest); counts that input."""
        due = self._late_recent > 0
        self._late_recent = max(0, self._late_recent - 1)
        return due

    def age(self, now_ns: int | None) -> float | None:
        """Seconds from the newest sample's stamp to ``now_ns`` (None before the first one)."""
        if not self.samples or not now_ns:
            return None
        return (now_ns - self.samples[-1][0]) * 1e-9

    def silent(self, now_ns: int | None) -> bool:
        """Whether an IMU heard before has been silent for longer than ``imu_timeout`` at ``now_ns``."""
        age = self.age(now_ns)
        return age is not None and age > self.config.imu_timeout
