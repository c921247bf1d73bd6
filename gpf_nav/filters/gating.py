"""The innovation gate every filter that refuses outliers shares (the GPF's cloud metric, the gated EKF).

A measured component whose innovation is beyond ``outlier_gate`` standard deviations of the innovation
covariance is not used, unless it has been refused ``outlier_gate_limit`` times in a row: then the
filter, not the sensor, is taken to be off, and the component is used until one passes the gate again.
``outlier_gate = 0`` disables the gate.

A refused component was not weighed, so the update's evidence leaves it out. What it would have added is
at most its Gaussian log-density at the gate's edge, ``-(g^2 + log(2 pi s)) / 2`` for a gate of ``g``
standard deviations and an innovation variance ``s`` in the measurement's units: the gate keeps the sum
over the refused components as :attr:`~InnovationGated.refused_log_likelihood`, a bound a filter comparing
members' evidence can charge a refusing member with (:mod:`gpf_nav.filters.multiple_model`, step 3).
"""
from __future__ import annotations

import math

import numpy as np

from gpf_nav.filters.interface import GATE

OUTLIER_GATE = 6.0
"""Default innovation gate of the navigation-grade filters, standard deviations."""
OUTLIER_GATE_LIMIT = 5
"""Default number of consecutive refusals of a component after which it is used anyway."""


class InnovationGated:
    """Mixin of a filter with an innovation gate: call :meth:`_init_gate` in ``__init__`` and
    :meth:`_gate` in the update.

    Attributes:
        outlier_gate: the gate, standard deviations of the innovation (0: no gate).
        outlier_gate_limit: consecutive refusals of a component after which it is used anyway.
        gated: components refused so far.
        refused_log_likelihood: the bound of the module docstring for the components the last refusing
            call of :meth:`_gate` left out (0 before any).
    """

    outlier_gate: float
    outlier_gate_limit: int
    gated: int
    refused_log_likelihood: float

    @property
    def capabilities(self) -> frozenset[str]:
        """The filter's, and :data:`~gpf_nav.filters.interface.GATE`."""
        return super().capabilities | {GATE}

    def _init_gate(self, outlier_gate: float, outlier_gate_limit: int) -> None:
        """Set the gate; ValueError when either option is negative."""
        if not (outlier_gate >= 0.0 and int(outlier_gate_limit) >= 0):
            raise ValueError(f"outlier_gate and outlier_gate_limit must be >= 0, got {outlier_gate}, "
                             f"{outlier_gate_limit}")
        self.outlier_gate = float(outlier_gate)
        self.outlier_gate_limit = int(outlier_gate_limit)
        self.gated = 0
        self.refused_log_likelihood = 0.0
        self._gate_streaks: dict[str, np.ndarray] = {}

    def _gate(self, innovation: np.ndarray, S: np.ndarray, rows: np.ndarray, sensor: str,
              whitener: np.ndarray | None = None) -> np.ndarray:
        """The measured ``rows`` ``(m,)`` bool less the outliers: a component whose innovation
        (``(k,)``, one per measured row, in any units that ``S`` shares) is beyond ``outlier_gate``
        standard deviations of the innovation covariance ``S`` ``(k, k)`` is left out, unless it has
        been left out ``outlier_gate_limit`` times in a row (consecutive refusals are counted per
        ``sensor`` name). ``whitener``: ``W`` ``(k, k)`` or its diagonal ``(k,)`` when ``S`` is that of
        the whitened innovation ``W r`` (None: ``S`` is in the measurement's units), for
        :attr:`refused_log_likelihood`. Returns ``rows`` itself when no component is left out (and
        always when the gate is off)."""
        if not self.outlier_gate:
            return rows
        # a few components: Python floats cost less than numpy calls on arrays of three
        limits = [self.outlier_gate * math.sqrt(s) for s in S.diagonal().tolist()]
        outlier = [abs(v) > limit for v, limit in zip(innovation.tolist(), limits)]
        streak = self._gate_streaks.setdefault(sensor, np.zeros(rows.size, dtype=int))
        if not any(outlier):
            streak[rows] = 0
            return rows
        refused, positions = [], []  # (measurement rows; their positions among the measured ones)
        for j, (i, is_outlier) in enumerate(zip(np.flatnonzero(rows).tolist(), outlier)):  # a few components
            streak[i] = streak[i] + 1 if is_outlier else 0
            if is_outlier and streak[i] <= self.outlier_gate_limit:
                refused.append(i)
                positions.append(j)
        if not refused:
            return rows
        self.gated += len(refused)
        self.refused_log_likelihood = _edge_log_density(self.outlier_gate, S, whitener, positions)
        used = rows.copy()
        used[refused] = False
        return used


def _edge_log_density(gate: float, S: np.ndarray, whitener: np.ndarray | None, components: list[int]) -> float:
    """Sum over ``components`` (positions in ``S`` ``(k, k)``) of the Gaussian log-density at ``gate``
    standard deviations, in the measurement's units (module docstring): the innovation variances are
    ``S``'s diagonal, or ``W^-1 S W^-T``'s for the ``whitener`` ``W``."""
    if whitener is None:
        variances = S.diagonal()
    elif whitener.ndim == 1:
        variances = S.diagonal() / whitener ** 2
    else:
        unwhitened = np.linalg.solve(whitener, np.linalg.solve(whitener, S).T)
        variances = unwhitened.diagonal()
    picked = variances[components]
    return float(-0.5 * (len(components) * gate ** 2 + np.log(2.0 * np.pi * picked).sum()))
