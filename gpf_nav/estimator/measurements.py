"""Measurement handling: the innovation gate a measurement passes, and the fusion of a late measurement at
its own stamp.

* A stream with a gate (``gates``) is tested on the predicted estimate
  (:func:`gpf_nav.sensors.innovation_distance`, chi-square; with the sensor's estimated bias and its sigma
  when it has bias states), of each model a multiple-model filter holds
  (:meth:`~gpf_nav.filters.interface.Filter.predicted_estimates`): refused as ``innovation_gate`` (the
  filter stays predicted to the stamp) when no model admits it, unless ``gate_limit`` were refused in a
  row.
* A measurement stamped before the filter's time, by at most ``history_length`` s, is fused at its own
  stamp: the filter is restored from the last snapshot taken before it (:mod:`gpf_nav.estimator.history`),
  the inputs between are re-applied, it is updated with the late input, and the later inputs are
  re-applied; the result equals in-order delivery bit for bit. Older stamps are refused
  (``older_than_history``), and so are stamps within it but before the filter's (re-)initialisation
  (``stale_stamp``). With ``history_length`` 0 every stamp before the filter's time is ``stale_stamp``.
* Re-application is paid from a budget in seconds of stamps
  (:class:`gpf_nav.estimator.input_checks.ReapplyBudget`: ``reapply_budget`` s per second of the filter's
  time, at most ``history_length`` s saved up): a late measurement whose lateness exceeds what is left is
  refused (``reapply_budget``), so a stream of late data cannot take more than that share of the work.
"""
from __future__ import annotations

import copy
from functools import lru_cache
from typing import Callable

import numpy as np
from scipy.stats import chi2

from gpf_nav.estimator.engine_config import NS, EngineConfig
from gpf_nav.estimator.history import Entry, History, configuration
from gpf_nav.estimator.input_checks import ReapplyBudget
from gpf_nav.filters.interface import Filter
from gpf_nav.sensors import Sensor, innovation_distance

Step = Callable[[int, np.ndarray, str, Sensor | None, bool], str]
"""The engine's step of one input: ``(stamp_ns, y, stream, sensor, feed_monitors) -> reason`` (predict to
the stamp, update; ``""`` when updated)."""

RESCAN_EVERY = 32
"""Snapshots between two searches of the filter for the models and sensors its snapshots share (a search
costs about a snapshot)."""


@lru_cache(maxsize=64)
def _chi2_threshold(probability: float, dof: int) -> float:
    return float(chi2.ppf(probability, dof))


class InnovationGate:
    """The innovation gates of the streams that have one (``gates``).

    Attributes:
        streaks: stream -> its measurements refused in a row (each input of the history keeps a copy, which
            re-applying it restores).
    """

    def __init__(self, config: EngineConfig):
        self.config = config
        self.streaks: dict[str, int] = {}

    def refuses(self, flt: Filter, stream: str, sensor: Sensor | None, y: np.ndarray) -> bool:
        """Whether the gate of ``stream`` (a sensor object's streams only) refuses ``y`` ``(m,)`` on every
        predicted estimate of ``flt``. Counts the refusals in a row; after ``gate_limit`` the next one
        passes."""
        probability = self.config.gates.get(stream, 0.0)
        if sensor is None or probability <= 0.0:
            return False
        for lifted, mean, cov in flt.predicted_estimates(sensor):  # with the sensor's estimated bias, if any
            d2, k = innovation_distance(lifted, y, mean, cov, flt.time)
            if k == 0 or d2 <= _chi2_threshold(probability, k):
                self.streaks[stream] = 0
                return False
        streak = self.streaks.get(stream, 0)
        if streak >= self.config.gate_limit:
            self.streaks[stream] = 0
            return False
        self.streaks[stream] = streak + 1
        return True


