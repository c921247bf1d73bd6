"""One Monte Carlo run: one scenario realisation, every filter on it, per-filter summaries.

A :class:`RunTask` is self-contained (seed, run index, scenario config, filter names), so the result does
not depend on which process or machine executes it: the scenario seed and the filters' seed are derived
from ``(seed, run)`` alone by :func:`run_seeds`, and nothing uses a global random state.

The paper's fairness rule holds inside a run: every filter sees the same truth (hence the same process
noise), the same measurements and the same prior ``N(prior_mean, prior_cov)``. All filters of a run also
get the same seed for their own random stream (common random numbers), so e.g. the particle filters
start from the same initial cloud. The truth and prior of run ``r`` do not depend on the case, the
mismatch ``epsilon`` or the noise scale beyond what those parameters change physically (see
docs/scenario.md, "Seeds and streams"), which pairs the runs of Case 1 and Case 2 and of a sweep.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from gpf_nav import registry
from gpf_nav.experiments import metrics
from gpf_nav.filters.interface import N_PARTICLES, RESAMPLING
from gpf_nav.integrity import ConsistencyMonitor, innovation_moments
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate, undetermined_subspace
from gpf_nav.sim.surface_stations import scenario_stations
from gpf_nav.sensors.model import ModelSensor
from gpf_nav.sensors.sensor import Sensor

DEFAULT_DIVERGENCE_BOUND = 1.0e6  # m: a run whose position error ever exceeds 1000 km has diverged
NEES_BOUND = 22.458
"""chi-square 99.9 % bound of 6 degrees of freedom: a step whose NEES is above it is overconfident."""
REPORT_AFTER = 100.0
"""Observability verdicts are counted from this many seconds into a run (the data need time to determine
what they can)."""
NAMED_COSINE = 0.95
"""An undetermined subspace is *named* when its dimension is right and every principal angle to the
scenario's known one is below arccos of this (18 degrees), in the no-data standard deviations."""

ORACLE_GRID = tuple(10.0 ** k for k in range(8))
"""Process-noise variance multipliers searched by the oracle-tuned rows (x1 ... x1e7)."""
ORACLE_FAMILIES = {e.label: registry.label(e.tunes) for e in registry.ENTRIES.values() if e.tunes}
"""Oracle-tuned rows (label) and the label of the filter they tune: per case and swept value, the grid
member with the lowest mean position RMSE over the runs (it has seen the truth: not a filter a user could
run)."""


def grid_name(family: str, multiplier: float) -> str:
    """Name of the member of an oracle family run with ``Q`` times ``multiplier``."""
    return f"{ORACLE_FAMILIES[family]}, Q x{multiplier:g}"


def expand_filters(filters: tuple[str, ...]) -> tuple[str, ...]:
    """The filters to run: oracle families replaced by their grid members."""
    out = []
    for name in filters:
        out.extend(grid_name(name, m) for m in ORACLE_GRID) if name in ORACLE_FAMILIES else out.append(name)
    return tuple(dict.fromkeys(out))


def select_oracle(results: list[dict], filters: tuple[str, ...]) -> dict:
    """Add each oracle family of ``filters`` to ``results`` (in place) as a copy of its best grid
    member (lowest mean position RMSE over these runs); returns ``{family: chosen multiplier}``."""
    chosen = {}
    for family in (f for f in filters if f in ORACLE_FAMILIES):
        def score(m):
            values = [r["filters"][grid_name(family, m)]["position_rmse"] for r in results]
            values = [v for v in values if np.isfinite(v)]
            return np.mean(values) if len(values) == len(results) else np.inf
        best = min(ORACLE_GRID, key=score)
        chosen[family] = best
        for r in results:
            r["filters"][family] = r["filters"][grid_name(family, best)]
    return chosen


def make_filter(name: str, model, n_particles: int, seed):
    """Construct the filter ``name`` (a :mod:`gpf_nav.registry` name or label, or an oracle grid member
    ``"<label>, Q x<m>"``, built as the filter it tunes), with the diagnostic co-state where the filter
    offers it."""
    if ", Q x" in name:
        name = name.split(", Q x")[0]
    return registry.make(name, model, n_particles, seed, compute_costate=True)


def filter_model_of(name: str, config: ScenarioConfig):
    """The model filter ``name`` runs on: the scenario's filter model, with the process-noise density
    scaled for an oracle grid member (``Q x m``: density times ``sqrt(m)``)."""
    if ", Q x" in name:
        multiplier = float(name.rsplit("x", 1)[1])
        config = dataclasses.replace(config, filter_accel_noise_density=config.filter_accel_noise_density
                                     * math.sqrt(multiplier))
    return filter_model(config)


