"""Integrity watch: the co-state integrity monitor (:class:`gpf_nav.integrity.CostateMonitor`) fed at each
update, its alarms held for the diagnostics, and the policy for a persistent FAULT.

* The monitor takes the co-state of every update with the model's own measurement, over the components
  its last co-state covers (the filter's ``costate_measured``); not that of a re-applied update (it was
  fed when first applied), of one at which the core filter re-initialised itself, or of one with no time
  step (counted as skipped). Only filters with a co-state have it (the GPF; the SPF with
  ``compute_costate``). It starts again at every (re-)initialisation of the filter, and after raising (the
  error is kept for the diagnostics).
* A WARN or FAULT stays reported for ``monitor_hold`` s of the steady clock (< 0: until the monitor starts
  again).
* After ``fault_updates`` updates in a row at FAULT the filter is re-initialised by ``fault_action``:
  ``"measurements"`` starts it again from the next ``init_window`` measurements (the batch fit, even with an
  ``initial_state``), ``"prior"`` from the last initial state (parameters, ``set_state``, ``set_pose`` or batch
  fit) predicted to the filter's time; ``"none"`` leaves it (the FAULT is only reported).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from gpf_nav.estimator.engine_config import EngineConfig
from gpf_nav.filters.interface import COSTATE, Filter
from gpf_nav.integrity import CostateMonitor, IntegrityStatus

LEVEL_RANK = {"OK": 0, "WARN": 1, "FAULT": 2}
FAULT_ACTIONS = ("none", "measurements", "prior")
"""What a persistent integrity FAULT leads to (``EngineConfig.fault_action``)."""


@dataclass(frozen=True)
class IntegrityReport:
    """What :meth:`gpf_nav.estimator.engine.EstimatorEngine.integrity` says about the co-state monitor.

    Attributes:
        state: ``"active"``, ``"disabled"`` (``monitor_enabled: false``) or ``"unavailable"`` (the
            filter has no co-state: EKF, UKF, EnKF, SPF without ``compute_costate``).
        level: the level reported: worst of the last update's and of the held alarms (``"OK"``,
            ``"WARN"``, ``"FAULT"``); ``"OK"`` unless active.
        status: the monitor's last :class:`IntegrityStatus` (None unless active).
        alarm: the status of the alarm behind ``level`` when it is held (None when ``level`` is the
            last update's own), and ``alarm_age`` its age [s, steady clock].
        samples, rejected, skipped, quarantined: monitor samples since its last reset; samples it
            ignored (non-finite); updates not fed (``dt = 0``); samples kept out of its reference.
        fault_updates, warn_updates: updates at FAULT / at WARN since start-up (cumulative).
        resets: monitor resets since start-up.
        error: the last exception the monitor raised ("" if none; the monitor is then reset).
    """

    state: str
    level: str = "OK"
    status: IntegrityStatus | None = None
    alarm: IntegrityStatus | None = None
    alarm_age: float = 0.0
    samples: int = 0
    rejected: int = 0
    skipped: int = 0
    quarantined: int = 0
    fault_updates: int = 0
    warn_updates: int = 0
    resets: int = 0
    error: str = ""


class IntegrityWatch:
    """Feeds the co-state monitor, holds its alarms and counts its FAULTs in a row.

    Args:
        config: the engine's settings (``monitor``, ``monitor_hold``, ``fault_action``, ``fault_updates``).
        clock: the steady clock [s] of the alarm holds.

    Attributes:
        monitor: the :class:`CostateMonitor` (None: disabled, ``monitor`` None).
        fault_streak: updates in a row at FAULT since the monitor started again.
        fault_updates, warn_updates: updates at FAULT / at WARN (cumulative).
        resets: times the monitor started again after taking samples (cumulative).
        error: the last exception the monitor raised ("" if none).
    """

    def __init__(self, config: EngineConfig, clock: Callable[[], float]):
        self.config = config
        self.clock = clock
        self.monitor = CostateMonitor(**config.monitor) if config.monitor is not None else None
        self.fault_updates = 0
        self.warn_updates = 0
        self.resets = 0
        self.error = ""
        self.fault_streak = 0
        self._skipped = 0  # updates not fed since the monitor started again
        self._alarms: dict[str, tuple[float, IntegrityStatus]] = {}  # level -> (clock, status) of its last

    def reset(self) -> None:
        """Start the monitor again (the filter was (re-)initialised)."""
        self.fault_streak = 0
        if self.monitor is None:
            return
        if self.monitor.samples or self._skipped:
            self.resets += 1
        self.monitor.reset()
        self._skipped = 0
        self._alarms = {}

    def feed(self, flt: Filter, dt: float) -> bool:
        """Give the monitor the co-state of the update ``flt`` just made after a prediction of ``dt`` s.
        Never raises: False when the monitor did (every monitor is then to start again)."""
        if self.monitor is None or COSTATE not in flt.capabilities:
            return True
        if dt <= 0.0:
            self._skipped += 1
            return True
        measured = np.array(flt.costate_measured, dtype=bool)
        try:
            status = self.monitor.update(np.asarray(flt.costate_mean, dtype=float), measured)
        except Exception as err:  # noqa: BLE001 - e.g. a co-state of another shape: start again
            self.error = f"{type(err).__name__}: {err}"
            return False
        self.fault_streak = self.fault_streak + 1 if status.level == "FAULT" else 0
        if status.level == "FAULT":
            self.fault_updates += 1
        elif status.level == "WARN":
            self.warn_updates += 1
        if status.level != "OK":
            self._alarms[status.level] = (self.clock(), status)
        return True

    @property
    def persistent_fault(self) -> bool:
        """Whether the FAULT has lasted ``fault_updates`` updates and a ``fault_action`` is to re-initialise."""
        return self.config.fault_action != "none" and self.fault_streak >= self.config.fault_updates

    def report(self, flt: Filter) -> IntegrityReport:
        """The monitor's state for the diagnostics, ``flt`` the filter it watches."""
        common = dict(fault_updates=self.fault_updates, warn_updates=self.warn_updates, resets=self.resets,
                      error=self.error)
        if self.monitor is None:
            return IntegrityReport("disabled", **common)
        if COSTATE not in flt.capabilities:
            return IntegrityReport("unavailable", **common)
        m = self.monitor
        status = m.status
        level, alarm, age = status.level, None, 0.0
        now = self.clock()
        for held in ("FAULT", "WARN"):
            if held not in self._alarms or LEVEL_RANK[held] <= LEVEL_RANK[level]:
                continue
            t, s = self._alarms[held]
            if self.config.monitor_hold < 0 or now - t < self.config.monitor_hold:
                level, alarm, age = held, s, now - t
                break
        return IntegrityReport("active", level, status, alarm, age, m.samples, m.rejected, self._skipped,
                               m.quarantined, **common)
