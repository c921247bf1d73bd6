"""Figures of the Monte Carlo campaign and the sweeps (matplotlib, headless ``Agg`` backend).

matplotlib is an optional extra (``pip install gpf_nav[experiments]``); it is imported only when a
figure is drawn. Every figure states what is plotted, over how many runs, and in which units.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

CASE_TITLES = {"full": "Case 1: full observability (range, azimuth, elevation)",
               "partial": "Case 2: partial observability (range, elevation; no azimuth)",
               "range": "Range only (no azimuth, no elevation)"}

_SHORT_CASE = {"full": "Case 1 (full obs.)", "partial": "Case 2 (partial obs.)"}

_COLOURS = {
    "GPF navigation (default)": "#000000",
    "EKF + compensation": "#bcbd22",
    "EKF + compensation, gated": "#808000",
    "EKF, oracle-tuned Q": "#2ca02c",
    "UKF, oracle-tuned Q": "#9467bd",
    "GPF (innovation, likelihood)": "#d62728",
    "GPF as printed (increment, likelihood)": "#ff7f0e",
    "GPF exact (innovation, corrected)": "#8c564b",
    "GPF Q-metric (innovation, corrected, eps=1)": "#e377c2",
    "SPF": "#1f77b4",
    "EKF": "#2ca02c",
    "UKF": "#9467bd",
    "EnKF": "#17becf",
}
_STYLES = {"UKF": "--", "GPF exact (innovation, corrected)": "--", "EKF, oracle-tuned Q": ":",
           "UKF, oracle-tuned Q": ":"}


def pyplot():
    """``matplotlib.pyplot`` on the headless ``Agg`` backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def colour(name: str) -> str:
    return _COLOURS.get(name, "#7f7f7f")


def style(name: str) -> str:
    return _STYLES.get(name, "-")


