"""Observability report: which directions of the state the measurements have actually determined.

A filter's covariance says how sure it is; it does not say *why*. Where the data cannot determine a
direction of the state (range only from the centre of a central force field: any rotation of the whole
trajectory gives the same ranges), the posterior along it should stay the prior, and an estimator that
narrows it has invented information. :class:`ObservabilityTracker` measures the information the
measurements carried, independently of the estimator's own covariance, and names the directions that
received (almost) none.

Definition. Along a reference trajectory the tracker runs two linearised covariance recursions from the
prior ``P0``: ``F`` the transition Jacobian, ``Q`` the process noise, ``H`` the measured rows' Jacobian and
``R`` their noise,

* without data: ``P_free <- F P_free F^T + Q`` (the prior carried forward);
* with data:    ``P_data <- F P_data F^T + Q``, then the Kalman update by ``(H, R)`` at every measurement.

The information the data carried, in the prior's own scaled units, is
``J_s = L^T (P_data^-1 - P_free^-1) L`` with ``L L^T = P_free``: its eigenvalue ``lambda_i`` along the
scaled direction ``u_i`` is the data's information over the prior's (``1 / (1 + lambda)`` is the share of
the no-data variance left). A direction with ``lambda_i < threshold`` (default
:data:`UNDETERMINED_INFORMATION`: the data removed less than 1 % of the prior's variance) is *undetermined*; in state units it is ``d_i = L u_i``.

Filters whose update is observability-constrained
(:meth:`~gpf_nav.filters.particle.ParticleFilter.update`) keep the prediction along the directions that
carried less than their own, smaller, threshold (:meth:`ObservabilityTracker.basis`).

Everything is linearised along a reference trajectory (:class:`ObservabilityTracker`): the report is about the geometry (which directions the
measurement functions and the dynamics can see), not about how far the estimate is from the truth.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from gpf_nav.kernels import information

UNDETERMINED_INFORMATION = 0.01
"""Default threshold: a direction along which the data carried less than this much information, relative to
the prior's (scaled units), is undetermined."""
REANCHOR_SIGMAS = 10.0
"""A measurement this many standard deviations of the no-data prediction from the reference's moves the
reference to the filter's mean, if it is within as many of the mean's."""
REBUILD_LOG = 20_000
"""Predictions and updates since the prior that the tracker keeps to rebuild its recursions along a new
reference (:meth:`ObservabilityTracker.reanchor`); past it a move keeps what was accumulated."""
QUEUE_LIMIT = 4096
"""Predictions and updates a tracker queues before it runs them unread (:class:`ObservabilityTracker`)."""

@dataclass(frozen=True)
class ObservabilityReport:
    """What the data determined so far.

    Attributes:
        undetermined: number of undetermined directions (0 when every direction is determined).
        directions: ``(d, n)`` the undetermined directions in state units (unit vectors after scaling each
            component by the prior's standard deviation: read them as "this combination of the state").
        information: ``(n,)`` the data's information over the prior's along the scaled eigen-directions,
            smallest first.
        threshold: the information below which a direction is undetermined.
        updates: measurement updates the tracker has seen since the prior.
        elapsed: time predicted over since the prior, s.
        scale: ``(n,)`` the no-data standard deviations the information is measured in.
        eigenvectors: ``(n, n)`` every direction (rows, state units), in the order of ``information``.
    """

    undetermined: int
    directions: np.ndarray
    information: np.ndarray
    threshold: float
    updates: int
    elapsed: float = 0.0
    scale: np.ndarray = field(repr=False, default=None)
    eigenvectors: np.ndarray = field(repr=False, default=None)

    @property
    def determined(self) -> bool:
        """Whether every direction of the state is determined."""
        return self.undetermined == 0

    def describe(self, names: tuple[str, ...] | None = None, top: int = 4) -> list[str]:
        """One line per undetermined direction: its ``top`` largest scaled components, e.g.
        ``"+0.71 py -0.70 vz"``; ``names`` label the state components (default ``x0, x1, ...``)."""
        n = self.directions.shape[1] if self.directions.size else len(self.information)
        names = names or tuple(f"x{i}" for i in range(n))
        lines = []
        for d in self.directions:
            scaled = d / self.scale
            scaled = scaled / max(np.linalg.norm(scaled), 1e-300)
            order = np.argsort(-np.abs(scaled))[:top]
            lines.append(" ".join(f"{scaled[i]:+.2f} {names[i]}" for i in order if abs(scaled[i]) >= 0.05))
        return lines


