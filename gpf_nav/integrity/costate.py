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
* ``b_1 .. b_B`` = reference window means: the older samples cut into consecutive blocks of
  ``window + gap``, each averaged over its last ``window`` samples (the first ``gap`` are a guard), the
  last ``B <= reference`` blocks kept; ``gap`` samples also separate the test window from the reference;
* ``S`` = sample covariance of the ``b_j`` about their own mean (``nu = B - 1`` dof);
* ``T^2 = m^T S^-1 m``. If the window means are independent ``N(0, Sigma)`` (H0), ``nu S`` is
  Wishart(``Sigma``, ``nu``) independent of ``m``, and ``(nu - p + 1) / (p nu) T^2 ~ F(p, nu - p + 1)``:
  the p-value is exact whatever ``Sigma`` is.

Centring the reference on its own mean keeps the scale right when the co-state is biased from the start
(a mismatch present from t = 0 is still tested against zero with a clean scale).

Serial correlation. Consecutive co-states are correlated: the default GPF's co-state is close to a first
difference of the measurement noise (lag-1 autocorrelation about -0.5), the bootstrap PF's is positively
correlated. The test and reference means average the same number of consecutive samples, so ``S`` is the
variance of a *window mean* of the correlated process (a differenced noise telescopes inside a window;
the reference means see exactly that), and the ``gap`` makes the window means independent for any process
whose memory is shorter than ``gap`` samples, nearly so when the memory is short against ``window``. No
model of the correlation is needed. The limit: a correlation time comparable with ``window`` (an AR(1)
with ``phi = 0.9``, ``(1 + phi) / (1 - phi) = 19`` samples, against ``window = 10``) makes the window
means correlated and the false-alarm rate too high (2.7e-3 for a set 1e-3; docs/integrity.md).

Quarantine. The samples of a test window whose p-value is below ``quarantine_rate`` (default
``false_alarm_rate / 100``) never enter the reference: a clear fault does not inflate its own yardstick,
so a persistent fault stays ``FAULT``.

Missing data. A sample whose measured components are not all finite is ignored and counted
(:attr:`CostateMonitor.rejected`); a sample with no measured component is ignored and counted
(:attr:`CostateMonitor.unmeasured`). Samples are used in arrival order (a skipped sample leaves no hole).
The test uses the components measured in *every* sample of the test window and of every reference window
(e.g. range and elevation in the partial-observability case); a component measured only intermittently is
left out until it has been measured throughout. Until ``min_reference`` reference windows exist the monitor
is not ready: level ``OK``, ``statistic`` NaN, ``p_value`` 1, ``ready`` False.

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


@dataclass(frozen=True)
class _Reference:
    """Whitening of the reference window means: ``T^2 = |W (m / scale)|^2`` over the kept components."""

    keep: np.ndarray      # (p0,) bool: components with non-zero reference variance
    scale: np.ndarray     # (k,) their standard deviations
    whiten: np.ndarray    # (p, k) rows eigvec^T / sqrt(eigval) of the correlation, numerically non-zero
    p: int
    nu: int


def _reference(reference_means: np.ndarray) -> _Reference | None:
    B = reference_means.shape[0]
    nu = B - 1
    if nu < 1:
        return None
    centred = reference_means - reference_means.mean(axis=0)
    scale = np.sqrt(np.einsum("ij,ij->j", centred, centred) / nu)
    keep = scale > 0.0
    if not keep.any():
        return None
    z_ref = centred[:, keep] / scale[keep]
    eigval, eigvec = np.linalg.eigh(z_ref.T @ z_ref / nu)
    good = eigval > 1e-10 * eigval[-1]
    p = int(good.sum())
    if nu - p + 1 < 1:
        return None
    whiten = eigvec[:, good].T / np.sqrt(eigval[good])[:, None]
    return _Reference(keep, scale[keep], whiten, p, nu)


