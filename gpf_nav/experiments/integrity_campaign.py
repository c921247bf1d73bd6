"""Co-state integrity monitor on the lunar descent: false alarms, detection of mismatch and of sudden faults.

    python -m gpf_nav.experiments.integrity_campaign [--runs 24] [--particles 200] [--out results/integrity]

For each Monte Carlo run ``r`` and each filter variant (default GPF; GPF with the process-noise metric,
``eps = 1`` and corrected weights; bootstrap PF with the diagnostic co-state) the filter's weighted mean
co-state is fed, step by step, to a :class:`gpf_nav.integrity.CostateMonitor`. Scenarios:

* ``nominal``: ``epsilon = 0`` (the filter model is the truth model): the false-alarm rate;
* ``mismatch``: ``epsilon = 0.09`` from the start (the paper's case): time to the first FAULT;
* ``gravity_step``: ``epsilon = 0`` until ``--fault-time`` (1200 s), then the truth's gravity becomes
  ``mu * --gravity-scale`` (1.2): the truth is re-integrated from the fault state with
  ``LunarDescentModel(mu_scale=1.2).transition`` in 0.5 s sub-steps plus fresh process noise of the truth
  density, and the measurements re-drawn from it with the *same* noise realisations;
* ``range_bias``: from ``--fault-time`` on, every range carries ``+ --range-bias`` sigma (10 sigma = 300 m);
* ``azimuth_bias``: from ``--fault-time`` on, every azimuth carries ``+ --azimuth-bias`` sigma.

The mid-run faults branch from the nominal run of the same seed: the filter is deep-copied at the fault
time, so before the fault the three fault runs are the nominal run, step for step. The first faulty
measurement is the one at ``fault_time + dt``; a detection delay is ``t(first FAULT at or after it) -
fault_time``. The monitor is post-processing: it sees only ``(costate_mean, measured)`` of each update.

Output: a table on stdout, ``<out>/integrity.json`` and the figures ``docs/figures/integrity_*.png``.
"""
from __future__ import annotations

import copy
import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from gpf_nav import registry
from gpf_nav.arguments import CommandParser, positive_int
from gpf_nav.experiments.montecarlo import git_commit, read_json, write_json
from gpf_nav.integrity import CostateMonitor
from gpf_nav.models.state_space import wrap_angle
from gpf_nav.models.lunar import MOON_RADIUS, LunarDescentModel
from gpf_nav.sim.scenario import Scenario, ScenarioConfig, filter_model, generate

VARIANTS = {"GPF": "gpf", "GPF-paper": "gpf-paper", "GPF-Q": "gpf-qmetric", "SPF": "spf", "SPF-2k": "spf"}
"""The campaign's variant (its table rows) -> the :mod:`gpf_nav.registry` filter it runs."""
_TUNED = {"SPF-2k": (2000, 1e-2)}  # variant: (particles, filter_accel_noise_density)
VARIANT_LABELS = {
    variant: f"{registry.label(name)}, " + (f"{_TUNED[variant][0]} particles, filter process-noise density "
                                            f"{_TUNED[variant][1]:g} m/s^1.5 (10x the truth's): a tuned, nearly "
                                            "consistent reference, not in the paper"
                                            if variant in _TUNED else "N particles")
    for variant, name in VARIANTS.items()}
"""The legend of each variant: the registry label and the particles (and tuning)."""
LEVEL_CODES = {"OK": 0, "WARN": 1, "FAULT": 2}
FIGURES = Path(__file__).resolve().parents[2] / "docs" / "figures"


