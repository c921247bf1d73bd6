"""The state-space model interface every filter in gpf_nav runs on.

A model describes, batched over particles (arrays shaped ``(N, n)``):

* the nominal drift ``f(x, t, u)`` of ``dx = f dt + G dB`` and its mean transition over ``dt``,
* the process-noise covariance ``Q(dt)`` of that transition,
* the measurement ``h(x)``, its Jacobian ``H(x)`` shaped ``(N, m, n)`` and the noise covariance ``R``,
* a residual hook ``y - h(x)`` that wraps angular components to (-pi, pi].

Filters never assume more than this, so a user model only has to subclass :class:`StateSpaceModel`.

Time: every ``t`` a filter passes is its elapsed time in seconds since ``initialize(mean, cov, t0)``
(``t0`` defaults to 0): the start of the interval for ``drift``, ``transition``, its Jacobian and
``process_noise``, the time of the measurement for ``measure`` and its Jacobian. ``process_noise`` and
the measurement methods may leave ``t`` out of their signature (a time-invariant ``Q`` or ``h``): the
class then accepts and ignores it, so models written before ``t`` was passed keep working.
"""
from __future__ import annotations

import functools
import inspect
from abc import ABC, abstractmethod

import numpy as np

from gpf_nav.kernels.angles import wrap_columns

