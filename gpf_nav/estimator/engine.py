"""The estimator's logic without ROS: :class:`EstimatorEngine` runs one core filter on stamped inputs.

``estimator_node`` drives it; the node only converts messages, applies the message-level checks of
:mod:`gpf_nav.estimator.input_checks` and publishes. Times are integer nanoseconds of ROS time. A
measurement at stamp ``t`` runs ``predict((t - t_filter) s, u)`` then ``update(y, sensor)``, ``u`` the IMU
input held at ``t`` and ``sensor`` None the model's own measurement (rae, range). Stamps more than
``max_future`` s ahead of the node clock are refused (``future_stamp``), and so are measurements above
``max_measurement_rate`` (``rate_limit``). The engine is the flow of an input through its roles, each a
module with its rules:

* :mod:`~gpf_nav.estimator.startup`: what the filter is (re-)initialised from;
* :mod:`~gpf_nav.estimator.measurements`: the innovation gate, and late measurements fused at their stamp;
* :mod:`~gpf_nav.estimator.imu_hold`: the IMU input, and IMU samples that come late;
* :mod:`~gpf_nav.estimator.integrity_watch` and :mod:`~gpf_nav.estimator.consistency_watch`: the monitors
  fed at each update, and what a persistent integrity FAULT leads to;
* :mod:`~gpf_nav.estimator.extrapolation`: the estimate published between measurements.

If the filter raises or its mean/covariance become non-finite, it is rebuilt from the last good estimate
(covariance inflated by ``reinit_inflation``), predicted to the failing stamp, and the event is counted
(``reinit_count``; diagnostics go to ERROR for ``reinit_hold`` s). A re-initialisation the core filter does
by itself (its ``recoveries`` counter: all particles non-finite or weightless, ESS collapse with
``collapse_steps``) is counted and reported the same way, and so is one after a persistent integrity FAULT
(also in ``fault_reinit_count``).
"""
from __future__ import annotations

import time
from operator import attrgetter
from typing import Callable

import numpy as np

from gpf_nav.estimator.consistency_watch import ConsistencyReport, ConsistencyWatch
from gpf_nav.estimator.engine_config import NS, EngineConfig
from gpf_nav.estimator.extrapolation import Extrapolation
from gpf_nav.estimator.filter_figures import filter_stats, observability
from gpf_nav.estimator.history import Entry
from gpf_nav.estimator.imu_hold import ImuHold
from gpf_nav.estimator.input_checks import Counters, RateLimiter, check_timing
from gpf_nav.estimator.integrity_watch import IntegrityReport, IntegrityWatch
from gpf_nav.estimator.measurements import InnovationGate, LateFusion
from gpf_nav.estimator.startup import StartUp
from gpf_nav.filters.interface import COSTATE, Filter
from gpf_nav.integrity import ObservabilityReport
from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.sensors import Sensor


