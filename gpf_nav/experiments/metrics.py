"""Error metrics of the Monte Carlo experiments: RMSE, NEES and its chi-square band, summaries, tests.

Everything here works on plain numpy arrays and is unit-tested against hand-computed cases
(``test/test_metrics.py``). Conventions:

* an *error* is ``estimate - truth`` of one state block (position or velocity), shaped ``(K, d)``;
* the RMSE of a run is ``sqrt(mean_k |e_k|^2)``, the root of the time average of the squared error norm
  (for a position block this is the 3-D position RMSE the paper's Table 1 reports);
* the NEES of step ``k`` is ``e_k^T P_k^-1 e_k`` with the full state error and covariance; it is NaN where
  ``P_k`` is not positive definite (a filter claiming zero uncertainty has no finite NEES);
* summaries over Monte Carlo runs are ``{mean, std}`` with the sample standard deviation (``ddof=1``),
  over the finite values only.
"""
from __future__ import annotations

import math

import numpy as np


def error_norms(estimates: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Euclidean norm of ``estimates - truth`` per row: ``(K, d), (K, d) -> (K,)``."""
    e = np.asarray(estimates, dtype=float) - np.asarray(truth, dtype=float)
    return np.sqrt(np.einsum("ij,ij->i", e, e))


def rmse(norms: np.ndarray) -> float:
    """Root mean square of error norms ``(K,)``: ``sqrt(mean(norms**2))``; NaN if any is non-finite."""
    norms = np.asarray(norms, dtype=float)
    if norms.size == 0:
        raise ValueError("rmse of an empty error series")
    return float(np.sqrt(np.mean(norms * norms)))


def nees(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared ``e_k^T P_k^-1 e_k`` per step.

    Args:
        errors: ``(K, n)`` estimate minus truth.
        covariances: ``(K, n, n)`` the filter's covariances.

    Returns:
        ``(K,)``; NaN at steps whose covariance is not positive definite or whose inputs are not finite.
    """
    errors = np.asarray(errors, dtype=float)
    covariances = np.asarray(covariances, dtype=float)
    if errors.ndim != 2 or covariances.shape != errors.shape + errors.shape[-1:]:
        raise ValueError(f"need errors (K, n) and covariances (K, n, n), got {errors.shape} and "
                         f"{covariances.shape}")
    finite = np.all(np.isfinite(errors), axis=1) & np.all(np.isfinite(covariances), axis=(1, 2))
    out = np.full(errors.shape[0], np.nan)
    if finite.all():
        try:  # one batched factorisation when every covariance is positive definite
            sym = 0.5 * (covariances + covariances.transpose(0, 2, 1))
            z = np.linalg.solve(np.linalg.cholesky(sym), errors[..., None])[..., 0]
            return np.einsum("ki,ki->k", z, z)
        except np.linalg.LinAlgError:
            pass
    for k in np.flatnonzero(finite):
        out[k] = nees_step(errors[k], covariances[k])
    return out


def not_positive_definite(covariances: np.ndarray) -> np.ndarray:
    """Which covariances ``(K, n, n)`` a consumer could not factor: ``(K,)`` bool, True where the matrix
    as given is non-finite or its Cholesky factorisation (of the lower triangle, numpy's) fails, i.e. it
    is singular or indefinite to working precision."""
    covariances = np.asarray(covariances, dtype=float)
    bad = ~np.all(np.isfinite(covariances), axis=(1, 2))
    try:  # one batched factorisation when every finite covariance is positive definite
        np.linalg.cholesky(covariances[~bad])
        return bad
    except np.linalg.LinAlgError:
        pass
    for k in np.flatnonzero(~bad):
        try:
            np.linalg.cholesky(covariances[k])
        except np.linalg.LinAlgError:
            bad[k] = True
    return bad


def nees_step(error: np.ndarray, covariance: np.ndarray) -> float:
    """NEES of one step, ``e^T P^-1 e`` via a Cholesky factor; NaN if ``P`` is not positive definite."""
    if not (np.all(np.isfinite(error)) and np.all(np.isfinite(covariance))):
        return math.nan
    try:
        factor = np.linalg.cholesky(0.5 * (covariance + covariance.T))
    except np.linalg.LinAlgError:
        return math.nan
    z = np.linalg.solve(factor, error)
    return float(z @ z)


def chi2_band(dof: int, runs: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` band of the average of ``runs`` independent chi-square(``dof``) values.

    For a consistent filter the NEES averaged over ``runs`` Monte Carlo runs at one time step is
    ``chi2(dof * runs) / runs``; the band is its ``(1 - p) / 2`` and ``(1 + p) / 2`` quantiles
    (Bar-Shalom, Li and Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 5.4.2).
    """
    from scipy.stats import chi2

    if dof < 1 or runs < 1 or not 0.0 < probability < 1.0:
        raise ValueError("need dof >= 1, runs >= 1 and 0 < probability < 1")
    alpha = 1.0 - probability
    total = dof * runs
    return float(chi2.ppf(alpha / 2.0, total) / runs), float(chi2.ppf(1.0 - alpha / 2.0, total) / runs)


def fraction_in_band(values: np.ndarray, band: tuple[float, float]) -> float:
    """Fraction of the finite ``values`` inside the closed ``band``; NaN if none is finite."""
    values = np.asarray(values, dtype=float)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return math.nan
    return float(np.mean((finite >= band[0]) & (finite <= band[1])))


def time_average(series: np.ndarray) -> float:
    """Mean of the finite entries of a time series ``(K,)``; NaN if none is finite."""
    series = np.asarray(series, dtype=float)
    finite = series[np.isfinite(series)]
    return float(finite.mean()) if finite.size else math.nan


def mean_std(values) -> dict:
    """``{"mean", "std", "n"}`` of the finite values (sample std, ``ddof=1``; 0 for a single value).

    ``mean`` and ``std`` are None when no value is finite (JSON has no NaN).
    """
    values = np.asarray(values, dtype=float).reshape(-1)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return {"mean": None, "std": None, "n": 0}
    std = float(finite.std(ddof=1)) if finite.size > 1 else 0.0
    return {"mean": float(finite.mean()), "std": std, "n": int(finite.size)}


def wilcoxon_p(a, b) -> float | None:
    """Two-sided p-value of the paired Wilcoxon signed-rank test of ``a`` against ``b``.

    ``a[i]`` and ``b[i]`` must come from the same Monte Carlo run (paired samples); pairs where either
    value is non-finite are dropped. Returns 1.0 when every paired difference is zero (no evidence of
    a difference) and None when fewer than one finite pair remains.
    """
    from scipy.stats import wilcoxon

    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"paired samples need equal 1-D shapes, got {a.shape} and {b.shape}")
    keep = np.isfinite(a) & np.isfinite(b)
    a, b = a[keep], b[keep]
    if a.size == 0:
        return None
    if np.all(a == b):
        return 1.0
    return float(wilcoxon(a, b, zero_method="wilcox", alternative="two-sided").pvalue)


def correlation(x, y) -> float | None:
    """Pearson correlation of the finite pairs; None when undefined (fewer than 3 pairs, or constant)."""
    x = np.asarray(x, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float).reshape(-1)
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    if x.size < 3:
        return None
    dx, dy = x - x.mean(), y - y.mean()
    denominator = math.sqrt(float(dx @ dx) * float(dy @ dy))
    if denominator == 0.0 or not math.isfinite(denominator):
        return None
    return float(dx @ dy) / denominator


def rank_correlation(x, y) -> float | None:
    """Spearman rank correlation of the finite pairs (Pearson of average ranks); None when undefined."""
    from scipy.stats import rankdata

    x = np.asarray(x, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float).reshape(-1)
    keep = np.isfinite(x) & np.isfinite(y)
    if keep.sum() < 3:
        return None
    return correlation(rankdata(x[keep]), rankdata(y[keep]))
