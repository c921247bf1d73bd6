"""Start-up: what the filter is (re-)initialised from.

First match wins: the ``initial_state`` parameter (at ``initial_stamp``, or at the first measurement when
that is negative); a ``set_state`` (full state) or ``set_pose`` (position) message; else the first
``init_window`` measurements of the model's own through
:func:`gpf_nav.estimator.initialization.batch_initial_state` (a fit that does not determine the state slides
the window by one). A ``set_state`` or ``set_pose`` that comes while measurements are buffered for that fit
(say the latched prior, delivered just after the first live measurement) is not stale: the filter starts
from it and then takes the buffered measurements stamped at or after it. The last initial state from one of
:data:`PRIOR_SOURCES` is kept as the prior a re-initialisation after a persistent integrity FAULT may start
from (:mod:`gpf_nav.estimator.integrity_watch`).
"""
from __future__ import annotations

import numpy as np

from gpf_nav.estimator.engine_config import EngineConfig
from gpf_nav.estimator.initialization import batch_initial_state
from gpf_nav.models.state_space import StateSpaceModel

PRIOR_SOURCES = ("parameters", "set_state", "set_pose", "measurements")
"""Initialisations kept as the prior a ``fault_action: prior`` starts again from."""


class StartUp:
    """The initial states: the parameters', a pose's, the batch fit's, and the last one (the prior).

    Attributes:
        source: where the filter's current initial state came from (one of :data:`PRIOR_SOURCES`,
            ``"recovery"`` or ``"prior"``; ``""`` before the first).
        prior: ``(mean (n,), cov (n, n), t_ns)`` of the last initial state from :data:`PRIOR_SOURCES`
            (None: none since the last full reset).
        buffer: ``(stamp_ns, y (m,))`` of the measurements waiting for the batch fit.
        fit_failures: batch fits that did not determine the state.
    """

    def __init__(self, config: EngineConfig, model: StateSpaceModel):
        self.config = config
        self.model = model
        self.reset(from_data=False)

    def reset(self, from_data: bool) -> None:
        """Back to the start-up state; ``from_data``: the next initial state is the batch fit's even when an
        ``initial_state`` is configured (the prior is then kept)."""
        self._from_data = from_data
        if not from_data:
            self.prior: tuple[np.ndarray, np.ndarray, int] | None = None
        self.buffer: list[tuple[int, np.ndarray]] = []
        self.fit_failures = 0
        self.source = ""

    @property
    def fits_data(self) -> bool:
        """Whether the next initial state is the batch fit of measurements (rather than ``initial_state``)."""
        return self.config.initial_state is None or self._from_data

    @property
    def window(self) -> int:
        """Measurements of a batch fit (``init_window``, at least two)."""
        return max(2, int(self.config.init_window))

    def parameters(self) -> tuple[np.ndarray, np.ndarray]:
        """The ``initial_state`` parameter ``(n,)`` and its covariance ``(n, n)`` (``initial_std``)."""
        return self.config.initial_state, np.diag(self.config.initial_std ** 2)

    def parameters_stamp_ns(self) -> int | None:
        """The stamp at which the filter starts from the parameters without waiting for a measurement
        (``initial_stamp``; None: it waits)."""
        if self.fits_data or self.config.initial_stamp < 0.0:
            return None
        return int(round(self.config.initial_stamp * 1e9))

    def started(self, mean: np.ndarray, cov: np.ndarray, t_ns: int, source: str) -> None:
        """The filter started from ``mean`` ``(n,)``, ``cov`` ``(n, n)`` at ``t_ns`` (from ``source``)."""
        self.source = source
        if source in PRIOR_SOURCES:
            self.prior = (np.array(mean, dtype=float), np.array(cov, dtype=float), int(t_ns))
        self._from_data = False
        self.buffer = []

    def fit(self, stamp_ns: int, y: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Buffer the model's measurement ``y`` ``(m,)`` stamped ``stamp_ns``; once :attr:`window` are
        buffered, their batch fit ``(mean (n,), cov (n, n))`` at ``stamp_ns``. None while it waits for more."""
        self.buffer.append((stamp_ns, y))
        window = self.window
        if len(self.buffer) < window:
            return None
        times = np.array([t for t, _ in self.buffer], dtype=np.int64)
        ys = np.array([v for _, v in self.buffer])
        seconds = (times - times[0]) * 1e-9
        fit = None
        if seconds[-1] > 0.0:
            try:
                fit = batch_initial_state(self.model, seconds, ys)
            except Exception:  # noqa: BLE001 - a failed fit just waits for more data
                fit = None
        if fit is None:
            self.fit_failures += 1
            self.buffer = self.buffer[-(window - 1):]  # slide the window
        return fit

    def buffered_since(self, stamp_ns: int) -> list[tuple[int, np.ndarray]]:
        """The buffered measurements stamped at or after ``stamp_ns`` (what a state given then takes)."""
        return [(t, y) for t, y in self.buffer if t >= stamp_ns]

    def pose(self, position: np.ndarray, position_cov: np.ndarray | None,
             estimate: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray] | None:
        """The state ``(mean (n,), cov (n, n))`` of a ``set_pose``: ``position`` ``(p,)`` with
        ``position_cov`` ``(p, p)`` (None: ``initial_std``'s), the velocity of ``estimate`` ``(mean (n,),
        cov (n, n))`` at the pose's stamp, else of the ``initial_state`` parameter; None when neither is
        there."""
        p, v = list(self.model.position_index), list(self.model.velocity_index)
        mean = np.zeros(self.model.state_dim)
        cov = np.diag(self.config.initial_std ** 2)
        if estimate is not None:
            mean[v] = estimate[0][v]
            cov[np.ix_(v, v)] = estimate[1][np.ix_(v, v)]
        elif self.config.initial_state is not None:
            mean[v] = np.asarray(self.config.initial_state)[v]
        else:
            return None
        mean[p] = position
        if position_cov is not None:
            cov[np.ix_(p, p)] = position_cov
        return mean, cov

    def waiting_for(self) -> str:
        """What the uninitialised filter waits for, in words (for the node's periodic warning)."""
        text = f"waiting for set_state, set_pose or measurements ({len(self.buffer)}/{self.window} buffered)"
        if self.fit_failures:
            text += (f"; the batch fit failed {self.fit_failures} times: it needs at least two "
                     "measurements with range, azimuth and elevation (set initial_state or send set_pose)")
        return text