def _t2(test_mean: np.ndarray, ref: _Reference) -> tuple[float, float]:
    u = ref.whiten @ (test_mean[ref.keep] / ref.scale)
    t2 = float(u @ u)
    f = (ref.nu - ref.p + 1) / (ref.p * ref.nu) * t2
    return t2, float(special.fdtrc(ref.p, ref.nu - ref.p + 1, f))


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
    ref = _reference(reference_means)
    if ref is None:
        return math.nan, 1.0, 0, reference_means.shape[0] - 1
    t2, p_value = _t2(np.asarray(test_mean, dtype=float), ref)
    return t2, p_value, ref.p, ref.nu


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
        quarantine_rate: p-value below which the samples of the test window and its guard are kept out
            of the reference (default ``false_alarm_rate / 100``; 0 disables the quarantine).

    The newest ``window + gap`` samples are the test window (the last ``window``) and the guard before
    it. Older samples go to the reference, in consecutive blocks of ``window + gap`` whose last
    ``window`` samples are averaged (the reference window means; the reference keeps the last
    ``reference`` of them). A sample that was among the newest ``window + gap`` at a test with
    ``p_value < quarantine_rate`` is *quarantined* (never enters the reference), so a clear fault does
    not inflate the scale it is measured against: a persistent fault stays ``FAULT``, and a transient one
    does not blind the monitor afterwards. The quarantine threshold is far below the FAULT one on
    purpose: quarantining every FAULT would keep the most extreme H0 windows out of the reference,
    shrink its spread and raise the false-alarm rate above ``false_alarm_rate``. The monitor is ready after
    ``(min_reference + 1) * (window + gap)`` accepted samples (defaults: 84, i.e. 168 s at the lunar
    scenario's 2 s step) and remembers at most ``(reference + 2) * (window + gap)`` (264, 528 s).
    """

    def __init__(self, window: int = 10, reference: int = 20, min_reference: int = 6, gap: int = 2,
                 false_alarm_rate: float = 1e-3, warn_false_alarm_rate: float = 1e-2,
                 quarantine_rate: float | None = None):
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
        self.quarantine_rate = (self.false_alarm_rate / 100.0 if quarantine_rate is None
                                else float(quarantine_rate))
        if not 0.0 <= self.quarantine_rate <= self.false_alarm_rate:
            raise ValueError("need 0 <= quarantine_rate <= false_alarm_rate")
        self.stride = window + gap
        self.reset()

    def reset(self) -> None:
        """Forget every sample and counter (e.g. after a filter re-initialisation)."""
        self._dim: int | None = None
        self._recent: np.ndarray | None = None       # (stride, m) newest samples, oldest first
        self._recent_mask: np.ndarray | None = None
        self._tainted = np.zeros(self.stride, dtype=bool)
        self._n_recent = 0
        self._block_sum: np.ndarray | None = None    # block being filled from the admitted samples
        self._block_mask: np.ndarray | None = None
        self._block_count = 0
        self._means: list[np.ndarray] = []           # completed reference window means, oldest first
        self._masks: list[np.ndarray] = []
        self._cache: tuple | None = None             # (components, _Reference) of the current blocks
        self._count = 0
        self.rejected = 0     # samples ignored: a measured component not finite
        self.unmeasured = 0   # samples ignored: nothing measured
        self.quarantined = 0  # samples kept out of the reference (p_value < quarantine_rate)
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

    @property
    def reference_means(self) -> np.ndarray:
        """The reference window means ``(B, m)`` now in use, oldest first (0 for unmeasured)."""
        return np.array(self._means).reshape(len(self._means), -1)

    # --- the test --------------------------------------------------------------------------------------
    def update(self, costate_mean, measured=None) -> IntegrityStatus:
        """Add one co-state sample and test.

        Args:
            costate_mean: weighted mean co-state ``(m,)`` of the filter's last update.
            measured: ``(m,)`` bool, the components measured at that update (default: the finite ones).
                Unmeasured components are ignored whatever their value.

        Returns:
            The new :class:`IntegrityStatus` (also :attr:`status`). Never raises on NaN/inf: the sample
            is ignored and counted, and the previous status is returned. Raises ValueError only on a
            shape error (``measured`` not of the co-state's shape, or the dimension changing).
        """
        x = np.array(costate_mean, dtype=float).reshape(-1)
        if measured is None:
            mask = np.isfinite(x)
        else:
            mask = np.array(measured, dtype=bool).reshape(-1)
            if mask.shape != x.shape:
                raise ValueError(f"measured must have shape {x.shape}, got {mask.shape}")
        if self._dim is None:
            self._allocate(x.size)
        elif x.size != self._dim:
            raise ValueError(f"co-state dimension changed from {self._dim} to {x.size}")
        if not mask.any():
            self.unmeasured += 1
            return self._status
        if not np.all(np.isfinite(x[mask])):
            self.rejected += 1
            return self._status
        x = np.where(mask, x, 0.0)
        if self._n_recent == self.stride:  # the oldest recent sample leaves: to the reference or out
            if self._tainted[0]:
                self.quarantined += 1
            else:
                self._admit(self._recent[0], self._recent_mask[0])
            self._recent[:-1] = self._recent[1:]
            self._recent_mask[:-1] = self._recent_mask[1:]
            self._tainted[:-1] = self._tainted[1:]
            self._n_recent -= 1
        self._recent[self._n_recent] = x
        self._recent_mask[self._n_recent] = mask
        self._tainted[self._n_recent] = False
        self._n_recent += 1
        self._count += 1
        self._status = self._test()
        if self._status.p_value < self.quarantine_rate:
            self._tainted[:] = True
        return self._status

    def _allocate(self, m: int) -> None:
        self._dim = m
        self._recent = np.zeros((self.stride, m))
        self._recent_mask = np.zeros((self.stride, m), dtype=bool)
        self._block_sum = np.zeros(m)
        self._block_mask = np.ones(m, dtype=bool)

    def _admit(self, x: np.ndarray, mask: np.ndarray) -> None:
        """Add one sample to the reference block being filled; close the block when full."""
        if self._block_count >= self.gap:  # the first ``gap`` samples of a block are the guard
            self._block_sum += x
            self._block_mask &= mask
        self._block_count += 1
        if self._block_count == self.stride:
            self._means.append(self._block_sum / self.window)
            self._masks.append(self._block_mask)
            if len(self._means) > self.reference:
                del self._means[0], self._masks[0]
            self._block_sum = np.zeros(self._dim)
            self._block_mask = np.ones(self._dim, dtype=bool)
            self._block_count = 0
            self._cache = None

    def _test(self) -> IntegrityStatus:
        if self._n_recent < self.stride or len(self._means) < self.min_reference:
            return _NOT_READY
        measured = self._recent_mask.all(axis=0)
        if self._cache is None or not np.array_equal(self._cache[0], measured):
            components = np.flatnonzero(measured & np.logical_and.reduce(self._masks))
            ref = _reference(np.array(self._means)[:, components]) if components.size else None
            self._cache = (measured, components, ref)
        _, components, ref = self._cache
        if ref is None:
            return _NOT_READY
        t2, p_value = _t2(self._recent[self.gap:, components].mean(axis=0), ref)
        if p_value < self.false_alarm_rate:
            level = "FAULT"
        elif p_value < self.warn_false_alarm_rate:
            level = "WARN"
        else:
            level = "OK"
        return IntegrityStatus(level, t2, t2_threshold(ref.p, ref.nu, self.false_alarm_rate), p_value, True,
                               tuple(components[ref.keep].tolist()))


__all__ = ["CostateMonitor", "IntegrityStatus", "hotelling_t2", "t2_threshold", "LEVELS"]
