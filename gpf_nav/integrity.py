"""Estimator-integrity monitor on the geometric co-state (no ROS).

The paper (Section 3.5, Theorem "Nominal consistency of the geometric co-state") shows that under a
correct model ``E[lambda_t | F^y_t] = 0``: a co-state whose mean stays away from zero means that the
dynamics, the measurement model or the estimator itself disagree with the data. :class:`CostateMonitor`
turns that into a test with a set false-alarm rate, fed one weighted-mean co-state per filter update::

    monitor = CostateMonitor()
    for y in measurements:
        flt.predict(dt); flt.update(y)
        status = monitor.update(flt.costate_mean, np.isfinite(y))
        status.level          # "OK" | "WARN" | "FAULT"

The statistic is *self-normalised*: it never uses the filter's covariance (the GPF's cloud collapses onto
the measurement and its covariance is overconfident) nor the co-state's nominal scale. It compares the
mean co-state of the latest ``window`` samples with the spread of the means of earlier windows of the same
length (batch means), with a Hotelling ``T^2`` test:

* ``m`` = mean of the last ``window`` samples (the test window), ``(p,)``;
* ``b_1 .. b_B`` = means of the ``B`` preceding windows of ``window`` samples, each separated from the
  next (and the first from the test window) by ``gap`` skipped samples; ``S`` their sample covariance;
* ``T^2 = m^T S^-1 m``. If the window means are independent ``N(0, Sigma)`` (H0), ``(B - 1) S`` is
  Wishart(``Sigma``, ``B - 1``) independent of ``m``, and ``(nu - p + 1) / (p nu) T^2 ~ F(p, nu - p + 1)``
  with ``nu = B - 1``: the p-value is exact whatever ``Sigma`` is.

Serial correlation. Consecutive co-states are correlated: the default GPF's co-state is close to a first
difference of the measurement noise (lag-1 autocorrelation about -0.5), the bootstrap PF's is positively
correlated. Both batch means share the same within-window correlation, so the scale ``S`` is the variance
of a *window mean* of the correlated process (a differenced noise telescopes inside a window; the batch
means see exactly that); the ``gap`` makes consecutive window means independent for any process whose
memory is shorter than ``gap`` samples, and nearly so when the memory is short against ``window``.
The test is therefore calibrated for short-memory stationary co-states, with no model of the correlation.

Missing data. A sample whose measured components are not all finite is ignored and counted
(:attr:`CostateMonitor.rejected`); a sample with no measured component is ignored and counted
(:attr:`CostateMonitor.unmeasured`). Samples are buffered in arrival order (a skipped sample leaves no
hole). The test uses the components measured in *every* buffered sample it uses (e.g. range and elevation
in the partial-observability case); a component measured only intermittently is left out until it has
been measured throughout the span. Until ``min_reference`` reference windows are available the monitor is
not ready: level ``OK``, ``statistic`` NaN, ``p_value`` 1.

The level is instantaneous (no latching): ``FAULT`` when ``p_value < false_alarm_rate``, ``WARN`` when
``p_value < warn_false_alarm_rate``, else ``OK``. Under H0 the probability that a given (ready) step is
``FAULT`` is ``false_alarm_rate``; consecutive steps share most of their data, so alarms come in runs.
See docs/integrity.md for the derivation, the parameters and the measured lunar figures.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np
from scipy import special, stats

LEVELS = ("OK", "WARN", "FAULT")


@dataclass(frozen=True)
class IntegrityStatus:
    """Result of one :meth:`CostateMonitor.update`.

    Attributes:
        level: ``"OK"``, ``"WARN"`` or ``"FAULT"`` (``"OK"`` while not ready).
        statistic: Hotelling ``T^2`` of the test-window mean co-state (NaN while not ready).
        threshold: the ``T^2`` above which the level is ``FAULT`` (NaN while not ready).
        p_value: probability under H0 of a ``T^2`` at least this large (1 while not ready).
        ready: whether a test was made (enough samples and reference windows).
        components: indices of the co-state components tested.
    """

    level: str
    statistic: float
    threshold: float
    p_value: float
    ready: bool = False
    components: tuple[int, ...] = ()

    def to_dict(self) -> dict:
        """Plain dict (e.g. for ``diagnostic_msgs/KeyValue`` pairs)."""
        out = asdict(self)
        out["components"] = list(self.components)
        return out


_NOT_READY = IntegrityStatus("OK", math.nan, math.nan, 1.0, False, ())


@lru_cache(maxsize=512)
def t2_threshold(p: int, nu: int, alpha: float) -> float:
    """``T^2`` exceeded with probability ``alpha`` under H0 (``p`` components, ``nu`` reference dof)."""
    return p * nu / (nu - p + 1) * float(stats.f.isf(alpha, p, nu - p + 1))


def hotelling_t2(test_mean: np.ndarray, reference_means: np.ndarray) -> tuple[float, float, int, int]:
    """One-sample Hotelling test of ``test_mean`` ``(p,)`` against zero, scale from ``reference_means``.

    ``reference_means`` ``(B, p)`` are independent draws with the covariance of ``test_mean``; their
    sample covariance (about their own mean, ``nu = B - 1`` dof) is the scale. Components with zero
    reference variance are dropped, and so are directions of numerically zero variance (the rank is the
    test's dimension).

    Returns:
        ``(T^2, p_value, p, nu)``; ``(nan, 1.0, 0, nu)`` if nothing can be tested (``nu < p``).
    """
    reference_means = np.asarray(reference_means, dtype=float)
    test_mean = np.asarray(test_mean, dtype=float)
    B = reference_means.shape[0]
    nu = B - 1
    if nu < 1:
        return math.nan, 1.0, 0, nu
    centred = reference_means - reference_means.mean(axis=0)
    scale = np.sqrt(np.einsum("ij,ij->j", centred, centred) / nu)
    keep = scale > 0.0
    if not keep.any():
        return math.nan, 1.0, 0, nu
    z_ref = centred[:, keep] / scale[keep]
    z = test_mean[keep] / scale[keep]
    corr = z_ref.T @ z_ref / nu
    eigval, eigvec = np.linalg.eigh(corr)
    good = eigval > 1e-10 * eigval[-1]
    p = int(good.sum())
    if nu - p + 1 < 1:
        return math.nan, 1.0, 0, nu
    proj = eigvec[:, good].T @ z
    t2 = float(np.sum(proj * proj / eigval[good]))
    f = (nu - p + 1) / (p * nu) * t2
    p_value = float(special.fdtrc(p, nu - p + 1, f))
    return t2, p_value, p, nu


class CostateMonitor:
    """Windowed batch-means Hotelling test of ``E[co-state] = 0`` (see the module docstring).

    Args:
        window: samples per window mean (the test window and each reference window). It should exceed
            the co-state's correlation time; it also sets how long a transient stays visible.
        reference: largest number of reference windows ``B`` (more: more power, slower adaptation).
        min_reference: reference windows needed before testing (at least ``m + 1`` for ``m`` components;
            the F distribution keeps the false-alarm rate right for any ``B``, few windows cost power).
        gap: samples skipped between consecutive windows (decorrelation guard).
        false_alarm_rate: per-step probability of ``FAULT`` under H0.
        warn_false_alarm_rate: per-step probability of ``WARN`` or worse under H0 (>= false_alarm_rate).

    The buffer holds ``window + reference * (window + gap)`` samples; the monitor is ready after
    ``window + min_reference * (window + gap)`` accepted samples (defaults: 250 and 82, i.e. 500 s and
    164 s at the lunar scenario's 2 s step).
    """

    def __init__(self, window: int = 10, reference: int = 20, min_reference: int = 6, gap: int = 2,
                 false_alarm_rate: float = 1e-3, warn_false_alarm_rate: float = 1e-2):
        window, reference, min_reference, gap = int(window), int(reference), int(min_reference), int(gap)
        if window < 1 or gap < 0:
            raise ValueError("window must be >= 1 and gap >= 0")
        if not 2 <= min_reference <= reference:
            raise ValueError("need 2 <= min_reference <= reference")
        if not 0.0 < false_alarm_rate <= warn_false_alarm_rate < 1.0:
            raise ValueError("need 0 < false_alarm_rate <= warn_false_alarm_rate < 1")
        self.window = window
        self.reference = reference
        self.min_reference = min_reference
        self.gap = gap
        self.false_alarm_rate = float(false_alarm_rate)
        self.warn_false_alarm_rate = float(warn_false_alarm_rate)
        self.capacity = window + reference * (window + gap)
        self.reset()

    def reset(self) -> None:
        """Forget every sample and counter (e.g. after a filter re-initialisation)."""
        self._values: np.ndarray | None = None  # (2 * capacity, m): each sample written twice
        self._measured: np.ndarray | None = None
        self._count = 0      # samples accepted since reset
        self._head = 0       # next write position in [0, capacity)
        self.rejected = 0    # samples ignored: a measured component not finite
        self.unmeasured = 0  # samples ignored: nothing measured
        self._status = _NOT_READY

    # --- read-only state -------------------------------------------------------------------------------
    @property
    def status(self) -> IntegrityStatus:
        """Status of the last update."""
        return self._status

    @property
    def level(self) -> str:
        """Current level: ``"OK"``, ``"WARN"`` or ``"FAULT"``."""
        return self._status.level

    @property
    def samples(self) -> int:
        """Samples accepted since the last reset."""
        return self._count

    @property
    def ready(self) -> bool:
        """Whether the last update made a test."""
        return self._status.ready

    # --- the test --------------------------------------------------------------------------------------
    def update(self, costate_mean, measured=None) -> IntegrityStatus:
        """Add one co-state sample and test.

        Args:
            costate_mean: weighted mean co-state ``(m,)`` of the filter's last update.
            measured: ``(m,)`` bool, the components measured at that update (default: the finite ones).
                Unmeasured components are ignored whatever their value.

        Returns:
            The new :class:`IntegrityStatus` (also :attr:`status`). Never raises on NaN/inf: the sample
            is ignored and counted, and the previous status is returned.
        """
        x = np.array(costate_mean, dtype=float).reshape(-1)
        if measured is None:
            mask = np.isfinite(x)
        else:
            mask = np.array(measured, dtype=bool).reshape(-1)
            if mask.shape != x.shape:
                raise ValueError(f"measured must have shape {x.shape}, got {mask.shape}")
        if not mask.any():
            self.unmeasured += 1
            return self._status
        if not np.all(np.isfinite(x[mask])):
            self.rejected += 1
            return self._status
        if self._values is None or self._values.shape[1] != x.size:
            if self._values is not None:
                raise ValueError(f"co-state dimension changed from {self._values.shape[1]} to {x.size}")
            self._values = np.zeros((2 * self.capacity, x.size))
            self._measured = np.zeros((2 * self.capacity, x.size), dtype=bool)
        x = np.where(mask, x, 0.0)
        for pos in (self._head, self._head + self.capacity):
            self._values[pos] = x
            self._measured[pos] = mask
        self._head = (self._head + 1) % self.capacity
        self._count += 1
        self._status = self._test()
        return self._status

    def _test(self) -> IntegrityStatus:
        n = min(self._count, self.capacity)
        stride = self.window + self.gap
        n_ref = min(self.reference, (n - self.window) // stride)
        if n_ref < self.min_reference:
            return _NOT_READY
        used = self.window + n_ref * stride
        end = self._head + self.capacity  # one past the newest sample, in the doubled buffer
        values = self._values[end - used:end]
        measured = self._measured[end - used:end]
        # windows, newest last: reference windows at offsets 0, stride, ..., then the test window
        idx = np.arange(n_ref + 1)[:, None] * stride + np.arange(self.window)[None, :]
        windows = values[idx]                          # (n_ref + 1, window, m)
        components = np.flatnonzero(measured[idx].all(axis=(0, 1)))
        if components.size == 0:
            return _NOT_READY
        means = windows[:, :, components].mean(axis=1)  # (n_ref + 1, p)
        t2, p_value, p, nu = hotelling_t2(means[-1], means[:-1])
        if p == 0:
            return _NOT_READY
        if p_value < self.false_alarm_rate:
            level = "FAULT"
        elif p_value < self.warn_false_alarm_rate:
            level = "WARN"
        else:
            level = "OK"
        return IntegrityStatus(level, t2, t2_threshold(p, nu, self.false_alarm_rate), p_value, True,
                               tuple(int(c) for c in components))


__all__ = ["CostateMonitor", "IntegrityStatus", "hotelling_t2", "t2_threshold", "LEVELS"]