def make_filter(variant: str, model, n_particles: int, seed: int):
    """The filter of ``variant`` (one of :data:`VARIANTS`), with its diagnostic co-state."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; known: {tuple(VARIANTS)}")
    n_particles = _TUNED.get(variant, (n_particles,))[0]
    return registry.make(VARIANTS[variant], model, n_particles, seed, compute_costate=True)


@dataclass(frozen=True)
class Settings:
    """Everything an evaluation needs (written to the JSON)."""

    runs: int = 24
    particles: int = 200
    seed: int = 2024
    epsilon: float = 0.09
    fault_time: float = 1200.0
    post_fault: float = 400.0
    gravity_scales: tuple[float, ...] = (1.2, 1.02)
    range_biases: tuple[float, ...] = (10.0, 3.0)
    azimuth_biases: tuple[float, ...] = (10.0,)
    window: int = 10
    reference: int = 20
    min_reference: int = 6
    gap: int = 2
    false_alarm_rate: float = 1e-3
    warn_false_alarm_rate: float = 1e-2
    variants: tuple[str, ...] = tuple(VARIANTS)
    alphas: tuple[float, ...] = (1e-3, 1e-2, 5e-2, 0.1)
    run_alphas: tuple[float, ...] = (1e-6, 1e-5, 1e-4, 1e-3)

    def faults(self) -> list[tuple[str, str, float]]:
        """``(name, kind, magnitude)`` of the mid-run faults."""
        return ([(f"gravity x{g:g}", "gravity", g) for g in self.gravity_scales]
                + [(f"range {b:+g} sigma", "range", b) for b in self.range_biases]
                + [(f"azimuth {b:+g} sigma", "azimuth", b) for b in self.azimuth_biases])

    def monitor(self) -> CostateMonitor:
        return CostateMonitor(window=self.window, reference=self.reference, min_reference=self.min_reference,
                              gap=self.gap, false_alarm_rate=self.false_alarm_rate,
                              warn_false_alarm_rate=self.warn_false_alarm_rate)


def _seeds(seed: int, run: int) -> tuple[int, int, int]:
    """Scenario seed, filter seed and fault-noise seed of run ``run``."""
    words = np.random.SeedSequence([int(seed), int(run)]).generate_state(3, np.uint64)
    return int(words[0]), int(words[1]), int(words[2])


# --- faulty measurement streams -------------------------------------------------------------------------
def gravity_step(scenario: Scenario, fault_step: int, scale: float, rng: np.random.Generator,
                 end: int | None = None, truth_step: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Truth ``(K + 1, 6)`` and measurements ``(K, 3)`` with the gravity scaled by ``scale`` from
    ``truth[fault_step]`` on; the measurement noise realisations of ``scenario`` are kept. Only steps
    before ``end`` (default: all) are re-integrated; later rows are NaN.

    Raises ValueError if the faulty truth reaches the surface before ``end``.
    """
    config = scenario.config
    base = filter_model(config)  # mu_scale 1, the measurement model of the scenario
    faulty = LunarDescentModel(mu_scale=scale, station=config.station, accel_noise_density=1.0,
                               max_step=truth_step)
    q = config.truth_accel_noise_density ** 2 * faulty.process_noise(config.dt)  # density 1 above
    chol = np.linalg.cholesky(q) if config.truth_accel_noise_density > 0 else np.zeros((6, 6))
    steps = scenario.measurements.shape[0]
    end = steps if end is None else min(int(end), steps)
    truth = scenario.truth.copy()
    truth[end + 1:] = np.nan
    x = truth[fault_step][None, :]
    for k in range(fault_step, end):
        x = faulty.transition(x, config.dt, 0.0, scenario.specific_force[k]) + chol @ rng.standard_normal(6)
        truth[k + 1] = x[0]
    if np.min(np.linalg.norm(truth[:end + 1, :3], axis=1)) < MOON_RADIUS:
        raise ValueError("the gravity-step truth reaches the lunar surface; lower the scale or "
                         "shorten --post-fault")
    noise = base.residual(scenario.measurements, base.measure(scenario.truth[1:]))
    y = scenario.measurements.copy()
    fresh = base.measure(truth[fault_step + 1:end + 1]) + noise[fault_step:end]
    fresh[:, 1] = wrap_angle(fresh[:, 1])
    y[fault_step:end] = np.where(np.isfinite(scenario.measurements[fault_step:end]), fresh, np.nan)
    y[end:] = np.nan
    return truth, y


def biased(scenario: Scenario, fault_step: int, component: int, sigmas: float) -> np.ndarray:
    """Measurements with ``sigmas`` noise standard deviations added to ``component`` from ``fault_step``."""
    std = np.sqrt(np.diag(filter_model(scenario.config).measurement_noise()))
    y = scenario.measurements.copy()
    y[fault_step:, component] += sigmas * std[component]
    if component > 0:
        y[fault_step:, component] = wrap_angle(y[fault_step:, component])
    return y


# --- running filters and monitors -----------------------------------------------------------------------
def run_steps(flt, measurements: np.ndarray, truth: np.ndarray, force: np.ndarray, dt: float,
              k0: int, k1: int) -> dict:
    """Steps ``k0 .. k1 - 1`` of an initialised filter.

    Returns per step the co-state mean, the measured mask, the position error (m) and the whitened
    innovation ``(y - h(predicted mean)) / sigma`` (a filter-independent consistency check: for a
    consistent filter its time mean is near zero).
    """
    m = measurements.shape[1]
    model = flt.model
    std = np.sqrt(np.diag(model.measurement_noise()))
    costate = np.full((k1 - k0, m), np.nan)
    innovation = np.full((k1 - k0, m), np.nan)
    error = np.full(k1 - k0, np.nan)
    for i, k in enumerate(range(k0, k1)):
        try:
            flt.predict(dt, force[k])
            predicted = model.measure(flt.mean[None, :])[0]
            flt.update(measurements[k])
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            break
        innovation[i] = model.residual(measurements[k], predicted) / std
        costate[i] = flt.costate_mean
        e = flt.mean[:3] - truth[k + 1, :3]
        error[i] = math.sqrt(float(e @ e))
    return {"costate": costate, "measured": np.isfinite(measurements[k0:k1]), "error": error,
            "innovation": innovation}


def _join(a: dict, b: dict) -> dict:
    return {key: np.concatenate([a[key], b[key]]) for key in a}


def monitor_series(settings: Settings, costate: np.ndarray, measured: np.ndarray) -> dict:
    """Feed a co-state series to a fresh monitor; per-step level code, ``T^2``, threshold, p, ready."""
    monitor = settings.monitor()
    n = costate.shape[0]
    out = {"level": np.zeros(n, dtype=np.int8), "statistic": np.full(n, np.nan),
           "threshold": np.full(n, np.nan), "p_value": np.ones(n), "ready": np.zeros(n, dtype=bool)}
    for k in range(n):
        s = monitor.update(costate[k], measured[k])
        out["level"][k] = LEVEL_CODES[s.level]
        out["statistic"][k], out["threshold"][k] = s.statistic, s.threshold
        out["p_value"][k], out["ready"][k] = s.p_value, s.ready
    out["rejected"] = monitor.rejected
    return out


