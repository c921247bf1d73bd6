"""Consistency monitor: is the filter's covariance as large as the errors the measurements show?

A consistent filter's innovations ``r = y - h(m^-)`` have the covariance it predicts,
``S = H P^- H^T + R`` (``P^-`` the predicted covariance, ``H`` the measurement Jacobian at the predicted
mean ``m^-``), and are white: the normalised innovation squared ``e = r^T S^-1 r`` of an update with ``k``
measured components is ``chi^2(k)``, and the sum over the latest ``window`` updates is ``chi^2`` with the
sum of their ``k`` as degrees of freedom. :class:`ConsistencyMonitor` tests that sum at every update:

* ``level = "FAULT"`` when ``P(chi^2_dof > sum) < false_alarm_rate`` (the covariance is too small for the
  errors: an overconfident filter), ``"WARN"`` below ``warn_false_alarm_rate``, else ``"OK"``;
* under a consistent filter the probability that a given update is ``FAULT`` is ``false_alarm_rate``
  (consecutive windows share data, so alarms come in runs).

It is filter-agnostic (it needs the predicted mean and covariance, which every filter has) and it sees
only what the measurements see: an error along a direction no measurement depends on (an undetermined
direction, :mod:`gpf_nav.integrity.observability`) never shows in an innovation, so no innovation test can
flag it; that is the observability report's job. The co-state monitor (:mod:`gpf_nav.integrity.costate`)
tests a different hypothesis, a bias of the co-state's mean, without the filter's covariance.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy import special

from gpf_nav.integrity.costate import LEVELS

FALSE_ALARM_RATE = 1e-3
"""Default probability that a given update of a consistent filter is ``FAULT``."""
WARN_FALSE_ALARM_RATE = 1e-2
"""Default probability that a given update of a consistent filter is at least ``WARN``."""
WINDOW = 10
"""Default number of updates whose normalised innovations are summed."""


@dataclass(frozen=True)
class ConsistencyStatus:
    """Result of one :meth:`ConsistencyMonitor.update`.

    Attributes:
        level: ``"OK"``, ``"WARN"`` or ``"FAULT"``.
        nis: normalised innovation squared of this update (NaN when it could not be formed).
        statistic: the window's sum of normalised innovations squared.
        dof: its degrees of freedom (measured components in the window).
        p_value: ``P(chi^2_dof >= statistic)``.
    """

    level: str
    nis: float
    statistic: float
    dof: int
    p_value: float


class ConsistencyMonitor:
    """Windowed ``chi^2`` test of the normalised innovations (module docstring).

    Args:
        false_alarm_rate: probability that a given update of a consistent filter is ``FAULT``.
        warn_false_alarm_rate: the same for ``WARN`` or worse (at least ``false_alarm_rate``).
        window: updates summed (>= 1).

    Attributes:
        updates: updates tested.
        faults: updates whose level was ``FAULT``.
        rejected: updates that could not be tested (a non-finite innovation or a singular ``S``).
    """

    def __init__(self, false_alarm_rate: float = FALSE_ALARM_RATE,
                 warn_false_alarm_rate: float = WARN_FALSE_ALARM_RATE, window: int = WINDOW):
        if not 0.0 < false_alarm_rate <= warn_false_alarm_rate < 1.0:
            raise ValueError("need 0 < false_alarm_rate <= warn_false_alarm_rate < 1, got "
                             f"{false_alarm_rate}, {warn_false_alarm_rate}")
        if int(window) < 1:
            raise ValueError(f"window must be at least 1, got {window}")
        self.false_alarm_rate = float(false_alarm_rate)
        self.warn_false_alarm_rate = float(warn_false_alarm_rate)
        self.window = int(window)
        self._samples: deque[tuple[float, int]] = deque(maxlen=self.window)
        self.updates = self.faults = self.rejected = 0
        self.status = ConsistencyStatus("OK", float("nan"), 0.0, 0, 1.0)

    def reset(self) -> None:
        """Forget the window (after a re-initialisation of the filter)."""
        self._samples.clear()

    def update(self, innovation: np.ndarray, covariance: np.ndarray) -> ConsistencyStatus:
        """Test the update whose measured innovation is ``innovation`` ``(k,)`` (angles wrapped) with the
        predicted innovation covariance ``covariance`` ``(k, k)``."""
        r = np.asarray(innovation, dtype=float).reshape(-1)
        S = np.asarray(covariance, dtype=float)
        if not r.size:
            return self.status
        try:
            nis = float(r @ np.linalg.solve(S, r))
        except np.linalg.LinAlgError:
            nis = float("nan")
        if not (np.isfinite(nis) and nis >= 0.0):
            self.rejected += 1
            return self.status
        self._samples.append((nis, r.size))
        statistic = sum(s for s, _ in self._samples)
        dof = sum(k for _, k in self._samples)
        p = float(special.chdtrc(dof, statistic))  # P(chi^2_dof >= statistic), without stats' overhead
        level = LEVELS[2] if p < self.false_alarm_rate else LEVELS[1] if p < self.warn_false_alarm_rate \
            else LEVELS[0]
        self.updates += 1
        self.faults += level == LEVELS[2]
        self.status = ConsistencyStatus(level, nis, statistic, dof, p)
        return self.status


def innovation_moments(sensor, y: np.ndarray, mean: np.ndarray, cov: np.ndarray, t: float = 0.0
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The measured components' innovation ``y - h(mean)`` ``(k,)`` (angles wrapped) and its predicted
    covariance ``H cov H^T + R`` ``(k, k)``, linearised at ``mean`` ``(n,)``, for ``sensor``'s
    measurement ``y`` ``(m,)`` (NaN: not measured)."""
    y = np.asarray(y, dtype=float)
    rows = np.isfinite(y)
    h, H = sensor.measure_and_jacobian(np.asarray(mean, dtype=float)[None], t)
    r = sensor.residual(y, h[0])[rows]
    H = H[0][rows]
    return r, H @ cov @ H.T + sensor.noise(t)[np.ix_(rows, rows)]


__all__ = ["ConsistencyMonitor", "ConsistencyStatus", "innovation_moments", "FALSE_ALARM_RATE", "WINDOW"]
