"""Filter construction from node parameters: ``make_filter(name, model, **options)``.

Maps the estimator's parameter names to the core constructors' arguments and refuses invalid values
with a message that names the parameter. No rclpy here.
"""
from __future__ import annotations

import math

import numpy as np

from gpf_nav import registry
from gpf_nav.filters.compensated import UNMODELLED_ACCELERATION_STD, UNMODELLED_ACCELERATION_TIME
from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.filters.model_averaging import NOMINAL_PRIOR
from gpf_nav.filters.multiple_model import (COMPENSATION_SCALES, COMPENSATION_TIMES, NARROW_FILTER, NARROW_FILTERS,
                                            NESTING_GATE, NOMINAL_ACCELERATION_NOISE, NOMINAL_SWITCH_TIME, SIZE_GATE,
                                            SWITCH_TIME)
from gpf_nav.models.gravity import FIELDS, make_field
from gpf_nav.models.lunar import LunarDescentModel

FILTERS = registry.node_names()
"""The node's filters (:func:`gpf_nav.registry.node_names`): ``gpf`` is the multiple-model GPF (``gpf-mm``
an alias); ``gpf-single`` one compensated GPF."""


def make_filter(name: str, model, *, n_particles: int = N_PARTICLES, seed: int | None = 0,
                reference: str = "innovation", weighting: str = "corrected",
                metric: str = "cloud", regularization: float = 0.0,
                unmodelled_acceleration_std: float = UNMODELLED_ACCELERATION_STD,
                unmodelled_acceleration_time: float = UNMODELLED_ACCELERATION_TIME,
                nominal_prior: float = NOMINAL_PRIOR, kernel_bandwidth: float = 0.0,
                flattening_horizon: float = registry.FLATTENING_HORIZON, model_switch_time: float = SWITCH_TIME,
                nominal_switch_time: float = NOMINAL_SWITCH_TIME,
                nominal_acceleration_noise: float = NOMINAL_ACCELERATION_NOISE,
                compensation_scales=COMPENSATION_SCALES, compensation_times=COMPENSATION_TIMES,
                nesting_gate: float = NESTING_GATE, size_gate: float = SIZE_GATE, narrow_filter: str = NARROW_FILTER,
                collapse_steps: int = 0,
                resampling: str = "systematic", ess_threshold: float = 0.5, compute_costate: bool = True,
                ukf_alpha: float = 1e-3, ukf_beta: float = 2.0, ukf_kappa: float = 0.0):
    """Build the node's filter ``name`` (one of :data:`FILTERS`, an entry of :mod:`gpf_nav.registry`) on
    ``model``.

    ``seed < 0`` (or None) draws a random seed; ``regularization`` and ``kernel_bandwidth`` 0 take the
    filter's defaults. Options a filter does not use are ignored (for example ``n_particles`` for the
    EKF); the entry's ``node_options`` are added. With the defaults, ``make_filter("gpf", model)`` is
    ``MultipleModelGPF(model, **registry.NAVIGATION_GPF)`` (``gpf-mm`` the same), or the nominal
    ``GeometricProjectionPF`` when ``unmodelled_acceleration_std`` is 0 (no second model); ``make_filter("gpf-single", model)`` is
    ``GeometricProjectionPF(model)`` (``nominal_prior`` applies to it only). Raises ValueError naming the
    offending parameter.
    """
    errors = check_filter_options(name, n_particles=n_particles, reference=reference,
                                  weighting=weighting, regularization=regularization,
                                  resampling=resampling, ess_threshold=ess_threshold,
                                  metric=metric, collapse_steps=collapse_steps, ukf_alpha=ukf_alpha,
                                  ukf_kappa=ukf_kappa, state_dim=model.state_dim,
                                  unmodelled_acceleration_std=unmodelled_acceleration_std,
                                  unmodelled_acceleration_time=unmodelled_acceleration_time,
                                  nominal_prior=nominal_prior, kernel_bandwidth=kernel_bandwidth,
                                  flattening_horizon=flattening_horizon, model_switch_time=model_switch_time,
                                  nominal_switch_time=nominal_switch_time,
                                  nominal_acceleration_noise=nominal_acceleration_noise,
                                  compensation_scales=compensation_scales, compensation_times=compensation_times,
                                  nesting_gate=nesting_gate, size_gate=size_gate, narrow_filter=narrow_filter)
    if errors:
        raise ValueError("; ".join(errors))
    seed = None if seed is None or int(seed) < 0 else int(seed)
    options = dict(reference=reference, weighting=weighting, metric=metric,
                   unmodelled_acceleration_std=unmodelled_acceleration_std,
                   unmodelled_acceleration_time=unmodelled_acceleration_time, nominal_prior=nominal_prior,
                   switch_time=model_switch_time, nominal_switch_time=nominal_switch_time,
                   nominal_acceleration_noise=float(nominal_acceleration_noise),
                   compensation_scales=_floats(compensation_scales), compensation_times=_floats(compensation_times),
                   nesting_gate=float(nesting_gate), size_gate=float(size_gate), narrow_filter=narrow_filter,
                   resampling=resampling,
                   ess_threshold=ess_threshold,
                   collapse_steps=int(collapse_steps), compute_costate=bool(compute_costate),
                   alpha=ukf_alpha, beta=ukf_beta, kappa=ukf_kappa)
    if regularization:
        options["regularization"] = regularization
    if kernel_bandwidth:
        options["kernel_bandwidth"] = kernel_bandwidth
    options["flattening_horizon"] = flattening_horizon  # (gpf-single, mean-linearised, has no use for it)
    entry = registry.lookup(name)
    return registry.make(name, model, int(n_particles), seed, **options, **entry.node_options)