class EstimatorEngine:
    """Runs one core filter on stamped inputs. See the module docstring for the rules.

    Args:
        factory: builds a fresh, uninitialised filter (called at start, on reset and on recovery).
        model: the filter's model (``state_dim``, ``position_index``, ...).
        config: :class:`EngineConfig`.
        monotonic: steady clock [s] used by the rate limiter, the ERROR hold and the monitors' alarm holds.

    Attributes:
        filter: the core filter; ``t_ns`` its time (None: not initialised), ``mean`` ``(n,)`` and ``cov``
            ``(n, n)`` its last finite estimate, ``version`` bumped at every change of it.
        counters: accepted and refused inputs (:class:`Counters`; cumulative, like ``reinit_count``,
            ``fault_reinit_count`` and the monitors' counts).
        last_measurement_ns, last_update_ns: stamps of the newest accepted measurement and of the last
            update.
    """

    def __init__(self, factory: Callable[[], Filter], model: StateSpaceModel, config: EngineConfig,
                 monotonic: Callable[[], float] = time.monotonic):
        self.factory = factory
        self.model = model
        self.config = config
        self.monotonic = monotonic
        self.counters = Counters()
        self.reinit_count = 0
        self.last_reinit_reason = ""
        self._last_reinit_time = -np.inf
        self.fault_reinit_count = 0
        self._rate = RateLimiter(config.max_measurement_rate)
        self.startup = StartUp(config, model)
        self.gate = InnovationGate(config)
        self.fusion = LateFusion(config, step=self._step, restore=self._restore)
        self.imu_hold = ImuHold(config)
        self.integrity_watch = IntegrityWatch(config, self._now)
        self.consistency_watch = ConsistencyWatch(config, model, self._now)
        self.extrapolation = Extrapolation(config)
        self.reset()

    def reset(self, from_data: bool = False) -> None:
        """Back to the start-up state (counters are kept; they are cumulative); ``from_data``: initialise
        from the next measurements (the batch fit) even when an ``initial_state`` is configured."""
        self.startup.reset(from_data)
        self.filter = self.factory()
        self._core_recoveries = 0
        self.t_ns: int | None = None
        self.last_measurement_ns: int | None = None
        self.last_update_ns: int | None = None
        self.mean: np.ndarray | None = None
        self.cov: np.ndarray | None = None
        self.version = 0
        self._good: tuple[np.ndarray, np.ndarray, int] | None = None  # the last finite estimate and its stamp
        self.imu_hold.reset()
        self.fusion.reset()
        self.gate.streaks = {}
        self.extrapolation.drop()
        self._reset_monitors()
        self.consistency_watch.drop_alarm()
        t0_ns = self.startup.parameters_stamp_ns()
        if t0_ns is not None:
            self._start(*self.startup.parameters(), t0_ns, "parameters")

    # --- inputs ----------------------------------------------------------------------------------------
    def measurement(self, stamp_ns: int, y: np.ndarray, now_ns: int | None,
                    stream: str = "rae", sensor: Sensor | None = None) -> tuple[bool, str]:
        """Use measurement ``y`` ``(m,)`` (NaN = not measured) taken at ``stamp_ns`` by ``sensor`` (None: the
        model's own measurement).

        Returns ``(True, "")`` when the filter was updated (``mean``/``cov`` are then at the filter's
        time: ``stamp_ns``, or later for a late measurement), ``(True, "buffered")`` when it was kept
        for the initialisation, else ``(False, reason)``; the counters are updated either way.
        """
        self._apply_late_imu()
        last = None if self.initialized else self.last_measurement_ns
        ok, reason = check_timing(stamp_ns, last, now_ns, self._max_future_ns)
        late = ok and self.initialized and stamp_ns < self.t_ns
        if late:
            reason = self.fusion.refusal(self.t_ns, stamp_ns)
            ok = not reason
        if ok and not self._rate.allow(self.monotonic()):
            ok, reason = False, "rate_limit"
        if ok and late and not self.fusion.afford(self.t_ns, stamp_ns):
            ok, reason = False, "reapply_budget"
        if ok and not self.initialized and sensor is not None and self.startup.fits_data:
            ok, reason = False, "not_initialized"  # only the model's own measurements initialise
        if not ok:
            self.counters.reject(stream, reason)
            return False, reason
        y = np.asarray(y, dtype=float)
        self.counters.masked += int(np.sum(~np.isfinite(y)))
        self.last_measurement_ns = max(stamp_ns, self.last_measurement_ns or 0)
        if not self.initialized:
            if self.startup.fits_data:
                return self._buffer(stamp_ns, y, stream)
            self._start(*self.startup.parameters(), stamp_ns, "parameters")
        reason = self.fusion.fuse(stamp_ns, y, stream, sensor) if late else self._step(stamp_ns, y, stream, sensor)
        if reason:
            self.counters.reject(stream, reason)
            return False, reason
        self.counters.accept(stream)
        if self.integrity_watch.persistent_fault:
            self._act_on_fault()
        return True, ""

    def imu(self, stamp_ns: int, specific_force_world: np.ndarray, now_ns: int | None) -> tuple[bool, str]:
        """Hold a world-frame specific force ``(3,)`` [m/s^2] from ``stamp_ns`` on."""
        ok, reason = check_timing(stamp_ns, self.imu_hold.newest_ns, now_ns, self._max_future_ns)
        if not ok:
            self.counters.reject("imu", reason)
            return False, reason
        u = np.asarray(specific_force_world, dtype=float).copy()
        self.imu_hold.hold(stamp_ns, u)
        self.counters.accept("imu")
        if self.initialized and stamp_ns < self.t_ns:
            self.imu_hold.note_late(stamp_ns, u, self.fusion.history)
        else:
            self._apply_late_imu()  # caught up with the filter's time
        return True, ""

    def set_state(self, stamp_ns: int, mean: np.ndarray, cov: np.ndarray, now_ns: int | None) -> tuple[bool, str]:
        """(Re-)initialise at ``stamp_ns`` with a full state ``mean`` ``(n,)`` and covariance ``cov``
        ``(n, n)``: a state handed over (the simulator's prior; a vehicle's pre-descent state)."""
        ok, reason = self._check_reinit_timing("set_state", stamp_ns, now_ns)
        return self._reinitialize("set_state", stamp_ns, mean, cov) if ok else (ok, reason)

    def set_pose(self, stamp_ns: int, position: np.ndarray, position_cov: np.ndarray | None,
                 now_ns: int | None) -> tuple[bool, str]:
        """(Re-)initialise at ``stamp_ns`` with the given position ``(p,)``; velocity from the current
        estimate, else from the ``initial_state`` parameter. ``position_cov`` ``(p, p)`` None: ``initial_std``'s."""
        ok, reason = self._check_reinit_timing("set_pose", stamp_ns, now_ns)
        if not ok:
            return False, reason
        estimate = None
        if self.initialized and self.mean is not None:
            estimate = self.extrapolate(stamp_ns, force=True) if stamp_ns >= self.t_ns else None
            estimate = estimate if estimate is not None else (self.mean, self.cov)
        state = self.startup.pose(position, position_cov, estimate)
        if state is None:
            self.counters.reject("set_pose", "no_velocity")
            return False, "no_velocity"
        return self._reinitialize("set_pose", stamp_ns, *state)

    # --- the flow of an input --------------------------------------------------------------------------
    def _step(self, stamp_ns: int, y: np.ndarray, stream: str = "rae", sensor: Sensor | None = None,
              feed_monitors: bool = True) -> str:
        """Predict to ``stamp_ns`` and update with ``y`` ``(m,)``, keeping the input in the history: ``""``
        when updated, ``"innovation_gate"`` when the gate refused it (predicted only), ``"filter_error"``
        after a recovery. ``feed_monitors`` False: a re-applied input."""
        entry = self.fusion.entry(self.filter, self.t_ns, stamp_ns, stream, y, sensor, self.gate.streaks,
                                  self.imu_hold.extra_snapshot_due())
        try:
            dt = self._predict_to(stamp_ns)
            gated = self.gate.refuses(self.filter, stream, sensor, y)
            if not gated:
                if feed_monitors:
                    self.consistency_watch.test(self.filter, y, sensor)
                if sensor is None:
                    self.filter.update(y)
                else:
                    self.filter.update(y, sensor)
        except Exception as err:  # noqa: BLE001 - any filter failure means: recover, never crash the node
            self._recover(stamp_ns, f"filter raised {type(err).__name__}: {err}")
            return "filter_error"
        if not self._store(stamp_ns):
            self._recover(stamp_ns, "non-finite mean or covariance after the update")
            return "filter_error"
        self.fusion.keep(entry)
        if gated:
            return "innovation_gate"
        if not self._check_core_recovery() and feed_monitors and sensor is None:
            if not self.integrity_watch.feed(self.filter, dt):
                self._reset_monitors()
        self.last_update_ns = stamp_ns
        return ""

    def _predict_to(self, stamp_ns: int) -> float:
        """Predict the filter to ``stamp_ns`` with the IMU input held then; returns the step [s]."""
        dt = (stamp_ns - self.t_ns) * 1e-9
        if dt > 0.0:
            self.filter.predict(dt, self.imu_hold.input_at(stamp_ns))
        self.t_ns = stamp_ns
        return dt

    def _store(self, t_ns: int) -> bool:
        """Cache mean/covariance at ``t_ns``; False (and nothing stored) when they are not finite."""
        mean = np.array(self.filter.mean, dtype=float)
        cov = np.array(self.filter.covariance, dtype=float)
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            return False
        self.mean, self.cov = mean, cov
        self._good = (mean, cov, int(t_ns))
        self.version += 1
        return True

    def _restore(self, entry: Entry) -> None:
        """Put back the filter a history ``entry`` was applied to (its snapshot), at its time, with the gate
        streaks then."""
        self.filter, self.t_ns = entry.before, entry.before_ns
        self.gate.streaks = dict(entry.streaks)
        self._core_recoveries = self.filter.recoveries
        self.extrapolation.drop()

    def _apply_late_imu(self) -> None:
        """Re-apply the history from the earliest late IMU sample not yet applied, once for all of them."""
        stamp_ns = self.imu_hold.take_late()
        if stamp_ns is not None:
            self.fusion.reapply_from(stamp_ns)

    # --- start-up and recovery -------------------------------------------------------------------------
    def _start(self, mean: np.ndarray, cov: np.ndarray, t_ns: int, source: str) -> None:
        """Start a fresh filter from ``mean`` ``(n,)`` and ``cov`` ``(n, n)`` at ``t_ns``, every role with it."""
        fresh = self.factory()
        # the filter's time is the stamps' (s), the scale of moon_epoch: a station on the rotating
        # Moon and a field with tesseral terms turn with it
        fresh.initialize(mean, cov, t_ns * 1e-9)  # may raise: then nothing has changed
        self.filter = fresh
        self._core_recoveries = self.filter.recoveries
        self.t_ns = int(t_ns)
        self.startup.started(mean, cov, t_ns, source)
        self.fusion.restart(t_ns)
        self.imu_hold.forget_late()
        self.gate.streaks = {}
        self._reset_monitors()
        self._store(t_ns)

    def _buffer(self, stamp_ns: int, y: np.ndarray, stream: str) -> tuple[bool, str]:
        """Keep a measurement for the batch fit; start the filter when the fit is made."""
        self.counters.accept(stream)
        fit = self.startup.fit(stamp_ns, y)
        if fit is None:
            return True, "buffered"
        self._start(*fit, stamp_ns, "measurements")
        self.last_update_ns = stamp_ns
        return True, ""

    def _check_reinit_timing(self, stream: str, stamp_ns: int, now_ns: int | None) -> tuple[bool, str]:
        # uninitialised, the measurements buffered for the batch fit have moved no filter state yet
        last = self.last_measurement_ns if self.initialized else None
        ok, reason = check_timing(stamp_ns, last, now_ns, self._max_future_ns)
        if not ok:
            self.counters.reject(stream, reason)
        return ok, reason

    def _reinitialize(self, stream: str, stamp_ns: int, mean: np.ndarray, cov: np.ndarray) -> tuple[bool, str]:
        pending = [] if self.initialized else self.startup.buffered_since(stamp_ns)
        try:
            self._start(np.asarray(mean, dtype=float), np.asarray(cov, dtype=float), stamp_ns, stream)
        except Exception:  # noqa: BLE001 - e.g. a covariance the filter cannot factor
            self.counters.reject(stream, "non_finite")
            return False, "non_finite"
        self.last_measurement_ns = max(stamp_ns, self.last_measurement_ns or 0)
        self.counters.accept(stream)
        for t, y in pending:  # already counted as accepted when buffered
            self._step(t, y)
        return True, ""

    def _recover(self, stamp_ns: int, why: str) -> None:
        """Rebuild the filter from the last good estimate and predict it to ``stamp_ns``."""
        self._count_reinit(why)
        if self._good is None:
            self.reset()
            return
        mean, cov, t_ns = self._good
        if not self._restart(mean, self.config.reinit_inflation * cov, t_ns, "recovery", stamp_ns):
            good = self._good  # (the rebuilt filter's, when it was stored before the prediction failed)
            self.reset()
            self._good = good

    def _act_on_fault(self) -> None:
        """Re-initialise after ``fault_updates`` integrity FAULT updates in a row (``fault_action``)."""
        why = f"integrity FAULT for {self.integrity_watch.fault_streak} updates in a row"
        self.fault_reinit_count += 1
        self._count_reinit(why)
        t_ns, prior = self.t_ns, self.startup.prior
        if self.config.fault_action == "prior" and prior is not None and self._restart(*prior, "prior", t_ns):
            self.fusion.start_ns = t_ns  # the stamps before it belong to the state given up
            self.last_reinit_reason = f"{why}: re-initialised from the last prior"
            return
        last = self.last_measurement_ns
        self.reset(from_data=True)
        self.last_measurement_ns = last  # the fit takes only measurements after the ones given up
        self.last_reinit_reason = f"{why}: re-initialising from the next measurements"

    def _restart(self, mean: np.ndarray, cov: np.ndarray, t0_ns: int, source: str, t_ns: int) -> bool:
        """Start the filter from ``mean`` ``(n,)``, ``cov`` ``(n, n)`` at ``t0_ns`` and predict it to ``t_ns``;
        False when that raises or ends non-finite (the filter is then not to be used)."""
        try:
            self._start(mean, cov, t0_ns, source)
            self._predict_to(t_ns)
            return self._store(t_ns)
        except Exception:  # noqa: BLE001
            return False

    def _count_reinit(self, why: str) -> None:
        self.reinit_count += 1
        self.last_reinit_reason = why
        self._last_reinit_time = self.monotonic()
        self.extrapolation.drop()

    def _check_core_recovery(self) -> bool:
        """Count a re-initialisation the core filter did by itself (and reset the monitors); True if so."""
        recoveries = self.filter.recoveries
        recovered = recoveries > self._core_recoveries
        if recovered:
            self.reinit_count += recoveries - self._core_recoveries
            self.last_reinit_reason = f"core filter recovery: {self.filter.last_recovery_reason}"
            self._last_reinit_time = self.monotonic()
            self._reset_monitors()
        self._core_recoveries = recoveries
        return recovered

    def _reset_monitors(self) -> None:
        self.integrity_watch.reset()
        self.consistency_watch.reset()

    def _now(self) -> float:
        """The steady clock [s], looked up at each call (``monotonic`` may be replaced)."""
        return self.monotonic()

    @property
    def _max_future_ns(self) -> int:
        return int(self.config.max_future * NS)

    # --- outputs ---------------------------------------------------------------------------------------
    def extrapolate(self, now_ns: int, force: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
        """Predicted ``(mean (n,), cov (n, n))`` at ``now_ns`` from a copy of the filter (the filter is
        untouched); None when not initialised, ``now_ns`` is not after the filter time, the horizon exceeds
        ``max_extrapolation`` (unless ``force``) or the prediction is not finite."""
        return self.extrapolation.estimate(self.filter, self.t_ns, self.version, now_ns, self.imu_hold, force)

    @property
    def initialized(self) -> bool:
        return self.t_ns is not None

    @property
    def in_error(self) -> bool:
        """True for ``reinit_hold`` s after a re-initialisation."""
        return self.monotonic() - self._last_reinit_time < self.config.reinit_hold

    @property
    def has_costate(self) -> bool:
        """True when the filter computes a geometric co-state (the GPF; the SPF with compute_costate)."""
        return COSTATE in self.filter.capabilities

    # --- the roles' figures, under the names the node, the tools and the tests read ------------------
    init_source = property(attrgetter("startup.source"))
    init_failures = property(attrgetter("startup.fit_failures"))
    history = property(attrgetter("fusion.history"))
    late_count = property(attrgetter("fusion.late_count"))
    replayed_count = property(attrgetter("fusion.replayed_count"))
    snapshot_failures = property(attrgetter("fusion.snapshot_failures"))
    late_imu_count = property(attrgetter("imu_hold.late_count"))
    monitor = property(attrgetter("integrity_watch.monitor"))
    integrity_fault_updates = property(attrgetter("integrity_watch.fault_updates"))
    consistency = property(attrgetter("consistency_watch.monitor"))

    def integrity(self) -> IntegrityReport:
        """The co-state monitor's state for the diagnostics (see :class:`IntegrityReport`)."""
        return self.integrity_watch.report(self.filter)

    def consistency_report(self) -> ConsistencyReport | None:
        """The consistency monitor's state for the diagnostics (None when disabled)."""
        return self.consistency_watch.report()

    def waiting_for(self) -> str:
        """What the uninitialised engine waits for, in words (for the node's periodic warning)."""
        return self.startup.waiting_for()

    def imu_age(self, now_ns: int | None) -> float | None:
        """Seconds from the newest IMU sample's stamp to ``now_ns`` (None before the first one). Past
        ``imu_timeout`` the filter predicts without an input."""
        return self.imu_hold.age(now_ns)

    def imu_silent(self, now_ns: int | None) -> bool:
        """Whether an IMU heard before has been silent for longer than ``imu_timeout`` at ``now_ns``."""
        return self.imu_hold.silent(now_ns)

    def measurement_age(self, now_ns: int | None) -> float | None:
        """Seconds from the last accepted measurement's stamp to ``now_ns`` (None if none yet)."""
        if self.last_measurement_ns is None or not now_ns:
            return None
        return (now_ns - self.last_measurement_ns) * 1e-9

    def observability(self) -> ObservabilityReport | None:
        """The filter's observability report (None before it is initialised, or if it has none)."""
        return observability(self.filter) if self.initialized else None

    def filter_stats(self) -> dict:
        """The filter's figures for the diagnostics (:func:`~gpf_nav.estimator.filter_figures.filter_stats`;
        none before it is initialised)."""
        return filter_stats(self.filter) if self.initialized else {}