FILTERS = registry.labels("navigation", "paper")
"""The rows of the Monte Carlo table and the sweeps: the navigation-grade GPF, its fair baselines
(the same compensation; oracle-tuned process noise), then the paper's rows (all with N = 500 particles /
members)."""


def run_seeds(seed: int, run: int) -> tuple[int, int]:
    """``(scenario seed, filter seed)`` of Monte Carlo run ``run`` of a campaign seeded ``seed``."""
    words = np.random.SeedSequence([int(seed), int(run)]).generate_state(2, np.uint64)
    return int(words[0]), int(words[1])


@dataclass(frozen=True)
class RunTask:
    """Everything one run needs.

    Attributes:
        index: position of the result in the campaign's output (results are ordered by it).
        run: Monte Carlo run number (with ``seed``, it fixes the random numbers).
        seed: campaign seed.
        config: scenario configuration (case, epsilon, noise scale, duration, ...).
        filters: names of the filters to run, in order.
        n_particles: particles (and EnKF members).
        series: also return per-step time series (for the figures).
        divergence_bound: position error (m) beyond which a run counts as diverged.
        tag: free label carried to the result (e.g. the sweep value).
    """

    index: int
    run: int
    seed: int
    config: ScenarioConfig
    filters: tuple[str, ...] = FILTERS
    n_particles: int = N_PARTICLES
    series: bool = False
    divergence_bound: float = DEFAULT_DIVERGENCE_BOUND
    tag: dict = field(default_factory=dict, compare=False, hash=False)


def run_filter(flt, scenario, divergence_bound: float = DEFAULT_DIVERGENCE_BOUND,
               stations: list[tuple[Sensor, np.ndarray]] | None = None) -> dict:
    """Run one initialised-from-prior filter over a scenario and summarise it.

    The filter fuses the scenario's own measurements, or, when ``stations`` is given, each of its
    ``(sensor, measurements (K, m))`` in turn at every step instead (the surface stations of
    :func:`gpf_nav.sim.surface_stations.scenario_stations`).

    Returns a dict with per-run scalars (``position_rmse`` m, ``velocity_rmse`` m/s, ``ess`` time average
    of ESS/N, ``costate_norm`` time average, ``nees`` time average over the steps with a positive
    definite covariance, ``nees_defined`` fraction of such steps, ``resample_rate``, ``max_position_error``
    and ``final_position_error`` m, ``first_ess`` ESS/N after the first update, ``covariance_failures``
    the number of steps whose published covariance was singular or indefinite
    (:func:`~gpf_nav.experiments.metrics.not_positive_definite`), ``diverged``, ``nonfinite``, ``error``
    message or None, ``seconds``) and the per-step ``series``
    (``position_error`` m, ``velocity_error`` m/s, ``nees``, ``ess``, ``costate_norm``), NaN past a stop.
    A filter that raises or produces a non-finite estimate is stopped there and flagged ``nonfinite``.
    """
    steps = scenario.times.shape[0]
    dt = scenario.config.dt
    pos_err = np.full(steps, np.nan)
    vel_err = np.full(steps, np.nan)
    n = scenario.truth.shape[1]
    state_errors = np.full((steps, n), np.nan)
    covariances = np.full((steps, n, n), np.nan)
    ess = np.full(steps, np.nan)
    costate = np.full(steps, np.nan)
    resampled = np.zeros(steps, dtype=bool)
    undetermined = np.full(steps, np.nan)
    named = np.full(steps, np.nan)
    fault = np.zeros(steps, dtype=bool)
    monitor = ConsistencyMonitor()
    late = scenario.times - scenario.start_time >= REPORT_AFTER  # (the steps the verdicts count)
    expected = undetermined_subspace(scenario.config, scenario.truth[1:])  # (K, 6, d) or None
    # (the sensor the monitor predicts with, the one the filter is given: None for its model's own, data)
    own = ModelSensor(filter_model(scenario.config))
    streams = [(own, None, scenario.measurements)] if stations is None else [(s, s, y) for s, y in stations]
    is_particle = RESAMPLING in flt.capabilities
    error = None
    start = time.perf_counter()
    try:
        flt.initialize(scenario.prior_mean, scenario.prior_cov)
        for k in range(steps):
            flt.predict(dt, scenario.specific_force[k])
            for monitored, sensor, y in streams:
                if np.isfinite(y[k]).any():
                    r, S = innovation_moments(monitored, y[k], flt.mean, flt.covariance, flt.time)
                    fault[k] |= monitor.update(r, S).level == "FAULT"
                flt.update(y[k], sensor)
            report = flt.observability
            if report is not None:
                undetermined[k] = report.undetermined
                if late[k]:
                    named[k] = _named(report, None if expected is None else expected[k])
            mean = flt.mean
            if not np.all(np.isfinite(mean)):
                error = f"non-finite estimate at step {k}"
                break
            e = mean - scenario.truth[k + 1]
            pos_err[k] = math.sqrt(float(e[:3] @ e[:3]))
            vel_err[k] = math.sqrt(float(e[3:] @ e[3:]))
            state_errors[k] = e
            covariances[k] = flt.covariance
            if is_particle:
                ess[k] = flt.ess
                costate[k] = flt.costate_norm_mean
                resampled[k] = flt.resampled
    except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        error = f"{type(exc).__name__}: {exc}"
    seconds = time.perf_counter() - start
    nees = metrics.nees(state_errors, covariances)
    nonfinite = error is not None
    finished = bool(np.all(np.isfinite(pos_err)))
    summary = {
        "position_rmse": metrics.rmse(pos_err) if finished else math.nan,
        "velocity_rmse": metrics.rmse(vel_err) if finished else math.nan,
        "ess": metrics.time_average(ess) if is_particle and finished else math.nan,
        "costate_norm": metrics.time_average(costate) if is_particle and finished else math.nan,
        "nees": metrics.time_average(nees) if finished else math.nan,
        "nees_defined": float(np.mean(np.isfinite(nees))) if finished else math.nan,
        "resample_rate": float(resampled.mean()) if is_particle and finished else math.nan,
        "max_position_error": float(np.nanmax(pos_err)) if np.any(np.isfinite(pos_err)) else math.nan,
        "final_position_error": float(pos_err[-1]),
        "first_ess": float(ess[0]),
        "covariance_failures": int(metrics.not_positive_definite(covariances[np.isfinite(pos_err)]).sum()),
        "above_bound": float(np.mean(nees[np.isfinite(nees)] > NEES_BOUND)) if finished else math.nan,
        "undetermined_share": _share(undetermined[late] > 0, undetermined[late]),
        "named_share": _share(named[late] > 0, named[late]),
        "consistency_faults": float(fault.mean()),
        "first_fault": float(scenario.times[np.argmax(fault)] - scenario.start_time) if fault.any() else math.nan,
        "nonfinite": nonfinite,
        "error": error,
        "seconds": seconds,
    }
    summary["diverged"] = bool(not nonfinite and summary["max_position_error"] > divergence_bound)
    summary["series"] = {"position_error": pos_err, "velocity_error": vel_err, "nees": nees,
                         "ess": ess, "costate_norm": costate, "undetermined": undetermined,
                         "consistency_fault": fault}
    return summary


