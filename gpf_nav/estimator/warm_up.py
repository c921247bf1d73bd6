"""Warm-up: the estimator's filter run once, on a throwaway copy, before the first message.

The filters' compiled kernels (:mod:`gpf_nav.kernels`) are loaded from numba's cache on their first call in
a process, and compiled on the first start of an install (about 12 s on 2 cores). Left to the first
measurement, that wait stalls the node while its inputs pile up: on simulated time the node clock then
lags the stamps, valid IMU samples are refused as ``future_stamp`` and the filter predicts through a burn
without them. :func:`warm_up` pays the wait before the node subscribes: a throwaway engine with the same
factory, model and configuration takes a short noise-free trajectory of the model's own measurement,
with IMU samples, through its initialisation and a few updates, then rebuilds its observability trackers as
a reanchoring does minutes into a flight (a short noise-free run never reanchors). The engine the node
runs is untouched.
"""
from __future__ import annotations

import time

import numpy as np

from gpf_nav.estimator.engine import NS, EstimatorEngine

PERIOD = 2.0
"""Seconds between the warm-up's measurements (the Section 7 scenario's)."""
UPDATES = 4
"""Updates after the initialisation."""
IMU_PER_PERIOD = 4
"""IMU samples before each measurement."""
SPECIFIC_FORCE = np.array([0.0, 0.0, 0.5])
"""The warm-up's IMU specific force, m/s^2 (any finite value reaches the same kernels)."""


def warm_up(engine: EstimatorEngine, state: np.ndarray) -> tuple[float, str]:
    """Run a throwaway engine built like ``engine`` on the model's noise-free measurements of ``state``
    ``(n,)`` flowed by the model, ``init_window`` plus :data:`UPDATES` of them :data:`PERIOD` s apart, each
    after :data:`IMU_PER_PERIOD` IMU samples, with a prediction between them; then rebuild every observability
    tracker of its filter along its own reference.

    Returns the wall seconds it took and ``""``, or the error that stopped it (never raises: a failed
    warm-up only means the first message waits for the kernels instead).
    """
    start = time.perf_counter()
    steady = [0.0]  # the throwaway engine's own steady clock, so its rate limit never refuses
    try:
        rehearsal = EstimatorEngine(engine.factory, engine.model, engine.config, monotonic=lambda: steady[0])
        model, x = engine.model, np.asarray(state, dtype=float)[None]
        start_ns = max(0, int(round(engine.config.initial_stamp * NS)))  # (the prior's stamp, when one is set)
        updates = 0
        for k in range(1, engine.config.init_window + UPDATES + 1):
            for j in range(IMU_PER_PERIOD):
                rehearsal.imu(start_ns + int(((k - 1) * PERIOD + j * PERIOD / IMU_PER_PERIOD) * NS), SPECIFIC_FORCE,
                              None)
            x = model.transition(x, PERIOD, (k - 1) * PERIOD, SPECIFIC_FORCE)
            steady[0] += PERIOD
            ok, reason = rehearsal.measurement(start_ns + int(k * PERIOD * NS), model.measure(x, k * PERIOD)[0],
                                               None)
            if not ok:
                raise RuntimeError(f"measurement {k} refused: {reason}")
            updates += reason != "buffered"
            rehearsal.extrapolate(start_ns + int((k + 0.5) * PERIOD * NS))
        if updates < UPDATES or rehearsal.reinit_count or not np.isfinite(rehearsal.mean).all():
            raise RuntimeError(f"{updates} updates, {rehearsal.reinit_count} re-initialisations, mean "
                               f"{rehearsal.mean}: the throwaway filter did not run as the node's would")
        for tracker in rehearsal.filter.observability_trackers():
            if tracker.ready:
                tracker.reanchor(tracker.reference)
    except Exception as err:  # noqa: BLE001 - reported, never fatal
        return time.perf_counter() - start, f"{type(err).__name__}: {err}"
    return time.perf_counter() - start, ""

