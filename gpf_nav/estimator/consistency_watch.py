"""Consistency watch: the consistency monitor (:class:`gpf_nav.integrity.ConsistencyMonitor`) tested with
the innovation of each measurement against the predicted estimate, before the update, and its FAULT held
for the diagnostics: the filter's covariance too small for what the measurements show is a FAULT. Not a
re-applied measurement (it was tested when first applied), nor one the innovation gate refused. A FAULT
stays reported for ``monitor_hold`` s of the steady clock (< 0: until the engine is reset); the monitor
starts again at every (re-)initialisation of the filter, and after raising (the error is kept)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from gpf_nav.estimator.engine_config import EngineConfig
from gpf_nav.filters.interface import Filter
from gpf_nav.integrity import ConsistencyMonitor, ConsistencyStatus, innovation_moments
from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.sensors import ModelSensor, Sensor


@dataclass(frozen=True)
class ConsistencyReport:
    """What :meth:`gpf_nav.estimator.engine.EstimatorEngine.consistency_report` says about the consistency
    monitor (:mod:`gpf_nav.integrity.consistency`).

    Attributes:
        level: ``"OK"``, ``"WARN"`` or ``"FAULT"``: the last update's, or ``"FAULT"`` while an alarm is held
            (``monitor_hold``).
        status: the monitor's last :class:`ConsistencyStatus`.
        alarm: the held FAULT's status (None when ``level`` is the last update's) and ``alarm_age`` [s].
        updates, rejected: updates tested and updates that could not be (since the last reset).
        fault_updates: updates at FAULT since start-up (cumulative).
        error: the last exception the monitor raised ("" if none; the monitor is then reset).
    """

    level: str
    status: ConsistencyStatus
    alarm: ConsistencyStatus | None
    alarm_age: float
    updates: int
    rejected: int
    fault_updates: int
    error: str


class ConsistencyWatch:
    """Tests the consistency monitor with each measurement's innovation and holds its FAULT.

    Args:
        config: the engine's settings (``consistency``, ``monitor_hold``).
        model: the filter's model (its own measurement, for measurements without a sensor).
        clock: the steady clock [s] of the alarm hold.

    Attributes:
        monitor: the :class:`ConsistencyMonitor` (None: disabled, ``consistency`` None).
        fault_updates: updates at FAULT (cumulative).
        error: the last exception the monitor raised ("" if none).
    """

    def __init__(self, config: EngineConfig, model: StateSpaceModel, clock: Callable[[], float]):
        self.config = config
        self.clock = clock
        self.monitor = ConsistencyMonitor(**config.consistency) if config.consistency is not None else None
        self.fault_updates = 0
        self.error = ""
        self._model_sensor = ModelSensor(model)
        self.drop_alarm()

    def reset(self) -> None:
        """Start the monitor again (the filter was (re-)initialised); a held FAULT stays."""
        if self.monitor is not None:
            self.monitor.reset()

    def drop_alarm(self) -> None:
        """Forget the held FAULT (the engine's start-up state)."""
        self._alarm: tuple[float, ConsistencyStatus] | None = None

    def test(self, flt: Filter, y: np.ndarray, sensor: Sensor | None) -> None:
        """Give the monitor the innovation of ``y`` ``(m,)`` (of ``sensor``; None: the model's own
        measurement) against the predicted estimate of ``flt`` (never raises)."""
        if self.monitor is None:
            return
        try:
            if sensor is not None:  # with the sensor's estimated bias, if any
                sensor, mean, cov = flt.predicted_estimate(sensor)
            else:
                mean, cov = flt.mean, flt.covariance
            r, S = innovation_moments(sensor if sensor is not None else self._model_sensor, y, mean, cov,
                                      flt.time)
            status = self.monitor.update(r, S)
        except Exception as err:  # noqa: BLE001 - a monitor failure must not stop the update
            self.error = f"{type(err).__name__}: {err}"
            self.monitor.reset()
            return
        if status.level == "FAULT":
            self.fault_updates += 1
            self._alarm = (self.clock(), status)

    def report(self) -> ConsistencyReport | None:
        """The monitor's state for the diagnostics (None when disabled)."""
        m = self.monitor
        if m is None:
            return None
        alarm, age = None, 0.0
        if self._alarm is not None and m.status.level != "FAULT":
            t, held = self._alarm
            age = self.clock() - t
            if self.config.monitor_hold < 0 or age < self.config.monitor_hold:
                alarm = held
        level = "FAULT" if alarm is not None else m.status.level
        return ConsistencyReport(level, m.status, alarm, age, m.updates, m.rejected, self.fault_updates,
                                 self.error)
