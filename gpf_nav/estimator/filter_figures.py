"""Filter figures: what the diagnostics report of the core filter itself, read from the optional
capabilities it declares (:data:`gpf_nav.filters.interface.CAPABILITIES`): particle ESS and resampling,
co-state norms, gate and tempering counts, the compensated model's probability and unmodelled acceleration,
and the observability report."""
from __future__ import annotations

import numpy as np

from gpf_nav.filters.interface import (COMPENSATION, COSTATE, GATE, MODEL_PROBABILITIES, RESAMPLING, TEMPERING,
                                      Filter)
from gpf_nav.integrity import ObservabilityReport


def filter_stats(flt: Filter) -> dict:
    """ESS/N and co-state figures of a particle filter, and the estimated unmodelled acceleration ``(p,)``
    with its standard deviations ``(p,)`` of a compensated filter (keys absent otherwise) of the initialised
    filter ``flt``."""
    out = {}
    if RESAMPLING in flt.capabilities:
        out["ess"] = float(flt.ess)
        out["resample_count"] = int(flt.resample_count)
    if COSTATE in flt.capabilities:
        out["costate_norm_mean"] = float(flt.costate_norm_mean)
        out["costate_norm_max"] = float(flt.costate_norm_max)
    if GATE in flt.capabilities:
        out["gated"] = int(flt.gated)
    if TEMPERING in flt.capabilities:
        out["tempered_updates"] = int(flt.tempered_updates)
    if MODEL_PROBABILITIES in flt.capabilities:
        out["compensated_model_probability"] = float(1.0 - flt.model_probabilities[0])
    if COMPENSATION in flt.capabilities:
        acceleration = np.asarray(flt.unmodelled_acceleration, dtype=float)
        sigma = np.sqrt(np.clip(np.diag(flt.unmodelled_acceleration_covariance), 0.0, None))
        if np.all(np.isfinite(acceleration)) and np.all(np.isfinite(sigma)):
            out["unmodelled_acceleration"] = acceleration
            out["unmodelled_acceleration_std"] = sigma
    return out


def observability(flt: Filter) -> ObservabilityReport | None:
    """The initialised filter's :class:`~gpf_nav.integrity.ObservabilityReport` (None if it has none)."""
    try:
        return flt.observability
    except Exception:  # noqa: BLE001 - a broken report must not take the diagnostics down
        return None