def check_filter_options(name, *, n_particles, reference, weighting, regularization, resampling,
                         ess_threshold, metric="cloud", collapse_steps=0, ukf_alpha=1e-3,
                         ukf_kappa=0.0, state_dim=6, unmodelled_acceleration_std=0.0,
                         unmodelled_acceleration_time=1.0, nominal_prior=0.0, kernel_bandwidth=0.0,
                         flattening_horizon=0.0, model_switch_time=SWITCH_TIME,
                         nominal_switch_time=NOMINAL_SWITCH_TIME,
                         nominal_acceleration_noise=NOMINAL_ACCELERATION_NOISE,
                         compensation_scales=COMPENSATION_SCALES,
                         compensation_times=COMPENSATION_TIMES, nesting_gate=NESTING_GATE, size_gate=SIZE_GATE,
                         narrow_filter=NARROW_FILTER) -> list[str]:
    """Human-readable errors for invalid filter parameters (empty when all are valid)."""
    from gpf_nav import resampling as resamplers
    from gpf_nav.filters.gpf import METRICS, REFERENCES, WEIGHTINGS
    errors = []
    names = registry.node_names()
    if name not in names:
        errors.append(f"parameter 'filter' = {name!r} is not a known filter; choose one of {', '.join(names)}")
        return errors
    entry = registry.lookup(name)
    minimum = entry.min_particles
    if minimum is not None:
        if not isinstance(n_particles, (int, np.integer)) or n_particles < minimum:
            errors.append(f"parameter 'n_particles' = {n_particles!r} must be an integer >= {minimum}")
    if entry.particles:
        if not (isinstance(ess_threshold, (int, float)) and 0.0 < ess_threshold <= 1.0):
            errors.append(f"parameter 'ess_threshold' (tau) = {ess_threshold!r} must lie in (0, 1]")
        if resampling not in resamplers.SCHEMES:
            errors.append(f"parameter 'resampling' = {resampling!r} must be one of "
                          f"{', '.join(sorted(resamplers.SCHEMES))}")
        if not (math.isfinite(regularization) and regularization >= 0.0):
            errors.append(f"parameter 'regularization' = {regularization!r} must be >= 0 (0: default)")
        if not isinstance(collapse_steps, (int, np.integer)) or collapse_steps < 0:
            errors.append(f"parameter 'collapse_steps' = {collapse_steps!r} must be an integer >= 0")
    if "switch_time" in entry.options:
        if name == "gpf-mm" and not unmodelled_acceleration_std > 0.0:
            errors.append(f"parameter 'unmodelled_acceleration_std' = {unmodelled_acceleration_std!r} must be "
                          "positive for gpf-mm (its second model is the compensated one) [m/s^2]")
        if not (math.isfinite(model_switch_time) and model_switch_time > 0.0):
            errors.append(f"parameter 'model_switch_time' = {model_switch_time!r} must be positive [s]")
        if not (math.isfinite(nominal_switch_time) and nominal_switch_time >= 0.0):
            errors.append(f"parameter 'nominal_switch_time' = {nominal_switch_time!r} must be >= 0 (0: none) [s]")
        if not (math.isfinite(nominal_acceleration_noise) and nominal_acceleration_noise >= 0.0):
            errors.append(f"parameter 'nominal_acceleration_noise' = {nominal_acceleration_noise!r} must be >= 0 "
                          "(0: none) [m^2/s^3]")
        scales, times = _floats(compensation_scales), _floats(compensation_times)
        if not scales or scales[-1] != 1.0 or any(not a < b for a, b in zip((0.0,) + scales, scales)):
            errors.append(f"parameter 'compensation_scales' = {list(scales)!r} must increase from above 0 to 1")
        if len(times) != len(scales) or not times or times[-1] != 1.0 or not all(0.0 < t < math.inf for t in times):
            errors.append(f"parameter 'compensation_times' = {list(times)!r} must be positive, one per "
                          "compensation scale, the last 1")
        if not (isinstance(nesting_gate, (int, float)) and 0.0 <= nesting_gate < 1.0):
            errors.append(f"parameter 'nesting_gate' = {nesting_gate!r} must lie in [0, 1)")
        if not (isinstance(size_gate, (int, float)) and 0.0 <= size_gate < 1.0):
            errors.append(f"parameter 'size_gate' = {size_gate!r} must lie in [0, 1)")
        if narrow_filter not in NARROW_FILTERS:
            errors.append(f"parameter 'narrow_filter' = {narrow_filter!r} must be one of {', '.join(NARROW_FILTERS)}")
    if entry.kind == "gpf":
        if reference not in REFERENCES:
            errors.append(f"parameter 'reference' = {reference!r} must be one of {', '.join(REFERENCES)}")
        if weighting not in WEIGHTINGS:
            errors.append(f"parameter 'weighting' = {weighting!r} must be one of {', '.join(WEIGHTINGS)}")
        if metric not in METRICS:
            errors.append(f"parameter 'metric' = {metric!r} must be one of {', '.join(METRICS)}")
        elif metric == "cloud" and reference == "increment":
            errors.append("parameter 'reference' = 'increment' needs metric 'euclidean' or 'process_noise'")
        if not (math.isfinite(unmodelled_acceleration_std) and unmodelled_acceleration_std >= 0.0):
            errors.append(f"parameter 'unmodelled_acceleration_std' = {unmodelled_acceleration_std!r} "
                          "must be >= 0 [m/s^2]")
        if not (math.isfinite(unmodelled_acceleration_time) and unmodelled_acceleration_time > 0.0):
            errors.append(f"parameter 'unmodelled_acceleration_time' = {unmodelled_acceleration_time!r} "
                          "must be positive [s]")
        if not (isinstance(nominal_prior, (int, float)) and 0.0 <= nominal_prior < 1.0):
            errors.append(f"parameter 'nominal_prior' = {nominal_prior!r} must lie in [0, 1)")
        if not (math.isfinite(kernel_bandwidth) and 0.0 <= kernel_bandwidth < 1.0):
            errors.append(f"parameter 'kernel_bandwidth' = {kernel_bandwidth!r} must lie in [0, 1) (0: optimal)")
        if not (math.isfinite(flattening_horizon) and flattening_horizon >= 0.0):
            errors.append(f"parameter 'flattening_horizon' = {flattening_horizon!r} must be >= 0 [s]")
    if "alpha" in entry.options:
        if not ukf_alpha > 0.0:
            errors.append(f"parameter 'ukf_alpha' = {ukf_alpha!r} must be positive")
        if not state_dim + ukf_kappa > 0.0:
            errors.append(f"parameter 'ukf_kappa' = {ukf_kappa!r} must exceed -{state_dim}")
    return errors