def save(fig, path: Path, dpi: int = 110) -> Path:
    """Write ``fig`` to ``path`` (its folder made if need be), trimmed to its content, and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    pyplot().close(fig)
    return path


def error_evolution(times: np.ndarray, errors: dict, runs: int, path: Path) -> Path:
    """Position error (km) against time: median over runs with the 10-90 % band, per filter and case.

    ``errors[case][filter]`` is ``(runs, K)`` in metres.
    """
    plt = pyplot()
    cases = list(errors)
    fig, axes = plt.subplots(1, len(cases), figsize=(7.0 * len(cases), 5.0), squeeze=False, layout="constrained")
    for ax, case in zip(axes[0], cases):
        for name, series in errors[case].items():
            km = np.asarray(series) / 1e3
            ax.plot(times, np.nanmedian(km, axis=0), style(name), color=colour(name), label=name, lw=1.4)
            if km.shape[0] > 1:
                lo, hi = np.nanpercentile(km, [10, 90], axis=0)
                ax.fill_between(times, lo, hi, color=colour(name), alpha=0.15, lw=0)
        ax.set_yscale("log")
        ax.set_xlabel("time since apolune (s)")
        ax.set_ylabel("position error |r_hat - r| (km)")
        ax.set_title(CASE_TITLES.get(case, case), fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    _shared_legend(fig, axes[0][0])
    fig.suptitle(f"Position error over time: median of {runs} Monte Carlo runs, shaded 10-90 % of runs")
    return save(fig, path)


def ess_evolution(times: np.ndarray, ess: dict, runs: int, threshold: float, path: Path) -> Path:
    """ESS/N (before resampling) against time, mean over runs, particle filters only."""
    plt = pyplot()
    cases = list(ess)
    fig, axes = plt.subplots(1, len(cases), figsize=(7.0 * len(cases), 4.5), squeeze=False, layout="constrained")
    for ax, case in zip(axes[0], cases):
        for name, series in ess[case].items():
            s = np.asarray(series)
            mean = np.nanmean(s, axis=0)
            ax.plot(times, mean, style(name), color=colour(name), lw=1.2,
                    label=f"{name}: {np.nanmean(s):.3f}")
        ax.axhline(threshold, color="k", lw=0.8, ls=":", label=f"resampling threshold {threshold:g}")
        ax.set_ylim(-0.02, 1.05)
        ax.set_xlabel("time since apolune (s)")
        ax.set_ylabel("effective sample size / N (after weighting)")
        ax.set_title(CASE_TITLES.get(case, case), fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="lower left", title="time average of ESS/N", title_fontsize=8)
    fig.suptitle(f"Normalised effective sample size, mean of {runs} Monte Carlo runs")
    return save(fig, path)


def nees_evolution(times: np.ndarray, nees: dict, band: tuple[float, float], runs: int, path: Path) -> Path:
    """Run-averaged NEES against time (log scale) with the 95 % chi-square band of a consistent filter."""
    plt = pyplot()
    cases = list(nees)
    fig, axes = plt.subplots(1, len(cases), figsize=(7.0 * len(cases), 4.5), squeeze=False, layout="constrained")
    for ax, case in zip(axes[0], cases):
        for name, series in nees[case].items():
            avg = np.mean(np.asarray(series), axis=0)  # NaN where any run's covariance was singular
            if np.any(np.isfinite(avg)):
                ax.plot(times, avg, style(name), color=colour(name), lw=1.2, label=name)
            else:
                ax.plot([], [], style(name), color=colour(name), label=f"{name} (covariance singular)")
        ax.axhspan(band[0], band[1], color="k", alpha=0.15,
                   label=f"95 % band of a consistent filter [{band[0]:.2f}, {band[1]:.2f}]")
        ax.set_yscale("log")
        ax.set_xlabel("time since apolune (s)")
        ax.set_ylabel("NEES averaged over runs (dimensionless, 6 dof)")
        ax.set_title(CASE_TITLES.get(case, case), fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    _shared_legend(fig, axes[0][0], columns=3)
    fig.suptitle(f"Filter consistency: normalised estimation error squared, mean of {runs} runs "
                 f"(a consistent filter stays in the grey band)")
    return save(fig, path)


def rmse_boxplot(per_run: dict, path: Path) -> Path:
    """Distribution over runs of the position RMSE (km), one box per filter, one panel per case."""
    plt = pyplot()
    cases = list(per_run)
    fig, axes = plt.subplots(1, len(cases), figsize=(7.0 * len(cases), 4.8), squeeze=False, layout="constrained")
    for column, (ax, case) in enumerate(zip(axes[0], cases)):
        names = list(per_run[case])[::-1]  # first filter on top
        data = [np.asarray(per_run[case][n], dtype=float) for n in names]
        data = [d[np.isfinite(d)] for d in data]
        try:
            box = ax.boxplot(data, orientation="horizontal", patch_artist=True, widths=0.6)
        except TypeError:  # matplotlib < 3.10
            box = ax.boxplot(data, vert=False, patch_artist=True, widths=0.6)
        for patch, name in zip(box["boxes"], names):
            patch.set_facecolor(colour(name))
            patch.set_alpha(0.5)
        ax.set_yticks(range(1, len(names) + 1), names if column == 0 else [""] * len(names), fontsize=8)
        ax.set_xscale("log")
        ax.set_xlabel("position RMSE over the run (km)")
        ax.set_title(CASE_TITLES.get(case, case), fontsize=10)
        ax.grid(True, which="both", axis="x", alpha=0.3)
    runs = max(len(v) for c in per_run.values() for v in c.values())
    fig.suptitle(f"Position RMSE per Monte Carlo run ({runs} runs per box)")
    return save(fig, path)


def costate_degeneracy(points: dict, correlations: dict, runs: int, path: Path) -> Path:
    """The paper's co-state / degeneracy figure, SPF against GPF.

    ``points[case][filter]`` holds per-step arrays ``costate``, ``ess``, ``error`` (m) pooled over runs;
    ``correlations[case][filter]`` the Pearson coefficients ``costate_vs_ess`` and ``ess_vs_error``.
    Row per case; left: co-state norm against ESS/N; right: position error against ESS/N.
    """
    plt = pyplot()
    cases = list(points)
    fig, axes = plt.subplots(len(cases), 2, figsize=(13.0, 4.8 * len(cases)), squeeze=False, layout="constrained")
    for row, case in enumerate(cases):
        ax_c, ax_e = axes[row]
        for name, p in points[case].items():
            corr = correlations[case][name]
            rc = _fmt_r(corr["costate_vs_ess"]["pearson"])
            re = _fmt_r(corr["ess_vs_error"]["pearson"])
            ax_c.scatter(p["ess"], p["costate"], s=4, alpha=0.35, color=colour(name),
                         label=f"{name}: rho = {rc}")
            ax_e.scatter(p["ess"], np.asarray(p["error"]) / 1e3, s=4, alpha=0.35, color=colour(name),
                         label=f"{name}: rho = {re}")
        for ax in (ax_c, ax_e):
            ax.set_xlabel("effective sample size / N after weighting (1 = no degeneracy)")
            ax.set_xlim(-0.02, 1.05)
            ax.set_yscale("log")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8, markerscale=3, loc="best")
        ax_c.set_ylabel("mean co-state norm |lambda| (m^2/s)")
        ax_e.set_ylabel("position error (km)")
        label = _SHORT_CASE.get(case, case)
        ax_c.set_title(f"({'abcdefgh'[2 * row]}) {label}: co-state norm vs ESS/N", fontsize=10)
        ax_e.set_title(f"({'abcdefgh'[2 * row + 1]}) {label}: position error vs ESS/N", fontsize=10)
    fig.suptitle(f"Co-state, degeneracy and error, one point per time step of {runs} runs "
                 f"(rho: Pearson correlation over all steps)")
    return save(fig, path)


def _shared_legend(fig, ax, columns: int = 4) -> None:
    """One legend for the whole figure, below the panels, so no curve is hidden behind it."""
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=columns, fontsize=8, frameon=False)


def _fmt_r(value) -> str:
    return "n/a" if value is None else f"{value:+.2f}"


def sweep(values: np.ndarray, tables: dict, param_label: str, runs: int, path: Path,
          reference_value: float | None = None) -> Path:
    """One row of panels per metric (mean over runs with 1-sigma error bars, log scale) against a swept
    parameter, one column per case.

    ``tables[metric label][case][filter]`` is a list of ``{mean, std}``, one per value.
    """
    plt = pyplot()
    metrics = list(tables)
    cases = list(tables[metrics[0]])
    fig, axes = plt.subplots(len(metrics), len(cases), figsize=(7.0 * len(cases), 4.2 * len(metrics)),
                             squeeze=False, layout="constrained")
    for row, metric in enumerate(metrics):
        for ax, case in zip(axes[row], cases):
            for name, rows in tables[metric][case].items():
                mean = np.array([np.nan if r["mean"] is None else r["mean"] for r in rows])
                std = np.array([np.nan if r["std"] is None else r["std"] for r in rows])
                ax.errorbar(values, mean, yerr=std, fmt="o" + style(name), color=colour(name), label=name,
                            ms=4, lw=1.3, capsize=3)
            if reference_value is not None:
                ax.axvline(reference_value, color="k", ls=":", lw=0.8, label="Table 1 setting")
            ax.set_yscale("log")
            ax.set_xlabel(param_label)
            ax.set_ylabel(f"{metric}, mean +- std")
            ax.set_title(CASE_TITLES.get(case, case), fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
    _shared_legend(fig, axes[0][0])
    fig.suptitle(f"Against {param_label.split(' (')[0]}, {runs} Monte Carlo runs per point")
    return save(fig, path)


def stress(conditions: dict, prior: list, runs: int, path: Path) -> Path:
    """The stress campaign: mean position RMSE (bars; dots: median) and mean NEES per condition and
    filter, and the mean position RMSE against the prior size (a third panel, only with a sweep).

    ``conditions[name] = (label, {filter: row})`` and ``prior = [(scale, {filter: row}), ...]`` with the
    rows of :func:`gpf_nav.experiments.stress.summarise` (metres).
    """
    plt = pyplot()
    names = list(conditions)
    filters = list(next(iter(conditions.values()))[1])
    ratios = [2.2, 2.2, 1.2] if prior else [2.2, 2.2]
    fig, axes = plt.subplots(1, len(ratios), figsize=(21.0 * sum(ratios) / 5.6, 5.2), layout="constrained",
                             gridspec_kw={"width_ratios": ratios})
    width = 0.8 / len(filters)
    x = np.arange(len(names))

    def value(row, key):
        return np.nan if row[key] is None else row[key]

    for i, name in enumerate(filters):
        offset = x - 0.4 + (i + 0.5) * width
        rows = [conditions[c][1][name] for c in names]
        look = {"color": colour(name), "hatch": None if style(name) == "-" else "//", "edgecolor": "white"}
        axes[0].bar(offset, [value(r, "position_rmse_mean") for r in rows], width, label=name, **look)
        axes[0].plot(offset, [value(r, "position_rmse_median") for r in rows], "k.", ms=4)
        axes[1].bar(offset, [value(r, "nees_mean") for r in rows], width, **look)
        if prior:
            scales = [p[0] for p in prior]
            axes[2].plot(scales, [value(p[1][name], "position_rmse_mean") for p in prior], "o" + style(name),
                         color=colour(name), lw=1.3, ms=4)
    for ax, ylabel in ((axes[0], "position RMSE (m): bar mean, dot median"), (axes[1], "mean NEES (6 states)")):
        ax.set_xticks(x, [conditions[c][0] for c in names], rotation=25, ha="right", fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", axis="y", alpha=0.3)
    axes[1].axhspan(2.0, 15.0, color="0.85", zorder=0, label="2-15")
    axes[1].axhline(6.0, color="k", ls=":", lw=0.8)
    if prior:
        axes[2].set_xscale("log")
        axes[2].set_yscale("log")
        axes[2].set_xlabel("prior size s: position sigma s km, velocity sigma s m/s")
        axes[2].set_ylabel("mean position RMSE (m)")
        axes[2].set_title("prior-size sweep", fontsize=10)
        axes[2].grid(True, which="both", alpha=0.3)
    _shared_legend(fig, axes[0], columns=len(filters))
    fig.suptitle(f"Stress campaign: {runs} runs per condition, the same runs for every filter "
                 f"(NEES: grey band 2-15, dotted line 6)")
    return save(fig, path)


def estimate_errors(times: np.ndarray, errors: np.ndarray, sigmas: np.ndarray, title: str, path: Path) -> Path:
    """Per-axis error of one run against truth with the filter's 3-sigma bounds.

    ``times`` ``(K,)`` s, ``errors`` and ``sigmas`` ``(K, 6)`` (estimate - truth and the filter's standard
    deviations of ``x, y, z`` in m and ``vx, vy, vz`` in m/s). Top row position, bottom row velocity.
    """
    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(14.0, 6.5), sharex=True, layout="constrained")
    labels = [("x", "m"), ("y", "m"), ("z", "m"), ("vx", "m/s"), ("vy", "m/s"), ("vz", "m/s")]
    for i, ax in enumerate(axes.reshape(-1)):
        name, unit = labels[i]
        ax.fill_between(times, -3 * sigmas[:, i], 3 * sigmas[:, i], color="#1f77b4", alpha=0.2, lw=0,
                        label="±3σ (filter)")
        ax.plot(times, errors[:, i], color="#d62728", lw=0.9, label="estimate - truth")
        inside = np.mean(np.abs(errors[:, i]) <= 3 * sigmas[:, i]) if len(times) else np.nan
        ax.set_title(f"{name}: {100 * inside:.0f} % of updates within 3σ", fontsize=9)
        ax.set_ylabel(f"{name} error ({unit})")
        ax.grid(True, alpha=0.3)
        if i >= 3:
            ax.set_xlabel("time since the first update (s)")
    axes[0][0].legend(fontsize=8, loc="upper right")
    fig.suptitle(title)
    return save(fig, path)