def run_one(settings: Settings, run: int, keep_series: bool = False) -> dict:
    """Every variant on run ``run``: nominal, the mid-run faults, and the mismatch scenario.

    Nominal and mismatch runs cover the whole descent; the mid-run fault runs end ``post_fault`` seconds
    after the fault (a gravity step of 20 % would otherwise take the truth into the surface).
    """
    scenario_seed, filter_seed, fault_seed = _seeds(settings.seed, run)
    nominal_config = ScenarioConfig(epsilon=0.0)
    nominal = generate(nominal_config, scenario_seed)
    mismatch = generate(replace(nominal_config, epsilon=settings.epsilon), scenario_seed)
    dt = nominal_config.dt
    steps = nominal_config.steps
    fault_step = int(round(settings.fault_time / dt))
    fault_end = min(steps, fault_step + int(round(settings.post_fault / dt)))
    if not 0 < fault_step < steps:
        raise ValueError("fault_time must lie inside the run")
    streams = {}
    rng = np.random.default_rng(fault_seed)
    for name, kind, size in settings.faults():
        if kind == "gravity":
            streams[name] = gravity_step(nominal, fault_step, size, rng, end=fault_end)
        else:
            streams[name] = (nominal.truth, biased(nominal, fault_step, 0 if kind == "range" else 1, size))
    result = {"run": run, "variants": {}}
    for variant in settings.variants:
        config = nominal_config
        if variant in _TUNED:
            config = replace(config, filter_accel_noise_density=_TUNED[variant][1])
        model = filter_model(config)
        series = {}
        flt = make_filter(variant, model, settings.particles, filter_seed)
        flt.initialize(nominal.prior_mean, nominal.prior_cov)
        head = run_steps(flt, nominal.measurements, nominal.truth, nominal.specific_force, dt, 0, fault_step)
        for name, (truth, y) in streams.items():
            tail = run_steps(copy.deepcopy(flt), y, truth, nominal.specific_force, dt, fault_step, fault_end)
            series[name] = _join(head, tail)
        tail = run_steps(flt, nominal.measurements, nominal.truth, nominal.specific_force, dt, fault_step,
                         steps)
        series["nominal"] = _join(head, tail)
        flt = make_filter(variant, model, settings.particles, filter_seed)
        flt.initialize(mismatch.prior_mean, mismatch.prior_cov)
        series["mismatch"] = run_steps(flt, mismatch.measurements, mismatch.truth, mismatch.specific_force,
                                       dt, 0, steps)
        summary = {}
        for name, s in series.items():
            mon = monitor_series(settings, s["costate"], s["measured"])
            summary[name] = summarise(mon, s["error"], nominal.times,
                                      None if name == "mismatch" else fault_step, fault_end - fault_step,
                                      settings.alphas)
            if name == "nominal":  # whitened innovation over the second half: time mean and RMS
                half = s["innovation"][steps // 2:]
                summary[name]["innovation_mean"] = np.nanmean(half, axis=0).tolist()
                summary[name]["innovation_rms"] = np.sqrt(np.nanmean(half ** 2, axis=0)).tolist()
            if keep_series:
                summary[name]["series"] = {"statistic": mon["statistic"], "threshold": mon["threshold"],
                                           "level": mon["level"], "error": s["error"],
                                           "costate": s["costate"]}
        result["variants"][variant] = summary
    return result


def summarise(mon: dict, error: np.ndarray, times: np.ndarray, fault_step: int | None,
              horizon: int | None = None, alphas=Settings.alphas) -> dict:
    """Per-run figures of one monitored series; with ``fault_step``, also the detection figures over the
    ``horizon`` steps from it (for the nominal run: the chance of a FAULT in the same interval)."""
    level, ready = mon["level"], mon["ready"]
    fault = level == 2
    p = mon["p_value"][ready]
    out = {
        "p_below": [int((p < a).sum()) for a in alphas],
        "ready_time": float(times[np.argmax(ready)]) if ready.any() else math.nan,
        "ready_steps": int(ready.sum()),
        "fault_steps": int(fault.sum()),
        "warn_steps": int((level >= 1).sum()),
        "position_rmse": float(np.sqrt(np.nanmean(error ** 2))),
        "finished": bool(np.all(np.isfinite(error))),
        "rejected": int(mon["rejected"]),
    }
    first = np.flatnonzero(fault)
    out["first_fault_time"] = float(times[first[0]]) if first.size else math.nan
    out["min_p"] = float(p.min()) if p.size else 1.0
    if fault_step is not None:
        onset = times[fault_step - 1]  # = fault_time; measurement fault_step is the first faulty one
        pre = slice(0, fault_step)
        post = slice(fault_step, None if horizon is None else fault_step + horizon)
        after = np.flatnonzero(fault[post])
        out["fault_time"] = float(onset)
        out["delay"] = float(times[fault_step + after[0]] - onset) if after.size else math.nan
        out["pre_fault_steps"] = int(fault[pre].sum())
        out["pre_ready_steps"] = int(ready[pre].sum())
        out["faulted_at_onset"] = bool(fault[fault_step - 1])
        out["post_fault_steps"] = int(fault[post].sum())
        out["post_steps"] = int(ready[post].sum())
        p_post = mon["p_value"][post][ready[post]]
        out["min_p_post"] = float(p_post.min()) if p_post.size else 1.0
        out["pre_rmse"] = float(np.sqrt(np.nanmean(error[pre] ** 2)))
        out["post_rmse"] = float(np.sqrt(np.nanmean(error[post] ** 2)))
    return out


# --- aggregation ---------------------------------------------------------------------------------------
def _pct(values, q):
    """Percentile ``q`` of the finite values (NaN if none)."""
    values = np.asarray([v for v in values if np.isfinite(v)])
    return float(np.percentile(values, q)) if values.size else math.nan


def _rank_pct(values, q):
    """Nearest-rank percentile ``q`` with misses (NaN) counted as infinite delays."""
    values = np.sort([v if np.isfinite(v) else math.inf for v in values])
    if not values.size:
        return math.nan
    return float(values[max(0, math.ceil(q / 100.0 * values.size) - 1)])


def aggregate(settings: Settings, runs: list[dict]) -> dict:
    """Pool the per-run figures per variant and scenario."""
    out = {}
    faults = [name for name, _, _ in settings.faults()]
    for variant in settings.variants:
        rows = {name: [r["variants"][variant][name] for r in runs]
                for name in ["nominal", "mismatch"] + faults}
        nom = rows["nominal"]
        ready = sum(r["ready_steps"] for r in nom)
        n_fault = sum(r["fault_steps"] for r in nom)
        warns = sum(r["warn_steps"] for r in nom)
        rmse = np.array([r["position_rmse"] for r in nom])
        frac = np.array([r["fault_steps"] / max(r["ready_steps"], 1) for r in nom])
        clean = rmse <= np.median(rmse)
        below = np.sum([r["p_below"] for r in nom], axis=0)
        entry = {"nominal": {
            "ready_steps": ready,
            "alphas": list(settings.alphas), "rate_p_below": [float(b) / max(ready, 1) for b in below],
            "fault_rate": n_fault / max(ready, 1), "warn_rate": warns / max(ready, 1),
            "runs_with_fault": int(sum(r["fault_steps"] > 0 for r in nom)), "runs": len(nom),
            "median_position_rmse": float(np.median(rmse)),
            "fault_rate_better_half": _mean(frac[clean]),
            "fault_rate_worse_half": _mean(frac[~clean]),
            "rmse_alarm_correlation": _spearman(rmse, frac),
            "median_abs_range_innovation_mean": float(np.median([abs(r["innovation_mean"][0]) for r in nom])),
            "median_range_innovation_rms": float(np.median([r["innovation_rms"][0] for r in nom])),
        }}
        mis = rows["mismatch"]
        times = [r["first_fault_time"] for r in mis]
        entry["nominal"]["runs_min_p_below"] = [int(sum(r["min_p"] < a for r in nom))
                                                for a in settings.run_alphas]
        entry["nominal"]["median_first_fault"] = _pct([r["first_fault_time"] for r in nom], 50)
        entry["mismatch"] = {
            "runs": len(mis), "missed": int(sum(not np.isfinite(t) for t in times)),
            "median_first_fault": _pct(times, 50), "p90_first_fault": _pct(times, 90),
            "ready_time": _pct([r["ready_time"] for r in mis], 50),
            "runs_min_p_below": [int(sum(r["min_p"] < a for r in mis)) for a in settings.run_alphas],
            "fault_rate": sum(r["fault_steps"] for r in mis) / max(sum(r["ready_steps"] for r in mis), 1),
            "median_position_rmse": float(np.median([r["position_rmse"] for r in mis])),
        }
        for name in faults + ["control"]:
            rs = rows["nominal" if name == "control" else name]
            delays = [r["delay"] for r in rs if not r["faulted_at_onset"]]  # runs already in FAULT: no test
            entry[name] = {
                "runs": len(rs), "clean_runs": len(delays),
                "missed": int(sum(not np.isfinite(d) for d in delays)),
                "median_delay": _pct(delays, 50), "p90_delay": _pct(delays, 90),
                "p90_delay_with_misses": _rank_pct(delays, 90),
                "faulted_at_onset": int(sum(r["faulted_at_onset"] for r in rs)),
                "pre_fault_rate": sum(r["pre_fault_steps"] for r in rs) / max(sum(r["pre_ready_steps"]
                                                                              for r in rs), 1),
                "post_fault_rate": sum(r["post_fault_steps"] for r in rs) / max(sum(r["post_steps"]
                                                                                for r in rs), 1),
                "median_post_rmse": float(np.median([r["post_rmse"] for r in rs])),
                "run_alphas": list(settings.run_alphas),
                "runs_min_p_post_below": [int(sum(r["min_p_post"] < a for r in rs))
                                          for a in settings.run_alphas],
            }
        out[variant] = entry
    return out


def _mean(values) -> float:
    return float(np.mean(values)) if len(values) else math.nan


def _spearman(a, b) -> float:
    from scipy import stats

    if np.ptp(a) == 0 or np.ptp(b) == 0:
        return math.nan
    return float(stats.spearmanr(a, b).statistic)


def _fmt(x, unit="", digits=0):
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "inf" if x == math.inf else "-"
    return f"{x:.{digits}f}{unit}"


def table(settings: Settings, summary: dict) -> str:
    """Plain-text tables of the aggregated figures."""
    lines = [f"Alarms at epsilon = 0 (per ready step; set FAULT {settings.false_alarm_rate:g}, "
             f"WARN-or-worse {settings.warn_false_alarm_rate:g}); {settings.runs} runs x 1200 steps, "
             f"N = {settings.particles} (SPF-2k: 2000)",
             f"{'variant':8s} {'FAULT rate':>10s} {'WARN+ rate':>10s} {'runs w/ FAULT':>13s} "
             f"{'pos RMSE':>9s} {'FAULT rate by RMSE':>19s} {'range innovation (sigma)':>25s}",
             f"{'':8s} {'':>10s} {'':>10s} {'':>13s} {'median':>9s} {'best / worst half':>19s} "
             f"{'|time mean| / RMS, med':>25s}"]
    for v in settings.variants:
        n = summary[v]["nominal"]
        lines.append(f"{v:8s} {n['fault_rate']:10.5f} {n['warn_rate']:10.5f} "
                     f"{n['runs_with_fault']:>7d} / {n['runs']:<3d} {n['median_position_rmse']:7.0f} m "
                     f"{n['fault_rate_better_half']:>9.4f} / {n['fault_rate_worse_half']:<7.4f} "
                     f"{n['median_abs_range_innovation_mean']:>13.2f} / "
                     f"{n['median_range_innovation_rms']:.2f}")
    lines += ["", "Calibration at epsilon = 0: fraction of ready steps with p-value below alpha",
              f"{'variant':8s} " + " ".join(f"{'a=' + format(a, 'g'):>9s}" for a in settings.alphas)]
    for v in settings.variants:
        rates = summary[v]["nominal"]["rate_p_below"]
        lines.append(f"{v:8s} " + " ".join(f"{r:9.4f}" for r in rates))
    lines += ["", f"Mismatch epsilon = {settings.epsilon} from t = 0: time to the first FAULT (s); control: "
              "the same at epsilon = 0",
              f"{'variant':8s} {'ready at':>9s} {'median':>8s} {'90 %':>8s} {'missed':>8s} "
              f"{'FAULT rate':>11s} {'control: median, runs w/o FAULT':>32s}"]
    for v in settings.variants:
        m, n = summary[v]["mismatch"], summary[v]["nominal"]
        lines.append(f"{v:8s} {_fmt(m['ready_time']):>9s} {_fmt(m['median_first_fault']):>8s} "
                     f"{_fmt(m['p90_first_fault']):>8s} {m['missed']:>4d} / {m['runs']:<2d} "
                     f"{m['fault_rate']:11.3f} {_fmt(n['median_first_fault']):>21s}, "
                     f"{n['runs'] - n['runs_with_fault']:>2d} / {n['runs']}")
    lines += ["", f"Sudden faults at t = {settings.fault_time:.0f} s: detection delay (s) = first FAULT at "
              "or after the fault minus the fault time",
              f"over the {settings.post_fault:.0f} s after it and the runs not already in FAULT at the fault "
              "time; median of the detected runs, 90 % = nearest rank counting misses as infinite;",
              "'control' = the same interval of the fault-free run: its 'detections' are false alarms",
              f"{'fault':17s} {'variant':8s} {'median':>8s} {'90 %':>8s} {'missed':>8s} {'FAULT@onset':>12s} "
              f"{'FAULT rate pre/post':>20s}"]
    for name in [name for name, _, _ in settings.faults()] + ["control"]:
        for v in settings.variants:
            f = summary[v][name]
            lines.append(f"{name:17s} {v:8s} {_fmt(f['median_delay']):>8s} "
                         f"{_fmt(f['p90_delay_with_misses']):>8s} {f['missed']:>4d} / {f['clean_runs']:<2d} "
                         f"{f['faulted_at_onset']:>8d} / {f['runs']:<2d} "
                         f"{f['pre_fault_rate']:9.3f} / {f['post_fault_rate']:.3f}")
    alphas = settings.run_alphas
    lines += ["", "Runs (of all) with a p-value below alpha: epsilon = 0 (whole run), mismatch (whole run), "
              f"and each fault over the {settings.post_fault:.0f} s after {settings.fault_time:.0f} s "
              "('control': the fault-free run there)",
              f"{'case':17s} {'variant':8s} " + " ".join(f"{'a=' + format(a, 'g'):>8s}" for a in alphas)]
    for name in ["nominal", "mismatch"] + [name for name, _, _ in settings.faults()] + ["control"]:
        for v in settings.variants:
            f = summary[v][name]
            counts = f["runs_min_p_below"] if "runs_min_p_below" in f else f["runs_min_p_post_below"]
            lines.append(f"{name:17s} {v:8s} " + " ".join(f"{c:>3d} / {f['runs']:<2d}" for c in counts))
    return "\n".join(lines)


# --- figures -------------------------------------------------------------------------------------------
_DPI = 100  # the panels are wide (up to 19 in): a lower resolution than plots.save's default
_COLOURS = {"GPF": "#d62728", "GPF-paper": "#ff7f0e", "GPF-Q": "#e377c2", "SPF": "#1f77b4", "SPF-2k": "#2ca02c"}


def draw_figures(settings: Settings, runs: list[dict], summary: dict, example: dict, times: np.ndarray,
                 directory: Path) -> list[Path]:
    """``integrity_false_alarms.png``, ``integrity_delays.png`` and ``integrity_example.png``."""
    from matplotlib.ticker import NullFormatter

    from gpf_nav.experiments.plots import pyplot, save

    plt = pyplot()
    written = []
    variants = settings.variants

    # 1. false alarms at epsilon = 0: pooled rates vs the set rates, and per-run rate vs position RMSE
    fig, axes = plt.subplots(1, 3, figsize=(19, 4.8))
    ax = axes[0]
    x = np.arange(len(variants))
    floor = 1e-5
    fr = [max(summary[v]["nominal"]["fault_rate"], floor) for v in variants]
    wr = [max(summary[v]["nominal"]["warn_rate"], floor) for v in variants]
    ax.bar(x - 0.2, fr, 0.4, label="FAULT", color="#444444")
    ax.bar(x + 0.2, wr, 0.4, label="WARN or worse", color="#bbbbbb")
    ax.axhline(settings.false_alarm_rate, color="k", ls="--",
               label=f"set FAULT rate {settings.false_alarm_rate:g}")
    ax.axhline(settings.warn_false_alarm_rate, color="0.5", ls=":",
               label=f"set WARN rate {settings.warn_false_alarm_rate:g}")
    ax.set_yscale("log")
    ax.set_ylim(floor / 2, 1.5)
    ax.set_xticks(x, variants)
    ax.set_ylabel("alarm rate per ready step")
    ax.set_title(f"Alarm rate at epsilon = 0 ({settings.runs} runs x 1200 steps, N = {settings.particles})")
    ax.legend(fontsize=8)
    for ax, what in zip(axes[1:], ("rmse", "bias")):
        for v in variants:
            nom = [r["variants"][v]["nominal"] for r in runs]
            x = [n["position_rmse"] / 1e3 if what == "rmse" else abs(n["innovation_mean"][0]) for n in nom]
            fr = [max(n["fault_steps"] / max(n["ready_steps"], 1), floor) for n in nom]
            ax.scatter(x, fr, s=18, color=_COLOURS.get(v), label=v, alpha=0.8)
        ax.axhline(settings.false_alarm_rate, color="k", ls="--", lw=1)
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_yscale("log")
        ax.set_ylim(floor / 2, 1.5)
        ax.set_ylabel(f"FAULT rate of the run (floored at {floor:g})")
        ax.legend(fontsize=8)
        if what == "rmse":
            ax.set_xlabel("position RMSE of the run (km)")
            ax.set_title("Per run at epsilon = 0: alarms vs position error", fontsize=10)
        else:
            ax.set_xlabel("|time mean of the whitened range innovation|, 1200-2400 s (sigma)")
            ax.set_title("Per run at epsilon = 0: alarms vs range prediction bias", fontsize=10)
    written.append(save(fig, directory / "integrity_false_alarms.png", dpi=_DPI))

    # 2. detection delays per fault and variant; runs already in FAULT at the fault time are not tests
    faults = [name for name, _, _ in settings.faults()]
    names = ["mismatch"] + faults + ["control"]
    cols = 3
    rows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 4.4 * rows), squeeze=False)
    for ax, name in zip(axes.flat, names):
        for i, v in enumerate(variants):
            rs = [r["variants"][v]["nominal" if name == "control" else name] for r in runs]
            if name == "mismatch":
                d = np.array([r["first_fault_time"] for r in rs])
                note = f"missed\n{int((~np.isfinite(d)).sum())}/{d.size}"
            else:
                d = np.array([r["delay"] for r in rs if not r["faulted_at_onset"]])
                note = (f"missed {int((~np.isfinite(d)).sum())}/{d.size}\n"
                        f"in FAULT {len(rs) - d.size}")
            hit = d[np.isfinite(d)]
            jitter = (np.random.default_rng(i).random(hit.size) - 0.5) * 0.3
            ax.scatter(np.full(hit.size, i) + jitter, hit, s=14, color=_COLOURS.get(v))
            if hit.size:
                ax.hlines(np.median(hit), i - 0.3, i + 0.3, color="k")
            ax.text(i, 1.01, note, ha="center", va="bottom", fontsize=7, transform=ax.get_xaxis_transform())
        ax.set_yscale("log")
        ax.set_ylim(*((100.0, 2400.0) if name == "mismatch" else (1.5, 1.1 * settings.post_fault)))
        ax.set_xticks(range(len(variants)), variants)
        ax.set_xlim(-0.6, len(variants) - 0.4)
        ax.grid(True, axis="y", which="both", alpha=0.3)
        if name == "mismatch":
            ax.set_ylabel("time to first FAULT from t = 0 (s)")
            ax.set_title(f"epsilon = {settings.epsilon} from the start", pad=26, fontsize=10)
        elif name == "control":
            ax.set_ylabel(f"first FAULT after {settings.fault_time:.0f} s (s)")
            ax.set_title(f"no fault (control: false alarms in the same {settings.post_fault:.0f} s)",
                         pad=26, fontsize=10)
        else:
            ax.set_ylabel("first FAULT after the fault (s)")
            ax.set_title(f"{name} from {settings.fault_time:.0f} s", pad=26, fontsize=10)
    for ax in axes.flat[len(names):]:
        ax.set_visible(False)
    fig.suptitle(f"Co-state monitor detection, {settings.runs} runs (bar: median of detected runs; "
                 "runs already in FAULT at the fault time are left out)", y=1.0)
    fig.tight_layout()
    written.append(save(fig, directory / "integrity_delays.png", dpi=_DPI))

    # 3. one run: T^2 / threshold against time for every scenario and variant
    fig, axes = plt.subplots(len(faults) + 2, 1, figsize=(11, 2.4 * (len(faults) + 2)), sharex=True)
    for ax, name in zip(axes, ["nominal", "mismatch"] + faults):
        for v in variants:
            s = example["variants"][v][name]["series"]
            ratio = s["statistic"] / s["threshold"]
            ax.plot(times[:ratio.size], ratio, color=_COLOURS.get(v), lw=0.9, label=v)
        ax.axhline(1.0, color="k", ls="--", lw=0.8)
        if name in faults:
            ax.axvline(settings.fault_time, color="0.4", ls=":", lw=1.2)
        ax.set_yscale("log")
        ax.set_ylabel("T^2 / FAULT threshold")
        label = {"nominal": "epsilon = 0, no fault",
                 "mismatch": f"epsilon = {settings.epsilon} from the start"}.get(
            name, f"{name} from {settings.fault_time:.0f} s")
        ax.set_title(f"run {example['run']}: {label}", fontsize=10)
    axes[0].legend(fontsize=8, ncol=3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle("Monitor statistic relative to its FAULT threshold (above 1 = FAULT; dotted: fault time)",
                 y=1.0)
    fig.tight_layout()
    written.append(save(fig, directory / "integrity_example.png", dpi=_DPI))
    return written


# --- synthetic calibration ------------------------------------------------------------------------------
SYNTHETIC = ("iid", "differenced", "ar0.5", "ar0.8", "ar0.9")


def synthetic_series(kind: str, steps: int, rng: np.random.Generator, m: int = 3) -> np.ndarray:
    """H0 co-state series ``(steps, m)``: iid N(0, 1), a first difference of white noise (the default
    GPF's co-state is close to it), or an AR(1) ``ar<phi>``; components scaled by 1, 1e3 and 1e6."""
    e = rng.standard_normal((steps + 1, m))
    if kind == "iid":
        x = e[1:]
    elif kind == "differenced":
        x = e[1:] - e[:-1]
    elif kind.startswith("ar"):
        phi = float(kind[2:])
        x = np.empty((steps, m))
        x[0] = e[0] / math.sqrt(1.0 - phi * phi)
        for k in range(1, steps):
            x[k] = phi * x[k - 1] + e[k]
    else:
        raise ValueError(f"unknown series {kind!r}")
    return x * np.logspace(0, 3 * (m - 1), m)


def synthetic_calibration(settings: Settings, steps: int, seed: int) -> dict:
    """Per-ready-step rate of ``p < alpha`` of one monitor run over each synthetic H0 series."""
    out = {}
    for i, kind in enumerate(SYNTHETIC):
        x = synthetic_series(kind, steps, np.random.default_rng([seed, i]))
        mon = monitor_series(settings, x, np.ones(x.shape, dtype=bool))
        p = mon["p_value"][mon["ready"]]
        out[kind] = {"ready_steps": int(p.size),
                     "rate_p_below": [float(np.mean(p < a)) for a in settings.alphas],
                     "quarantined_tests": int(np.sum(p < settings.false_alarm_rate / 100.0))}
    return out


# --- command line --------------------------------------------------------------------------------------
def _csv(values) -> str:
    return ",".join(f"{v:g}" for v in values)


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split(",") if v.strip())


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    d = Settings()
    parser = CommandParser(prog="gpf-nav integrity", description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=positive_int, default=d.runs)
    parser.add_argument("--particles", type=positive_int, default=d.particles)
    parser.add_argument("--seed", type=int, default=d.seed)
    parser.add_argument("--epsilon", type=float, default=d.epsilon)
    parser.add_argument("--fault-time", type=float, default=d.fault_time, help="s")
    parser.add_argument("--post-fault", type=float, default=d.post_fault,
                        help="s evaluated after a mid-run fault")
    parser.add_argument("--gravity-scales", default=_csv(d.gravity_scales),
                        help="comma list of gravity multipliers from the fault time")
    parser.add_argument("--range-biases", default=_csv(d.range_biases), help="comma list, range sigmas")
    parser.add_argument("--azimuth-biases", default=_csv(d.azimuth_biases), help="comma list, azimuth sigmas")
    parser.add_argument("--window", type=positive_int, default=d.window)
    parser.add_argument("--reference", type=positive_int, default=d.reference)
    parser.add_argument("--min-reference", type=positive_int, default=d.min_reference)
    parser.add_argument("--gap", type=int, default=d.gap)
    parser.add_argument("--false-alarm-rate", type=float, default=d.false_alarm_rate)
    parser.add_argument("--warn-false-alarm-rate", type=float, default=d.warn_false_alarm_rate)
    parser.add_argument("--variants", default=",".join(d.variants), help=f"comma list of {tuple(VARIANTS)}")
    parser.add_argument("--out", type=Path, default=Path("results/integrity"), help="JSON directory")
    parser.add_argument("--figures", type=Path, default=FIGURES, help="figure directory")
    parser.add_argument("--no-plots", action="store_true")
    parser.add_argument("--replot", type=Path, metavar="JSON",
                        help="instead: print the table and redraw the figures of a previous integrity.json")
    parser.add_argument("--synthetic", type=int, default=0, metavar="STEPS",
                        help="instead: calibration of the monitor on synthetic H0 series of STEPS steps")
    args = parser.parse_args(argv)
    variants = tuple(v.strip() for v in args.variants.split(",") if v.strip())
    if not variants or any(v not in VARIANTS for v in variants):
        parser.error(f"--variants must be a comma list of {tuple(VARIANTS)}")
    try:
        lists = {name: _floats(getattr(args, name)) for name in ("gravity_scales", "range_biases", "azimuth_biases")}
    except ValueError:
        parser.error("--gravity-scales, --range-biases and --azimuth-biases must be comma-separated numbers")
    settings = Settings(runs=args.runs, particles=args.particles, seed=args.seed, epsilon=args.epsilon,
                        fault_time=args.fault_time, post_fault=args.post_fault, **lists, window=args.window,
                        reference=args.reference, min_reference=args.min_reference, gap=args.gap,
                        false_alarm_rate=args.false_alarm_rate,
                        warn_false_alarm_rate=args.warn_false_alarm_rate, variants=variants)
    try:
        settings.monitor()  # refuses inconsistent monitor settings before any run
    except ValueError as err:
        parser.error(str(err))
    start = time.perf_counter()
    if args.replot:
        report = read_json(args.replot)
        settings = Settings(**{k: tuple(v) if isinstance(v, list) else v
                               for k, v in report["settings"].items()})
        runs = report["runs"]
        for r in runs:
            for v in r["variants"].values():
                for s in v.values():
                    for key in ("series",):
                        if key in s:
                            s[key] = {k: np.array(x, dtype=float) for k, x in s[key].items()}
        times = ScenarioConfig().dt * np.arange(1, ScenarioConfig().steps + 1)
        print(table(settings, report["summary"]))
        written = draw_figures(settings, runs, report["summary"], runs[0], times, args.figures)
        print("wrote " + ", ".join(str(p) for p in written))
        return 0
    if args.synthetic:
        result = synthetic_calibration(settings, args.synthetic, settings.seed)
        print(f"Monitor on synthetic H0 series, {args.synthetic} steps each: fraction of ready steps with "
              "p below alpha")
        print(f"{'series':12s} " + " ".join(f"{'a=' + format(a, 'g'):>9s}" for a in settings.alphas))
        for kind, r in result.items():
            print(f"{kind:12s} " + " ".join(f"{v:9.4f}" for v in r["rate_p_below"]))
        path = args.out / "integrity_synthetic.json"
        write_json({"settings": settings.__dict__, "steps": args.synthetic, "series": result,
                    "command": "python -m gpf_nav.experiments.integrity_campaign " + " ".join(argv)}, path)
        print(f"\nwall time {time.perf_counter() - start:.0f} s; wrote {path}")
        return 0
    commit = git_commit()  # the code this process runs; read before a long campaign
    runs = []
    for run in range(settings.runs):
        runs.append(run_one(settings, run, keep_series=(run == 0)))
        print(f"run {run + 1}/{settings.runs} done ({time.perf_counter() - start:.0f} s)", file=sys.stderr)
    summary = aggregate(settings, runs)
    wall = time.perf_counter() - start
    print(table(settings, summary))
    times = ScenarioConfig().dt * np.arange(1, ScenarioConfig().steps + 1)
    written = []
    if not args.no_plots:
        written = draw_figures(settings, runs, summary, runs[0], times, args.figures)
    for r in runs:  # keep the example run's monitor statistic and threshold (for --replot) only
        for v in r["variants"].values():
            for s in v.values():
                series = s.pop("series", None)
                if series is not None:
                    s["series"] = {"statistic": series["statistic"], "threshold": series["threshold"]}
    report = {"settings": settings.__dict__, "variant_labels": VARIANT_LABELS, "summary": summary,
              "runs": runs, "wall_seconds": wall, "git_commit": commit,
              "command": "python -m gpf_nav.experiments.integrity_campaign " + " ".join(argv)}
    path = args.out / "integrity.json"
    write_json(report, path, indent=None)  # one line: the example run's series are long
    written.append(path)
    print(f"\nwall time {wall:.0f} s; wrote " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