def _floats(values) -> tuple[float, ...]:
    """A list parameter (or one number) as a tuple of floats."""
    return tuple(np.atleast_1d(np.asarray(values, dtype=float)).tolist())


def make_lunar_model(*, mu: float, station, range_noise_std: float, angle_noise_std: float,
                     accel_noise_density: float, max_step: float, gravity_field: str = "point",
                     gravity_epoch: float = 0.0) -> LunarDescentModel:
    """The lunar model from node parameters, refusing invalid values with the parameter's name."""
    errors = []
    if not (math.isfinite(mu) and mu > 0):
        errors.append(f"parameter 'mu' = {mu!r} must be a positive gravitational parameter [m^3/s^2]")
    station = list(station)
    if len(station) != 3 or not all(math.isfinite(c) for c in station):
        errors.append(f"parameter 'station' = {station!r} must be three finite coordinates [m]")
    for key, value in (("range_noise_std", range_noise_std), ("angle_noise_std", angle_noise_std),
                       ("max_step", max_step)):
        if not (math.isfinite(value) and value > 0):
            errors.append(f"parameter '{key}' = {value!r} must be positive")
    if not (math.isfinite(accel_noise_density) and accel_noise_density >= 0):
        errors.append(f"parameter 'accel_noise_density' = {accel_noise_density!r} must be >= 0")
    if gravity_field not in FIELDS:
        errors.append(f"parameter 'gravity_field' = {gravity_field!r} must be one of {', '.join(FIELDS)}")
    if not math.isfinite(gravity_epoch):
        errors.append(f"parameter 'gravity_epoch' = {gravity_epoch!r} must be finite [s]")
    if errors:
        raise ValueError("; ".join(errors))
    return LunarDescentModel(mu=mu, station=station, range_noise_std=range_noise_std,
                             angle_noise_std=angle_noise_std, accel_noise_density=accel_noise_density,
                             max_step=max_step, gravity=make_field(gravity_field, mu, gravity_epoch))