class ObservabilityTracker:
    """The linearised information recursions of the module docstring, for a filter on ``model``.

    The recursions are linearised along a *reference* trajectory that the model's own flow carries from the
    prior mean, not along the filter's mean: a mean that jumps at every correction turns the measurement
    Jacobians a little against the carried information at each update, and along a direction with a
    prior of 20 km measured to 30 m that fakes information within a few hundred updates (what first-
    estimate Jacobians and observability-constrained EKFs correct in visual-inertial navigation). A
    reference that only flows keeps the null directions of a symmetry exactly. It is moved to the
    filter's mean (:meth:`reanchor`) when the data say it has left the prior's reach (a measurement more
    than :data:`REANCHOR_SIGMAS` standard deviations of the no-data prediction away) and the mean has not
    (the same measurement within that reach of the mean's), or is not finite. A mean that does not explain
    the measurement either (a diverged filter, a gross outlier) is no better a point to linearise at, and a
    diverged filter would move the reference at every update.
    The move rebuilds both recursions from the prior along the model's trajectory through the new
    reference (carried back through the logged predictions): a reference that jumped would turn the
    carried information against the new Jacobians, like a moving mean, and give information to a
    direction no measurement sees.

    The recursions run when they are read. :meth:`predict` and :meth:`update` queue their calls (with
    copies of their arrays and the sensor's noise at the call); a read (:meth:`report`, :meth:`basis`,
    :attr:`reference`, the counters), :meth:`reanchor` or :meth:`reset` first runs the queue in order, the
    same arithmetic on the same numbers as at the calls, and so does a queue of :data:`QUEUE_LIMIT` calls.
    A filter whose update does not read the tracker (no observability constraint) pays for it only when
    its report is asked for.

    Args:
        model: the filter's state-space model (its own state: augmented, if the filter augments it).
        threshold: information over the prior's below which a direction is undetermined.
    """

    def __init__(self, model, threshold: float = UNDETERMINED_INFORMATION):
        if not threshold > 0.0:
            raise ValueError(f"threshold must be positive, got {threshold}")
        self.model = model
        self.threshold = float(threshold)
        self._free = self._data = self._reference = None
        self._prior: np.ndarray | None = None
        self._log: _Log | None = None
        self._report: ObservabilityReport | None = None
        self._noise: tuple[float, np.ndarray] | None = None
        self._queue = _Queue()
        self._updates = 0
        self._elapsed = 0.0
        self._reanchors = 0

    @property
    def updates(self) -> int:
        """Measurement updates since the prior."""
        self._run_queue()
        return self._updates

    @property
    def elapsed(self) -> float:
        """Time predicted over since the prior, s."""
        self._run_queue()
        return self._elapsed

    @property
    def reanchors(self) -> int:
        """Moves of the reference so far (:meth:`reanchor`)."""
        self._run_queue()
        return self._reanchors

    def reset(self, mean: np.ndarray, cov: np.ndarray) -> None:
        """Start again from the prior ``N(mean (n,), cov (n, n))``: nothing is determined yet."""
        self._run_queue()  # (the queued calls count in reanchors)
        cov = np.array(cov, dtype=float)
        self._reference = np.array(mean, dtype=float)
        self._free, self._data = cov, cov.copy()
        self._prior = cov.copy()
        self._log = _Log()
        self._updates = 0
        self._elapsed = 0.0
        self._report = None

    @property
    def ready(self) -> bool:
        """Whether :meth:`reset` has been called."""
        return self._free is not None

    @property
    def reference(self) -> np.ndarray | None:
        """``(n,)`` the state the recursions are linearised at now (None before :meth:`reset`)."""
        self._run_queue()
        return None if self._reference is None else self._reference.copy()

    def reanchor(self, mean: np.ndarray) -> None:
        """Move the reference to ``mean`` ``(n,)`` (the filter's) and rebuild both recursions along the
        model's trajectory through it (:meth:`_rebuild`); when that cannot be done (a log past
        :data:`REBUILD_LOG`, a model that does not flow back), keep what was accumulated."""
        self._run_queue()
        self._reanchor(mean)

    def _reanchor(self, mean: np.ndarray) -> None:
        """:meth:`reanchor`, the queue already run."""
        mean = np.asarray(mean, dtype=float)
        if self._free is not None and np.isfinite(mean).all():
            self._reference = mean.copy()
            self._reanchors += 1
            self._rebuild()
            self._report = None

    def _rebuild(self) -> None:
        """Both recursions again from the prior, linearised along the model's trajectory that reaches the
        reference now: carried back through the logged predictions (``transition_chain``), then forward
        through the log, the Jacobians along it in one call each (the model's ``transition_jacobian_along``,
        each sensor's ``jacobian_along``) and the recursions in one kernel
        (:func:`~gpf_nav.kernels.information.replay`). What does not depend on the reference (steps, rows,
        noises) was kept by the log as it grew (:class:`_Log`)."""
        log = self._log
        if log is None or log.full:
            return
        k, store = log.predictions, log.store
        dt, t, u = store.dt[:k], store.t[:k], store.inputs[:k]
        with np.errstate(all="ignore"):
            try:  # (K + 1, n): the state before each prediction, then the reference
                trajectory = self.model.transition_chain(self._reference, -dt[::-1], (t + dt)[::-1], u[::-1])[::-1]
            except (ValueError, FloatingPointError, ArithmeticError):
                return
        if not np.isfinite(trajectory).all():
            return
        n = trajectory.shape[1]
        F = self.model.transition_jacobian_along(trajectory[:-1], dt, t, u) if u else np.zeros((0, n, n))
        Q = self._noise_along(dt, t, n)
        H, R, rows = self._logged_updates(log, trajectory, n)
        self._free, self._data = information.replay(_matrix(self._prior), store.predicted[:log.size], _matrix(F),
                                                    _matrix(Q), _matrix(trajectory[1:]), H, R, rows)

    def _noise_along(self, dt: np.ndarray, t: np.ndarray, n: int) -> np.ndarray:
        """``Q`` ``(K, n, n)`` of each logged prediction (once per distinct ``dt`` when it does not depend on
        ``t``)."""
        if self.model.time_varying_noise:
            return np.array([self.model.process_noise(step, start) for step, start in zip(dt.tolist(), t.tolist())],
                            dtype=float).reshape(-1, n, n)
        distinct, index = np.unique(dt, return_inverse=True)
        return np.array([self.model.process_noise(step, 0.0) for step in distinct.tolist()],
                        dtype=float).reshape(-1, n, n)[index.ravel()]

    @staticmethod
    def _logged_updates(log: _Log, trajectory: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The measured rows' Jacobians and noises of the ``M`` logged updates, linearised along
        ``trajectory`` ``(K + 1, n)`` and padded to the most rows measured, ``r``: ``H`` ``(M, r, n)``, ``R``
        ``(M, r, r)`` and the rows used ``(M,)``. Each sensor's Jacobians in one call, its updates in log
        order; the kernel reads only the first ``rows[j]`` rows of each, so the padding rows of ``H``
        repeat a measured one."""
        m, store = log.updates, log.store
        group, count = store.group[:m], store.count[:m]
        width = int(count.max()) if m else 0
        # the updates sorted by sensor (stably: each sensor's in log order), so that a sensor's are a slice
        order, sizes = np.argsort(group, kind="stable"), np.bincount(group)
        end = np.cumsum(sizes)
        x, times = trajectory[store.at[:m][order]], store.times[:m][order]
        calls = [(start, stop, sensor.jacobian_along(x[start:stop], times[start:stop]))  # (G, m_s, n)
                 for sensor, start, stop in zip(store.sensors, end - sizes, end) if stop > start]
        full = np.empty((m, max((jacobians.shape[1] for *_, jacobians in calls), default=0), n))
        for start, stop, jacobians in calls:
            full[start:stop, :jacobians.shape[1]] = jacobians
        position = np.empty(m, dtype=np.int64)  # of each update in the sorted order
        position[order] = np.arange(m)
        H = full[position[:, None], store.rows[:m, :width]]
        return H, _matrix(store.noise[:m, :width, :width]), count

    def predict(self, dt: float, t: float, u=None) -> None:
        """Carry both recursions and the reference over ``dt`` from time ``t`` with the input ``u`` (queued:
        class docstring)."""
        if self._free is None:
            return
        self._enqueue((None, float(dt), float(t), None if u is None else np.array(u, dtype=float)))

    def update(self, sensor, y: np.ndarray, rows: np.ndarray, t: float, mean: np.ndarray) -> None:
        """Add the information of the measured ``rows`` ``(m,)`` of ``y`` from ``sensor`` at time ``t``,
        linearised at the reference (moved first to the filter's ``mean`` ``(n,)`` when ``y`` is beyond
        the no-data prediction's reach; queued: class docstring)."""
        if self._free is None or not rows.any():
            return
        self._enqueue((sensor, np.array(y, dtype=float), rows.copy(), float(t), np.array(mean, dtype=float),
                       np.array(sensor.noise(t), dtype=float)))

    def _enqueue(self, call: tuple) -> None:
        self._queue.append(call)
        if len(self._queue) >= QUEUE_LIMIT:
            self._run_queue()

    def _run_queue(self) -> None:
        """Run the queued calls in order (:meth:`_predict` for ``(None, dt, t, u)``, :meth:`_update` for
        ``(sensor, y, rows, t, mean, R)``)."""
        if not self._queue:
            return
        queue, self._queue = self._queue, _Queue()
        for call in queue:
            if call[0] is None:
                self._predict(*call[1:])
            else:
                self._update(*call)

    def _predict(self, dt: float, t: float, u: np.ndarray | None) -> None:
        """:meth:`predict`, run."""
        x = self._reference[None]
        F = _matrix(self.model.transition_jacobian(x, dt, t, u)[0])
        Q = _matrix(self._process_noise(dt, t))
        reference = _matrix(self.model.transition(x, dt, t, u)[0])
        ok, free, data = information.propagate(F, Q, reference, self._free, self._data)
        if not ok:
            return
        self._log.predict(dt, t, u)
        self._reference = reference
        self._elapsed += dt
        self._free, self._data = free, data
        self._report = None

    def _process_noise(self, dt: float, t: float) -> np.ndarray:
        """``Q(dt)``, cached for the last ``dt`` when the model's noise does not depend on time."""
        if self.model.time_varying_noise:
            return self.model.process_noise(dt, t)
        if self._noise is None or self._noise[0] != dt:
            self._noise = (dt, self.model.process_noise(dt, t))
        return self._noise[1]

    def _update(self, sensor, y: np.ndarray, rows: np.ndarray, t: float, mean: np.ndarray,
                noise: np.ndarray) -> None:
        """:meth:`update`, run; ``noise`` ``(m, m)`` is the sensor's at the call."""
        h, H = sensor.measure_and_jacobian(self._reference[None], t)
        if rows.all():  # (no gathers: the usual case)
            H, R, r = H[0], noise, sensor.residual(y, h[0])
        else:
            H, R, r = H[0][rows], noise[np.ix_(rows, rows)], sensor.residual(y, h[0])[rows]
        H, R = _matrix(H), _matrix(R)
        outcome, data = information.update(H, R, _matrix(r), self._free, self._data, REANCHOR_SIGMAS ** 2)
        if outcome == information.NOT_FINITE:
            return
        if outcome == information.FAR:
            if self._explains(sensor, y, rows, t, mean, R):
                self._reanchor(mean)
                H = _matrix(sensor.jacobian(self._reference[None], t)[0][rows])
            outcome, data = information.update(H, R, _EMPTY, self._free, self._data, 0.0)
        if outcome != information.UPDATED:  # a singular innovation covariance
            return
        self._log.update(sensor, rows, t, R)
        self._data = data  # Joseph form
        self._updates += 1
        self._report = None

    def _explains(self, sensor, y: np.ndarray, rows: np.ndarray, t: float, mean: np.ndarray,
                  noise: np.ndarray) -> bool:
        """Whether the filter's ``mean`` ``(n,)`` is within the no-data prediction's reach of the measured
        ``rows`` of ``y`` (the test the reference failed): only then is it a better point to linearise at.
        A filter that does not explain the measurement either (a diverged estimate, a gross outlier) would
        move the reference at every update, each move a rebuild of the whole log."""
        if not np.isfinite(mean).all():
            return False
        h, H = sensor.measure_and_jacobian(mean[None], t)
        r = sensor.residual(y, h[0])[rows]
        outcome, _ = information.update(_matrix(H[0][rows]), noise, _matrix(r), self._free, self._data,
                                        REANCHOR_SIGMAS ** 2)
        return outcome != information.FAR and outcome != information.NOT_FINITE

    def report(self) -> ObservabilityReport | None:
        """The report now (None before :meth:`reset`, or when a recursion has broken down)."""
        self._run_queue()
        if self._report is None and self._free is not None:
            self._report = self._compute()
        return self._report

    def basis(self, threshold: float | None = None) -> np.ndarray:
        """``(n, d)`` orthonormal basis (state units) of the directions with less information than
        ``threshold`` (default: the report's); ``(n, 0)`` when there are none or no report."""
        report = self.report()
        if report is None:
            return np.zeros((0 if self._free is None else self._free.shape[0], 0))
        limit = self.threshold if threshold is None else float(threshold)
        d = int(np.count_nonzero(report.information < limit))
        return _orthonormal(report.eigenvectors[:d].T) if d else np.zeros((report.information.size, 0))

    def _compute(self) -> ObservabilityReport | None:
        # in units of the prior's standard deviations (the two covariances mix metres and m/s)
        ok, s, info, vectors = information.report(self._free, self._data)
        if not ok:
            return None
        d = int(np.count_nonzero(info < self.threshold))
        return ObservabilityReport(d, vectors[:d], info, self.threshold, self._updates, self._elapsed,
                                   scale=s, eigenvectors=vectors)


_EMPTY = np.zeros(0)


class _Log:
    """The predictions and updates since the prior, in order, up to :data:`REBUILD_LOG` (then :attr:`full`,
    and no longer kept), with what a rebuild needs of them that does not depend on the reference, kept as
    they come (a rebuild then reads arrays, not entries): :attr:`store`'s first :attr:`size` entries,
    :attr:`predictions` predictions and :attr:`updates` updates.

    A copy of the filter (the estimator's late-measurement history) shares the store: entries are never
    changed, only appended, so a log appends in place while it is the one that wrote the store's last
    entry, and otherwise (a copy that went on, then this one) appends to a copy of its own prefix first.
    Copying a log costs nothing; diverging copies one prefix."""

    def __init__(self):
        self.store: _Store | None = _Store()
        self.size = self.predictions = self.updates = 0
        self.full = False

    def predict(self, dt: float, t: float, u) -> None:
        """Log a prediction over ``dt`` from ``t`` with the input ``u`` (None: none)."""
        store = self._writable()
        if store is not None:
            store.predict(self.size, self.predictions, float(dt), float(t),
                          None if u is None else np.array(u, dtype=float))
            self.size, self.predictions = self.size + 1, self.predictions + 1

    def update(self, sensor, rows: np.ndarray, t: float, R: np.ndarray) -> None:
        """Log an update of ``sensor``'s measured ``rows`` ``(m,)`` bool at ``t``, their noise ``R``
        ``(r, r)``."""
        store = self._writable()
        if store is not None:
            store.update(self.size, self.updates, sensor, np.flatnonzero(rows), float(t), R, self.predictions)
            self.size, self.updates = self.size + 1, self.updates + 1

    def _writable(self) -> _Store | None:
        """The store to append to, or None (:attr:`full`)."""
        if self.full:
            return None
        if self.size >= REBUILD_LOG:
            self.full, self.store = True, None
            return None
        if self.store.size != self.size:  # a copy of this log wrote past it
            self.store = self.store.prefix(self.size, self.predictions, self.updates)
        return self.store

    def __deepcopy__(self, memo) -> "_Log":
        return copy.copy(self)


class _Store:
    """The arrays of :class:`_Log`, whose first rows are its entries (capacity doubled as it grows).

    Attributes:
        size: entries written.
        predicted: ``(E,)`` whether each entry is a prediction (else an update).
        dt, t: ``(K,)`` each prediction's step and start, s; ``inputs`` its input (None: none).
        sensors: the distinct sensors of the updates, in order of first use (held: their ids stay theirs).
        group: ``(M,)`` each update's sensor (index into ``sensors``).
        at: ``(M,)`` the predictions before each update: its point of the trajectory.
        times: ``(M,)`` each update's time, s.
        count: ``(M,)`` the rows each update measured; ``rows`` ``(M, D)`` which (padded with 0).
        noise: ``(M, D, D)`` their noise ``R``, in the first ``count`` rows and columns.
    """

    _ARRAYS = ("predicted", "dt", "t", "group", "at", "times", "count", "rows", "noise")

    def __init__(self, capacity: int = 64):
        self.size = 0
        self.predicted = np.zeros(capacity, dtype=bool)
        self.dt, self.t, self.times = np.zeros(capacity), np.zeros(capacity), np.zeros(capacity)
        self.group, self.at, self.count = (np.zeros(capacity, dtype=np.int64) for _ in range(3))
        self.rows, self.noise = np.zeros((capacity, 0), dtype=np.int64), np.zeros((capacity, 0, 0))
        self.inputs: list = []
        self.sensors: list = []
        self._groups: dict[int, int] = {}

    def prefix(self, size: int, predictions: int, updates: int) -> _Store:
        """A copy holding the first ``size`` entries (of which ``predictions`` predictions)."""
        out = copy.copy(self)
        for name in self._ARRAYS:
            setattr(out, name, getattr(self, name).copy())
        out.size, out.inputs = size, self.inputs[:predictions]
        out.sensors, out._groups = list(self.sensors), dict(self._groups)
        return out

    def predict(self, e: int, k: int, dt: float, t: float, u: np.ndarray | None) -> None:
        """Write entry ``e``, prediction ``k``."""
        self._room(e, 0)
        self.predicted[e], self.dt[k], self.t[k] = True, dt, t
        self.inputs.append(u)
        self.size = e + 1

    def update(self, e: int, j: int, sensor, rows: np.ndarray, t: float, R: np.ndarray, at: int) -> None:
        """Write entry ``e``, update ``j``: the measured ``rows`` ``(r,)`` of ``sensor`` and their noise ``R``
        ``(r, r)``, at trajectory point ``at``."""
        r = rows.size
        self._room(e, r)
        group = self._groups.get(id(sensor))
        if group is None:
            group = self._groups[id(sensor)] = len(self.sensors)
            self.sensors.append(sensor)
        self.predicted[e], self.group[j], self.at[j], self.times[j], self.count[j] = False, group, at, t, r
        self.rows[j, :r], self.rows[j, r:] = rows, 0
        self.noise[j, :r, :r] = R
        self.size = e + 1

    def _room(self, e: int, r: int) -> None:
        """Grow the arrays to hold entry ``e`` (there are fewer predictions and updates than entries) and
        ``r`` measured rows."""
        capacity, width = self.predicted.size, self.rows.shape[1]
        if e < capacity and r <= width:
            return
        capacity, width = 2 * capacity if e >= capacity else capacity, max(r, width)
        for name in self._ARRAYS:
            old = getattr(self, name)
            new = np.zeros((capacity,) + (width,) * (old.ndim - 1), dtype=old.dtype)
            new[(slice(0, old.shape[0]),) + tuple(slice(0, d) for d in old.shape[1:])] = old
            setattr(self, name, new)


class _Queue(list):
    """Calls queued by :meth:`ObservabilityTracker.predict` and :meth:`~ObservabilityTracker.update`. Like the
    log's entries they are never changed, so a copy of the tracker shares them (and their sensors)."""

    def __deepcopy__(self, memo) -> "_Queue":
        return _Queue(self)


def _matrix(a) -> np.ndarray:
    """``a`` as the writeable C-contiguous float64 array the kernels take (no copy when it already is one:
    numba compiles a kernel again for each layout and for read-only arrays, e.g. a cached ``Q``)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


def _orthonormal(a: np.ndarray) -> np.ndarray:
    """An orthonormal basis ``(n, d)`` of the columns of ``a`` (which are independent)."""
    return information.orthonormal(_matrix(a))


__all__ = ["ObservabilityReport", "ObservabilityTracker", "UNDETERMINED_INFORMATION"]
