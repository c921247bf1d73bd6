"""The interface every filter shares: ``initialize``, ``predict``, ``update``, ``mean``, ``covariance``.

Measurements are vectors ``y`` of shape ``(m,)``; a non-finite component (NaN) means "not measured" and
the update uses only the measured rows. That is how partial observability reaches a filter.
``update(y, sensor)`` conditions on the measurement of any :class:`~gpf_nav.sensors.sensor.Sensor` of the
user's state; without one, on the model's own (:class:`~gpf_nav.sensors.model.ModelSensor`).

Optional capabilities are declared, not probed: :attr:`Filter.capabilities` names those a filter has
(:data:`CAPABILITIES`), and the attributes of every capability are declared on :class:`Filter` with the
value they read when the capability is absent (None, 0, False or empty).

Time: :attr:`Filter.time` is the elapsed time since ``initialize(mean, cov, t0)`` (``t0 + `` the sum of
the ``dt`` predicted over); it is the ``t`` the filter passes to the model.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np

from gpf_nav.integrity.observability import ObservabilityReport, ObservabilityTracker
from gpf_nav.models.state_space import StateSpaceModel
from gpf_nav.models.checks import validate_model
from gpf_nav.sensors.sensor import Padded, Sensor
from gpf_nav.sensors.model import ModelSensor


CLOUD = "cloud"
"""``particles`` ``(N, n)`` and ``weights`` ``(N,)`` (None: equal weights, an ensemble)."""
RESAMPLING = "resampling"
"""``ess`` (ESS/N after the last update), ``resampled`` (at the last update), ``resample_count``."""
COSTATE = "costate"
"""The geometric co-state of the last update: ``costate_mean`` ``(m,)``, ``costate_measured`` ``(m,)``
bool (the components it covers), ``costate_norm_mean``, ``costate_norm_max``."""
GATE = "gate"
"""An innovation gate: ``gated`` counts the measurement components it refused."""
TEMPERING = "tempering"
"""Likelihood tempering: ``tempered_updates`` counts the updates split into stages."""
MODEL_PROBABILITIES = "model_probabilities"
"""``model_probabilities`` ``(K,)``: of the nominal model, then of the compensated models."""
COMPENSATION = "compensation"
"""An estimated unmodelled acceleration: ``unmodelled_acceleration`` ``(p,)`` and its covariance
``unmodelled_acceleration_covariance`` ``(p, p)``."""
SENSOR_BIAS = "sensor_bias"
"""Sensor-bias states: ``sensor_names`` (the biased sensors) and ``sensor_bias(name)``."""
CAPABILITIES = (CLOUD, RESAMPLING, COSTATE, GATE, TEMPERING, MODEL_PROBABILITIES, COMPENSATION, SENSOR_BIAS)
"""Every optional capability a filter may declare in :attr:`Filter.capabilities`."""
ATTRIBUTES: dict[str, tuple[str, ...]] = {
    CLOUD: ("particles", "weights"),
    RESAMPLING: ("ess", "resampled", "resample_count"),
    COSTATE: ("costate_mean", "costate_measured", "costate_norm_mean", "costate_norm_max"),
    GATE: ("gated",),
    TEMPERING: ("tempered_updates",),
    MODEL_PROBABILITIES: ("model_probabilities",),
    COMPENSATION: ("unmodelled_acceleration", "unmodelled_acceleration_covariance"),
    SENSOR_BIAS: ("sensor_names", "sensor_bias", "predicted_estimate"),
}
"""The attributes and methods of :class:`Filter` that answer each capability (what a composite filter,
:mod:`gpf_nav.filters.composite`, reads from the member that answers it)."""

PADDED_SENSORS = 16
"""Padded wrappers of user sensors a filter keeps (:meth:`Filter._sensor_for`)."""
N_PARTICLES = 500
"""Default number of particles or ensemble members of the filters that have a :data:`CLOUD`."""

_EMPTY_VECTOR = np.zeros(0)
_EMPTY_VECTOR.flags.writeable = False
_EMPTY_MATRIX = np.zeros((0, 0))
_EMPTY_MATRIX.flags.writeable = False

COVARIANCE_LIMIT = 1e300
"""A covariance whose trace reaches this counts as unhealthy: inflated by a recovery, or estimated from
an ensemble (a sum of N such products), it would overflow."""


class Filter(ABC):
    """Base class of all filters: holds the model, the filter time and a seeded random generator.

    The model is checked (:func:`~gpf_nav.models.checks.validate_model`) at the first ``initialize``.

    Args:
        model: the state-space model the filter runs on.
        seed: seed (or ``numpy.random.Generator``) of the filter's own random stream.

    Attributes:
        recoveries: how many times the filter re-initialised itself (see :meth:`_recover`).
        last_recovery_reason: why it last did, or None.
        last_log_likelihood: the last update's log evidence ``log p(y | earlier data)``: a particle
            filter's estimate from its weights, a Gaussian filter's ``log N(r; 0, S)`` of the innovation, a
            multiple-model filter's mixture of its members'; 0 before the first update and after one that
            measured nothing.

    The attributes of the optional capabilities (:data:`CAPABILITIES`) follow; a filter that has one names
    it in :attr:`capabilities` and overrides them, the others read the absent value given here.
    """

    # --- optional capabilities: their attributes, as they read when absent ------------------------------
    particles: np.ndarray | None = None
    """``(N, n)`` particles or ensemble members (:data:`CLOUD`)."""
    weights: np.ndarray | None = None
    """``(N,)`` normalised weights of :attr:`particles` (:data:`CLOUD`; None: equal)."""
    ess: float | None = None
    """ESS/N after the last update (:data:`RESAMPLING`)."""
    resampled: bool = False
    """Whether the last update resampled (:data:`RESAMPLING`)."""
    resample_count: int = 0
    """Resamplings so far (:data:`RESAMPLING`)."""
    costate_mean: np.ndarray | None = None
    """Weighted mean co-state ``(m,)`` of the last update (:data:`COSTATE`)."""
    costate_measured: np.ndarray | None = None
    """Components ``(m,)`` bool the last co-state covers (:data:`COSTATE`)."""
    costate_norm_mean: float | None = None
    """Weighted mean of the per-particle co-state norms (:data:`COSTATE`)."""
    costate_norm_max: float | None = None
    """Largest per-particle co-state norm (:data:`COSTATE`)."""
    gated: int = 0
    """Measurement components refused by the innovation gate (:data:`GATE`)."""
    tempered_updates: int = 0
    """Updates split into tempering stages (:data:`TEMPERING`)."""
    model_probabilities: np.ndarray | None = None
    """``(K,)`` probabilities of the nominal model, then of the compensated models (:data:`MODEL_PROBABILITIES`)."""
    unmodelled_acceleration: np.ndarray = _EMPTY_VECTOR
    """Estimated unmodelled acceleration ``(p,)`` (:data:`COMPENSATION`; empty without)."""
    unmodelled_acceleration_covariance: np.ndarray = _EMPTY_MATRIX
    """Its covariance ``(p, p)`` (:data:`COMPENSATION`)."""
    sensor_names: tuple[str, ...] = ()
    """Sensors whose bias the filter estimates (:data:`SENSOR_BIAS`)."""

    @property
    def capabilities(self) -> frozenset[str]:
        """The optional capabilities (:data:`CAPABILITIES`) this filter has; none for the base class."""
        return frozenset()

    def sensor_bias(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """``(estimated bias (m,), its std (m,))`` of sensor ``name`` (:data:`SENSOR_BIAS`); KeyError when
        the filter estimates no bias of ``name``."""
        raise KeyError(f"{type(self).__name__} estimates no bias of sensor {name!r}")

    def predicted_estimate(self, sensor: Sensor) -> tuple[Sensor, np.ndarray, np.ndarray]:
        """What an innovation test of ``sensor`` needs: the sensor on the state the filter estimates, that
        state's mean and covariance (:data:`SENSOR_BIAS`: the augmented state, so that the sensor's estimated
        bias is subtracted and its uncertainty counted). Without the capability ``(sensor, mean (n,),
        covariance (n, n))``."""
        return sensor, self.mean, self.covariance

    def predicted_estimates(self, sensor: Sensor) -> list[tuple[Sensor, np.ndarray, np.ndarray]]:
        """The :meth:`predicted_estimate` of each hypothesis the filter holds, the most probable first: an
        innovation test should refuse a measurement only when every one refuses it (a measurement that one
        model explains is not an outlier). One for a single-model filter."""
        return [self.predicted_estimate(sensor)]

    def __init__(self, model: StateSpaceModel, seed: int | np.random.Generator | None = None):
        self.model = model
        self.rng = np.random.default_rng(seed)
        self.time = 0.0
        self.initialized = False
        self.recoveries = 0
        self.last_recovery_reason: str | None = None
        self.last_log_likelihood = 0.0
        self.recovery_inflation = 10.0
        self._last_good: tuple[np.ndarray, np.ndarray] | None = None
        self._recovering = False
        self._model_checked = False
        self._own_sensor = ModelSensor(model)
        self._observability = ObservabilityTracker(model)

    @abstractmethod
    def initialize(self, mean: np.ndarray, cov: np.ndarray, t0: float = 0.0) -> None:
        """Start from the Gaussian prior ``N(mean (n,), cov (n, n))`` at filter time ``t0``."""

    @abstractmethod
    def predict(self, dt: float, u: np.ndarray | None = None) -> None:
        """Propagate the estimate over ``dt`` seconds with the known input ``u`` held constant."""

    @abstractmethod
    def update(self, y: np.ndarray, sensor: Sensor | None = None) -> None:
        """Condition on measurement ``y`` ``(m,)`` of ``sensor`` (None: the model's own measurement);
        NaN components are not measured."""

    @property
    @abstractmethod
    def mean(self) -> np.ndarray:
        """Posterior mean ``(n,)``."""

    @property
    @abstractmethod
    def covariance(self) -> np.ndarray:
        """Posterior covariance ``(n, n)``."""

    @property
    def observability(self) -> ObservabilityReport | None:
        """What the measurements have determined since the prior, and the directions they have not
        (:mod:`gpf_nav.integrity.observability`); None before :meth:`initialize`."""
        return None if self._observability is None else self._observability.report()

    def observability_trackers(self) -> tuple[ObservabilityTracker, ...]:
        """The observability trackers this filter runs: its own; a filter that runs others, theirs (the
        estimator's warm-up rehearses their reanchoring)."""
        return () if self._observability is None else (self._observability,)

    def forgo_observability(self) -> None:
        """Run no observability recursions (:attr:`observability` is then None): for a member of a composite
        filter that reads no report of it. The recursions cost about as much as an EKF's own step."""
        self._observability = None

    def _observe_predict(self, dt: float, u) -> None:
        """Carry the observability recursions over ``dt`` (call before :attr:`time` moves)."""
        if self._observability is not None:
            self._observability.predict(dt, self.time, u)

    def _observe_update(self, y: np.ndarray, sensor: Sensor, rows: np.ndarray, mean: np.ndarray) -> None:
        """Add the information of the measured ``rows`` ``(m,)`` of ``y`` from ``sensor``; ``mean`` ``(n,)``
        is the filter's own (where the tracker moves its reference if it has lost it)."""
        if self._observability is not None:
            self._observability.update(sensor, y, rows, self.time, mean)

    def _require_initialized(self) -> None:
        if not self.initialized:
            raise RuntimeError(f"{type(self).__name__}: call initialize() before predict() or update()")

    # --- recovery ----------------------------------------------------------------------------------------
    def _remember(self, mean: np.ndarray, cov: np.ndarray, updated: bool = True) -> None:
        """Keep ``(mean, cov)`` as the last good estimate, if it is finite.

        After a recovery only an update (``updated``) may set it again: a prediction from the inflated
        re-initialisation is not evidence of health, and remembering it would let consecutive
        recoveries inflate an already inflated covariance."""
        if self._recovering and not updated:
            return
        if np.isfinite(mean).all() and np.isfinite(cov).all():
            self._last_good = (np.array(mean, dtype=float), np.array(cov, dtype=float))
            self._recovering = False

    def _guard(self, updated: bool, mean: np.ndarray, cov: np.ndarray) -> None:
        """After a step of a Gaussian or ensemble filter (``updated``: an update, else a prediction) that
        left the estimate ``mean (n,)``, ``cov (n, n)``: remember it when healthy, or recover from an
        estimate that is non-finite, has a negative variance or a trace beyond ``COVARIANCE_LIMIT``. It runs at every step: for the small
        ``n`` of these filters, sums of Python lists cost less than numpy reductions."""
        diagonal = cov.diagonal().tolist()
        # a sum is finite only if every term is (an overflowing sum counts as unhealthy too); a NaN on
        # the diagonal fails the comparisons
        if (min(diagonal) >= 0.0 and sum(diagonal) < COVARIANCE_LIMIT
                and math.isfinite(sum(mean.tolist()) + sum(cov.ravel().tolist()))):
            if updated or not self._recovering:
                self._last_good = (mean, cov)  # the filters never write their state in place
                self._recovering = False
        else:
            self._recover("estimate became non-finite, or its covariance indefinite or near overflow")

    def _recover(self, reason: str) -> None:
        """Re-initialise from the last good estimate with its covariance times ``recovery_inflation``.

        Counted in :attr:`recoveries`; :attr:`last_recovery_reason` says why. Filter time is kept. The
        inflation never compounds: until an update succeeds, the last good estimate stays the one
        remembered before the first of consecutive recoveries.
        """
        self.recoveries += 1
        self.last_recovery_reason = reason
        mean, cov = self._last_good
        self.initialize(mean, self.recovery_inflation * cov, self.time)
        self._last_good = (mean, cov)
        self._recovering = True

    # --- helpers shared by the filters ---------------------------------------------------------------
    def _check_prior(self, mean, cov, t0: float) -> tuple[np.ndarray, np.ndarray]:
        """Start ``initialize``: return the prior ``(mean (n,), cov (n, n))`` symmetrised, set the filter
        time to ``t0`` and, the first time, validate the model on the prior (``ValueError`` if wrong)."""
        n = self.model.state_dim
        mean = np.asarray(mean, dtype=float).reshape(-1)
        cov = np.asarray(cov, dtype=float)
        if mean.shape != (n,) or cov.shape != (n, n):
            raise ValueError(f"prior must be mean ({n},) and covariance ({n}, {n}); "
                             f"got {mean.shape} and {cov.shape}")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            raise ValueError("prior mean and covariance must be finite")
        t0 = float(t0)
        if not np.isfinite(t0):
            raise ValueError(f"t0 must be finite, got {t0}")
        cov = 0.5 * (cov + cov.T)
        if not self._model_checked:
            validate_model(self.model, mean, cov, t0)
            self._model_checked = True
        self.time = t0
        if self._observability is not None:
            self._observability.reset(mean, cov)
        return mean, cov

    @property
    def sensor_state_dim(self) -> int:
        """The state dimension sensors see (the user's: a filter that appends states of its own, such as
        model-error compensation, says how many it keeps for the user)."""
        return self.model.state_dim

    def _sensor_for(self, sensor: Sensor | None) -> Sensor:
        """The sensor an update uses, on the filter's own state: the model's own when None; a user's
        sensor padded with zero Jacobian columns for the states the filter appends."""
        if sensor is None:
            return self._own_sensor
        if self.sensor_state_dim < self.model.state_dim:
            # one wrapper per user sensor, so that the observability tracker's log sees one sensor and
            # rebuilds its Jacobians in one call per sensor, not one per logged update; the wrapper holds
            # the sensor, so its id is not reused while cached (a few sensors: the cache is emptied past
            # PADDED_SENSORS)
            cache = self.__dict__.setdefault("_padded", {})
            padded = cache.get(id(sensor))
            if padded is None or padded.sensor is not sensor:
                if len(cache) >= PADDED_SENSORS:
                    cache.clear()
                padded = cache[id(sensor)] = Padded(sensor, self.sensor_state_dim, self.model.state_dim)
            return padded
        return sensor

    def _check_measurement(self, y, sensor: Sensor) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(y (m,), measured rows (m,) bool)``; raise ValueError on a malformed shape."""
        y = np.asarray(y, dtype=float)
        if y.shape != (sensor.dim,):
            raise ValueError(f"measurement of sensor {sensor.name!r} must have shape ({sensor.dim},), "
                             f"got {y.shape}")
        return y, np.isfinite(y)

    def _measured_rows(self, y, sensor: Sensor) -> tuple[np.ndarray, np.ndarray, int] | None:
        """Start a Gaussian-type update: ``(y, mask, number of measured rows)``, or None (and a zero
        ``last_log_likelihood``) when nothing is measured."""
        self._require_initialized()
        y, mask = self._check_measurement(y, sensor)
        k = np.count_nonzero(mask)
        if not k:
            self.last_log_likelihood = 0.0
            return None
        return y, mask, k

    @staticmethod
    def _check_dt(dt) -> float:
        dt = float(dt)
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"dt must be finite and non-negative, got {dt}")
        return dt
