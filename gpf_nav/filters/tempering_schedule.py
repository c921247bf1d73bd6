"""Likelihood tempering (progressive correction): the stages of one particle-filter update.

A draw weighted by ``p(y | x)^f`` whose ESS/N would fall below ``tempering_ess`` is refused and drawn
again with ``f / TEMPERING_FACTOR``; an accepted stage is weighted (and resampled below ``tau N``), and the
next, drawn from the new cloud with no process noise, takes up to ``TEMPERING_FACTOR`` times more, until
the fractions sum to 1. :class:`Tempering` keeps that schedule for
:meth:`~gpf_nav.filters.particle.ParticleFilter._assimilate`.
"""
from __future__ import annotations

import numpy as np

from gpf_nav import resampling as resamplers

TEMPERING_FACTOR = 4.0
"""A refused draw retries with this many times less of the likelihood; after an accepted stage the next
takes up to this many times more."""
TEMPERING_DRAWS = 32
"""Most draws of one update (the last is accepted whatever its ESS)."""


class Tempering:
    """The likelihood fractions of one update's draws.

    Args:
        ess_floor: ``tempering_ess``: the ESS/N below which a draw is refused; 0 never refuses (one stage).

    Attributes:
        fraction: the part ``f`` of the log-likelihood the next draw weights by.
        draws: draws so far (refused ones included).
    """

    def __init__(self, ess_floor: float):
        self.ess_floor = ess_floor
        self.fraction = 1.0
        self.remaining = 1.0
        self.draws = 0

    def refuses(self, log_weights: np.ndarray, increment: np.ndarray | float, rows: np.ndarray) -> bool:
        """Count a draw whose log-weight ``increment`` ``(N,)`` would be added to the normalised
        ``log_weights`` ``(N,)``, the measured ``rows`` ``(m,)`` bool; True (and a smaller fraction for the
        next) when it leaves too few effective particles."""
        self.draws += 1
        if (self.ess_floor and self.draws < TEMPERING_DRAWS and rows.any()
                and normalized_ess(log_weights + increment) < self.ess_floor):
            self.fraction /= TEMPERING_FACTOR
            return True
        return False

    def accepted(self, rows: np.ndarray) -> bool:
        """After an accepted stage that used ``rows``: True when the update is complete, else set the next
        stage's fraction."""
        self.remaining -= self.fraction
        if self.remaining <= 0.0 or not rows.any():
            return True
        self.fraction = min(self.remaining, TEMPERING_FACTOR * self.fraction)
        if self.remaining - self.fraction < 1e-12:  # (rounding: the last stage takes what is left)
            self.fraction = self.remaining
        return False


def normalized_ess(log_weights: np.ndarray) -> float:
    """ESS / N of unnormalised log-weights ``(N,)`` (NaN counts as zero weight; 0 when all are)."""
    log_weights = np.where(np.isnan(log_weights), -np.inf, log_weights)
    peak = log_weights.max()
    if not -np.inf < peak < np.inf:
        return 0.0
    w = np.exp(log_weights - peak)
    return resamplers.effective_sample_size(w / w.sum()) / log_weights.size
