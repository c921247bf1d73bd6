"""Resampling schemes: normalised weights ``(N,)`` in, ancestor indices ``(N,)`` out.

All four schemes share one signature ``scheme(weights, rng) -> ancestors`` and are O(N) or
O(N log N): systematic resampling is a compiled kernel (:mod:`gpf_nav.kernels.systematic`), the others
vectorised numpy. Cumulative weights have their last entry forced to exactly 1 so
round-off can never produce an out-of-range ancestor.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from gpf_nav.kernels.systematic import systematic_ancestors

Resampler = Callable[[np.ndarray, np.random.Generator], np.ndarray]


def _cumulative(weights: np.ndarray) -> np.ndarray:
    cdf = np.cumsum(weights)
    cdf /= cdf[-1]
    cdf[-1] = 1.0
    return cdf


def _from_counts(counts: np.ndarray) -> np.ndarray:
    return np.repeat(np.arange(counts.size), counts)


def systematic(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: one uniform ``U``, points ``(U + j) / N``; offspring counted in O(N)."""
    return systematic_ancestors(np.ascontiguousarray(weights, dtype=float), rng.random())


def stratified(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Stratified resampling: one uniform per stratum ``[j/N, (j+1)/N)``."""
    n = weights.size
    points = (np.arange(n) + rng.random(n)) / n
    return np.searchsorted(_cumulative(weights), points, side="right")


def multinomial(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Multinomial resampling: offspring counts drawn from ``Multinomial(N, weights)``."""
    return _from_counts(rng.multinomial(weights.size, weights / weights.sum()))


def residual(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Residual resampling: ``floor(N w)`` copies each, the remainder drawn multinomially."""
    n = weights.size
    scaled = n * weights / weights.sum()
    # the tolerance keeps N * (1/N) == 0.999... from losing its deterministic copy to round-off
    counts = np.floor(scaled + 1e-9).astype(np.intp)
    if counts.sum() > n:
        counts = np.floor(scaled).astype(np.intp)
    remaining = n - int(counts.sum())
    if remaining > 0:
        rest = np.clip(scaled - counts, 0.0, None)
        counts += rng.multinomial(remaining, rest / rest.sum())
    return _from_counts(counts)


SCHEMES: dict[str, Resampler] = {
    "systematic": systematic,
    "stratified": stratified,
    "multinomial": multinomial,
    "residual": residual,
}


def get(name: str) -> Resampler:
    """The resampling scheme called ``name`` (one of :data:`SCHEMES`)."""
    try:
        return SCHEMES[name]
    except KeyError:
        raise ValueError(f"unknown resampling scheme {name!r}; choose from {sorted(SCHEMES)}") from None


def effective_sample_size(weights: np.ndarray) -> float:
    """ESS ``1 / sum(w^2)`` of normalised weights ``(N,)``."""
    return float(1.0 / np.einsum("i,i->", weights, weights))  # not a BLAS dot: see gpf_nav.blas