_TWO_PI = 2.0 * np.pi


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles to (-pi, pi]."""
    return a - _TWO_PI * np.ceil((a - np.pi) * (1.0 / _TWO_PI))


@functools.lru_cache(maxsize=16)
def _angle_columns(angular: bytes) -> np.ndarray | None:
    """The indices of the angular components of the mask ``angular`` (its bytes: cached, the residual
    runs at every step); None when there are none."""
    index = np.flatnonzero(np.frombuffer(angular, dtype=bool))
    return index if index.size else None


_TIME_OPTIONAL = ("process_noise", "measure", "measurement_jacobian", "measure_and_jacobian")
"""Methods whose ``t`` argument a model may leave out of its signature."""


def _ignoring_time(method):
    """``method(self, a)`` as ``method(self, a, t=0.0)``, marked ``time_invariant``."""
    @functools.wraps(method)
    def with_time(self, a, t=0.0):
        return method(self, a)
    del with_time.__wrapped__  # the signature shown is the one with ``t``
    with_time.time_invariant = True
    return with_time


def time_invariant(method) -> bool:
    """Whether a model method (e.g. ``type(model).process_noise``) ignores its ``t`` argument."""
    return getattr(method, "time_invariant", False)


class StateSpaceModel(ABC):
    """A continuous-time state-space model ``dx = f(x,t,u) dt + G dB``, ``y = h(x) + v``.

    Attributes:
        state_dim: n, the state dimension.
        measurement_dim: m, the measurement dimension.
        angular: boolean mask ``(m,)`` of measurement components that are angles (residuals wrapped).
        position_index: indices of the state components that are a position (used by ROS adapters and
            metrics; may be empty).
        velocity_index: indices of the velocity components (may be empty).
        measured_state_index: indices of the state components ``h`` depends on (the other columns of
            ``H`` are zero); None means all. Lets the projection skip structural zeros.
        orthogonal_jacobian_rows: the rows of ``H`` are mutually orthogonal everywhere (true of
            range/azimuth/elevation, the gradients of spherical coordinates); lets the projection
            replace its small solve by a division when ``R`` is diagonal.
        base_state_dim: the leading states that are the user's own model's (:attr:`state_dim` unless the
            model appends states of its own, as the compensation and the sensor-bias models do); the
            GPF's flattened coordinates move these only.

    A discrete-time model (``x_{k+1} = F(x_k, k) + w_k``) is written as ``transition`` ignoring ``dt``
    (the filter is then driven with ``predict(1.0)``, so ``t`` counts steps), ``process_noise`` the
    covariance of ``w_k``, and ``drift`` the per-step increment ``F(x) - x`` (used only by the GPF's
    ``increment`` reference). See ``docs/examples/bearings_only.py``.
    """

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        for name in _TIME_OPTIONAL:
            method = cls.__dict__.get(name)
            if callable(method) and "t" not in inspect.signature(method).parameters:
                setattr(cls, name, _ignoring_time(method))

    state_dim: int
    measurement_dim: int
    angular: np.ndarray
    position_index: tuple[int, ...] = ()
    velocity_index: tuple[int, ...] = ()
    measured_state_index: tuple[int, ...] | None = None
    orthogonal_jacobian_rows: bool = False

    @property
    def base_state_dim(self) -> int:
        """The leading states of the user's own model: all of them, for a model that appends none."""
        return self.state_dim

    @abstractmethod
    def drift(self, x: np.ndarray, t: float = 0.0, u: np.ndarray | None = None) -> np.ndarray:
        """Nominal drift ``f(x, t, u)``: ``(N, n) -> (N, n)``."""

    @abstractmethod
    def transition(self, x: np.ndarray, dt: float, t: float = 0.0,
                   u: np.ndarray | None = None) -> np.ndarray:
        """Mean transition: the noise-free flow of the drift over ``dt``, ``(N, n) -> (N, n)``."""

    @abstractmethod
    def transition_jacobian(self, x: np.ndarray, dt: float, t: float = 0.0,
                            u: np.ndarray | None = None) -> np.ndarray:
        """Jacobian of :meth:`transition` with respect to ``x``: ``(N, n) -> (N, n, n)``."""

    def transition_chain(self, x: np.ndarray, dt: np.ndarray, t: np.ndarray, u: list) -> np.ndarray:
        """``(K + 1, n)``: the state ``x`` ``(n,)`` and after each of ``K`` :meth:`transition` calls in turn, the
        ``k``-th over ``dt[k]`` from ``t[k]`` (``(K,)`` each) with the input ``u[k]`` (None: none): how the
        observability tracker carries its reference back. The default makes the calls; a model overrides it
        to make them in one, with the same numbers."""
        out = np.empty((len(dt) + 1, x.size))
        out[0] = x
        for k, (step, start, inputs) in enumerate(zip(dt, t, u)):
            out[k + 1] = self.transition(out[k:k + 1], float(step), float(start), inputs)[0]
        return out

    def transition_jacobian_along(self, x: np.ndarray, dt: np.ndarray, t: np.ndarray, u: list) -> np.ndarray:
        """Jacobians ``(K, n, n)`` of :meth:`transition` at the ``K`` states ``x`` ``(K, n)`` of a trajectory,
        each over its own ``dt[k]`` from its own ``t[k]`` (``(K,)`` each) with its own input ``u[k]`` (None:
        none): what the observability tracker needs to rebuild its recursions. The default calls
        :meth:`transition_jacobian` once per state; a model overrides it to do them in one call, with the same
        numbers."""
        out = np.empty((len(dt), self.state_dim, self.state_dim))
        for k, (step, start, inputs) in enumerate(zip(dt, t, u)):
            out[k] = self.transition_jacobian(x[k:k + 1], float(step), float(start), inputs)[0]
        return out

    @abstractmethod
    def process_noise(self, dt: float, t: float = 0.0) -> np.ndarray:
        """Covariance ``(n, n)`` of the state noise accumulated over ``[t, t + dt]``.

        Filters cache it per ``dt`` unless the model's signature takes ``t`` (then per ``(dt, t)``)."""

    @abstractmethod
    def measure(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Noise-free measurement ``h(x, t)``: ``(N, n) -> (N, m)``."""

    @abstractmethod
    def measurement_jacobian(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Measurement Jacobian ``H(x, t)``: ``(N, n) -> (N, m, n)``."""

    def measurement_jacobian_along(self, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Measurement Jacobians ``(K, m, n)`` at the ``K`` states ``x`` ``(K, n)``, each at its own time
        ``t[k]`` (the observability tracker's rebuild). The default calls :meth:`measurement_jacobian` once
        per state; a model overrides it to do them in one call, with the same numbers."""
        out = np.empty((len(t), self.measurement_dim, self.state_dim))
        for k, time in enumerate(t):
            out[k] = self.measurement_jacobian(x[k:k + 1], float(time))[0]
        return out

    @property
    def time_varying_noise(self) -> bool:
        """Whether ``process_noise`` depends on ``t`` (its signature takes ``t``): filters then cache
        ``Q`` per ``(dt, t)`` instead of per ``dt``. A model that wraps another delegates this."""
        return not time_invariant(type(self).process_noise)

    def compensation_frame(self, x: np.ndarray) -> np.ndarray | None:
        """Local frame an estimated unmodelled acceleration is carried in (dynamic model compensation,
        :mod:`gpf_nav.models.compensation`): ``(N, n) -> (N, p, p)`` orthonormal matrices whose columns are
        the frame's axes in the coordinates of the ``p`` velocity components, or None (the default): the
        state's own fixed axes. A model whose unmodelled forces keep their direction in a moving frame (an
        orbit's radial / along-track / cross-track axes, a vehicle's body axes) returns that frame, so the
        compensation need not re-learn a force each time the frame turns."""
        return None

    def pushed_transition(self, x: np.ndarray, dt: float, t: float, u, a: np.ndarray, velocity_gain: float,
                          position_gain: float, driven: np.ndarray, integrated: np.ndarray, out: np.ndarray) -> bool:
        """Optional fast path of the compensated transition (:mod:`gpf_nav.models.compensation`): write into
        ``out`` ``(n, N)`` the transition of the particle-last states ``x`` ``(n, N)`` plus the acceleration
        ``a`` ``(p, N)``, given in :meth:`compensation_frame` at ``x``, times ``velocity_gain`` on the rows
        ``driven`` ``(p,)`` and times ``position_gain`` on the rows ``integrated`` (empty: none), and return
        True. False (the default): the compensation does it from :meth:`transition` and
        :meth:`compensation_frame`, with the same numbers."""
        return False

    def pushed_transition_chain(self, x: np.ndarray, a: np.ndarray, dt: np.ndarray, t: np.ndarray, u: list,
                                velocity_gain: np.ndarray, position_gain: np.ndarray, decay: np.ndarray,
                                driven: np.ndarray, integrated: np.ndarray) -> np.ndarray | None:
        """Optional fast path of the compensated :meth:`transition_chain`: ``(K + 1, n + p)``, the state ``x``
        ``(n,)`` with the acceleration ``a`` ``(p,)`` and after each of ``K`` compensated transitions in turn
        (:meth:`pushed_transition` with the ``k``-th of ``dt``, ``t``, ``u``, ``velocity_gain`` and
        ``position_gain``, then ``a`` times ``decay[k]``). None (the default): the compensation makes the
        calls."""
        return None

    def compensation_push_derivative(self, x: np.ndarray, a: np.ndarray, relative_step: float
                                     ) -> np.ndarray | None:
        """Optional fast path of the compensated transition's Jacobian (:mod:`gpf_nav.models.compensation`):
        ``d(F(x) a) / dx`` ``(N, p, n)`` of the acceleration ``a`` ``(N, p)`` turned by
        :meth:`compensation_frame` at the states ``x`` ``(N, n)``, by central differences with the steps
        ``relative_step * max(|x|, 1)``. None (the default): the compensation differences
        :meth:`compensation_frame` itself, with the same numbers."""
        return None

    def measure_and_jacobian(self, x: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """``(h(x, t) (N, m), H(x, t) (N, m, n))`` together; override to share work between the two."""
        return self.measure(x, t), self.measurement_jacobian(x, t)

    @abstractmethod
    def measurement_noise(self) -> np.ndarray:
        """Measurement-noise covariance ``R`` ``(m, m)``."""

    def residual(self, y: np.ndarray, y_pred: np.ndarray) -> np.ndarray:
        """Measurement residual ``y - y_pred`` with angular components wrapped to (-pi, pi].

        Shapes broadcast: ``(m,)`` against ``(N, m)`` gives ``(N, m)``.
        """
        return wrapped_residual(y, y_pred, self.angular)

    def measurement_residual(self, y: np.ndarray, x: np.ndarray, t: float = 0.0, reverse: bool = False
                             ) -> np.ndarray:
        """The residual ``(N, m)`` of the measurement ``y`` ``(m,)`` at the states ``x`` ``(N, n)``:
        :meth:`residual` of ``y`` and :meth:`measure`, or, ``reverse``, of :meth:`measure` and ``y`` (``h(x) -
        y``, the departure from a measurement ``y``). A model overrides it to do both in one pass, with the
        same numbers."""
        h = self.measure(x, t)
        return self.residual(h, y) if reverse else self.residual(y, h)

    def measurement_mean(self, y: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Weighted mean of measurements ``(K, m)`` with weights ``(K,)``; angles by circular mean."""
        return measurement_mean(y, weights, self.angular)


def wrapped_residual(y: np.ndarray, y_pred: np.ndarray, angular: np.ndarray) -> np.ndarray:
    """``y - y_pred`` (shapes broadcast) with the components of the mask ``angular`` ``(m,)`` wrapped to
    (-pi, pi]: the residual of models and sensors (:mod:`gpf_nav.sensors`)."""
    r = np.asarray(y, dtype=float) - y_pred
    angles = _angle_columns(np.asarray(angular, dtype=bool).tobytes())
    if angles is not None:  # in place, through a two-dimensional view of the new array
        if r.ndim > 2:
            r = np.ascontiguousarray(r)  # (its reshape is then a view)
        wrap_columns(r.reshape(-1, r.shape[-1]), angles)
    return r


def measurement_mean(y: np.ndarray, weights: np.ndarray, angular: np.ndarray) -> np.ndarray:
    """Weighted mean of measurements ``(K, m)`` with weights ``(K,)``; the components of the mask
    ``angular`` ``(m,)`` by circular mean."""
    mean = np.einsum("k,km->m", weights, y)  # not BLAS: K may be an ensemble size
    if np.any(angular):
        a = y[:, angular]
        mean[angular] = np.arctan2(np.einsum("k,km->m", weights, np.sin(a)),
                                   np.einsum("k,km->m", weights, np.cos(a)))
    return mean