def _share(hits: np.ndarray, values: np.ndarray) -> float:
    """Share of the steps with a defined ``values`` (not NaN) where ``hits``; NaN when none is defined."""
    defined = np.isfinite(values)
    return float(hits[defined].mean()) if defined.any() else math.nan


def _named(report, expected: np.ndarray | None) -> float:
    """1.0 when the report's undetermined subspace is ``expected`` ``(6, d)`` (same dimension, principal
    angles within :data:`NAMED_COSINE`, the user's state of the report), 0.0 when not, NaN when the
    scenario knows no such subspace."""
    if expected is None:
        return math.nan
    directions = report.directions[:, :expected.shape[0]]
    if directions.shape[0] != expected.shape[1]:
        return 0.0
    if not expected.shape[1]:
        return 1.0
    scale = report.scale[:expected.shape[0]]
    a = np.linalg.qr(expected / scale[:, None])[0]
    b = np.linalg.qr(directions.T / scale[:, None])[0]
    return float(np.linalg.svd(a.T @ b, compute_uv=False).min() >= NAMED_COSINE)


def run_task(task: RunTask) -> dict:
    """Generate the scenario of ``task`` and run every filter on it.

    Returns ``{"index", "run", "case", "tag", "filters": {name: summary}}``; each summary as
    :func:`run_filter`, without ``series`` unless ``task.series``. Also ``"times"`` (s) when series are kept.
    """
    scenario_seed, filter_seed = run_seeds(task.seed, task.run)
    scenario = generate(task.config, scenario_seed)
    stations = scenario_stations(scenario, scenario_seed) if task.config.surface_stations else None
    out = {"index": task.index, "run": task.run, "case": task.config.case, "tag": dict(task.tag),
           "filters": {}}
    for name in expand_filters(task.filters):
        flt = make_filter(name, filter_model_of(name, task.config), task.n_particles, filter_seed)
        summary = run_filter(flt, scenario, task.divergence_bound, stations)
        if not task.series:
            del summary["series"]
        out["filters"][name] = summary
    if task.series:
        out["times"] = scenario.times.copy()
    return out