class LateFusion:
    """The inputs the filter took (:class:`History`) and their re-application for a late input.

    Args:
        config: the engine's settings (``history_length``, ``reapply_budget``).
        step: the engine's step of one input, which re-application repeats.
        restore: puts back the filter an input of the history was applied to (its snapshot, at its
            ``before_ns``, with the gate streaks then).

    Attributes:
        history: the inputs of the last ``history_length`` s.
        start_ns: the stamp of the filter's (re-)initialisation: stamps before it are ``stale_stamp``.
        late_count: late measurements fused at their stamp.
        replayed_count: inputs re-applied after late measurements and late IMU samples.
        snapshot_failures: filter copies that failed (each emptied the history).
    """

    def __init__(self, config: EngineConfig, step: Step, restore: Callable[[Entry], None]):
        self.config = config
        self._step = step
        self._restore = restore
        self.start_ns = 0
        self._configuration: tuple[object, dict[int, object]] | None = None
        self._snapshots = 0
        self.reset()

    def reset(self) -> None:
        """Back to the engine's start-up state: nothing kept, nothing counted."""
        self.history = History(int(round(self.config.history_length * NS)))
        self._budget = ReapplyBudget(self.config.reapply_budget, self.config.history_length, 0)
        self.late_count = 0
        self.replayed_count = 0
        self.snapshot_failures = 0

    def restart(self, t_ns: int) -> None:
        """The filter starts again at ``t_ns``: the inputs before are dropped, the budget is full."""
        self.start_ns = int(t_ns)
        self.history.clear()
        self._budget = ReapplyBudget(self.config.reapply_budget, self.config.history_length, t_ns)

    def refusal(self, t_ns: int, stamp_ns: int) -> str:
        """Why a measurement stamped at ``stamp_ns``, before the filter's time ``t_ns``, cannot be fused at
        its stamp (``""``: it can)."""
        if self.config.history_length <= 0.0:
            return "stale_stamp"
        if (t_ns - stamp_ns) * 1e-9 > self.config.history_length:
            return "older_than_history"
        if stamp_ns < self.start_ns:
            return "stale_stamp"
        if self.history.split(stamp_ns) is None:
            return "older_than_history"
        return ""

    def afford(self, t_ns: int, stamp_ns: int) -> bool:
        """Take the lateness of a measurement at ``stamp_ns`` (filter at ``t_ns``) from the budget; False
        (nothing taken) when less is left."""
        return self._budget.spend(t_ns, (t_ns - stamp_ns) * 1e-9)

    def entry(self, flt: Filter, t_ns: int, stamp_ns: int, stream: str, y: np.ndarray, sensor: Sensor | None,
              streaks: dict[str, int], extra_due: bool) -> Entry | None:
        """The history's entry of input ``y`` ``(m,)`` about to be applied to ``flt`` (at ``t_ns``), with a
        copy of ``flt`` every ``SNAPSHOT_EVERY`` inputs or, ``extra_due``, while IMU samples come late
        (:meth:`gpf_nav.estimator.imu_hold.ImuHold.extra_snapshot_due`); None when the history keeps nothing."""
        keep = self.history.length_ns > 0
        periodic = self.history.wants_snapshot()
        extra = not periodic and extra_due  # the newest input's snapshot
        before = self.snapshot(flt) if keep and (periodic or extra) else None
        if not keep or (before is None and len(self.history) == 0):  # (a failed copy emptied the history)
            return None
        return Entry(stamp_ns, stream, y, sensor, before, t_ns, dict(streaks), extra=extra and before is not None)

    def keep(self, entry: Entry | None) -> None:
        """Add the entry of an input that was applied (None: not kept)."""
        if entry is not None:
            self.history.append(entry)

    def fuse(self, stamp_ns: int, y: np.ndarray, stream: str, sensor: Sensor | None) -> str:
        """Fuse ``y`` ``(m,)`` stamped before the filter's time at its stamp (:meth:`refusal` says it can):
        restore the last snapshot before it, re-apply the inputs between, then the late one, then the
        inputs stamped after it (their counters are not counted again; the monitors are not fed again).
        Returns the late input's step's reason."""
        i, j = self.history.split(stamp_ns)
        redo = self._rewind(j)
        self._reapply(redo[:i - j])
        reason = self._step(stamp_ns, y, stream, sensor, True)
        self._reapply(redo[i - j:])
        self.late_count += 1
        self.replayed_count += len(redo)
        return reason

    def reapply_from(self, stamp_ns: int) -> None:
        """Re-apply the history from the first input stamped after ``stamp_ns`` (a late IMU sample's), if it
        still holds it."""
        split = self.history.split(stamp_ns)
        if split is None:
            return
        redo = self._rewind(split[1])
        self._reapply(redo)
        self.replayed_count += len(redo)

    def _rewind(self, j: int) -> list[Entry]:
        """Take the history's inputs from index ``j`` on and restore the filter they were applied to (the
        snapshot kept with input ``j``); returns them, to be re-applied."""
        redo = self.history.take(j)
        self._restore(redo[0])
        return redo

    def _reapply(self, entries: list[Entry]) -> None:
        for entry in entries:
            self._step(entry.t_ns, entry.y, entry.stream, entry.sensor, False)

    def snapshot(self, flt: Filter) -> Filter | None:
        """A deep copy of ``flt`` for the history, sharing its models and sensors
        (:func:`~gpf_nav.estimator.history.configuration`, found again for a new filter model and every
        :data:`RESCAN_EVERY` snapshots, so that sensors first used later are shared too; one not yet
        found is copied). A filter that cannot be copied empties the history (None): late
        stamps before this input are then ``older_than_history``."""
        try:
            model = flt.model
            self._snapshots += 1
            if (self._configuration is None or self._configuration[0] is not model
                    or self._snapshots % RESCAN_EVERY == 0):
                self._configuration = (model, configuration(flt))
            return copy.deepcopy(flt, dict(self._configuration[1]))
        except Exception:  # noqa: BLE001 - e.g. a user's filter wrapper: go on without late fusion
            self.history.clear()
            self.snapshot_failures += 1
            return None
