"""Named filter configurations: the one table the estimator node, the campaigns and the bench build from.

An entry (:class:`FilterEntry`) is a configuration of one of the filter classes: its short name (the
node's ``filter`` parameter, ``--filters`` of the campaigns, the bench), the label its rows carry in
reports, and ``build(model, n_particles, seed, **options)``. Adding a filter is one :func:`register` call
(or one entry in :data:`ENTRIES`); the node offers it when ``node`` is set, the campaigns and the bench
accept it by name or label.

    from gpf_nav import registry
    flt = registry.make("gpf-paper", model, n_particles=500, seed=0)
    registry.lookup("EKF, oracle-tuned Q").tunes    # -> "ekf"
"""
from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Callable, Mapping

from gpf_nav.filters import (BootstrapPF, CompensatedEKF, EnsembleKF, ExtendedKF, Filter,
                             GeometricProjectionPF, MultipleModelGPF, UnscentedKF)
from gpf_nav.filters.compensated import UNMODELLED_ACCELERATION_STD
from gpf_nav.filters.gating import OUTLIER_GATE, OUTLIER_GATE_LIMIT
from gpf_nav.filters.gpf import OBSERVABILITY_CONSTRAINT
from gpf_nav.filters.interface import N_PARTICLES
from gpf_nav.filters.multiple_model import (COMPENSATION_SCALES, COMPENSATION_TIMES, NARROW_FILTER, NESTING_GATE,
                                            NOMINAL_ACCELERATION_NOISE, NOMINAL_SWITCH_TIME, SIZE_GATE, SWITCH_TIME)
from gpf_nav.models.acceleration_noise import WhiteAccelerationNoise
from gpf_nav.models.state_space import StateSpaceModel

KINDS = ("gpf", "particle", "ensemble", "kalman")
"""``gpf``: a geometric projection particle filter; ``particle``: another weighted-particle filter;
``ensemble``: an ensemble Kalman filter; ``kalman``: a Gaussian filter (no particles)."""

PARTICLE_OPTIONS = frozenset({"resampling", "ess_threshold", "collapse_steps", "regularization"})
"""Options every weighted-particle filter of the table takes."""
GPF_OPTIONS = PARTICLE_OPTIONS | {"reference", "weighting", "metric", "unmodelled_acceleration_std",
                                  "unmodelled_acceleration_time", "kernel_bandwidth", "tempering_ess",
                                  "linearization", "flattening_horizon"}
"""Options every GPF of the table takes (:class:`~gpf_nav.filters.gpf.GeometricProjectionPF`'s)."""

PAPER_GPF = MappingProxyType({"metric": "euclidean", "weighting": "likelihood",
                              "unmodelled_acceleration_std": 0.0})
"""Options of the paper's GPF on top of :class:`GeometricProjectionPF`'s defaults: Euclidean projection,
likelihood weights, no compensation."""
FLATTENING_HORIZON = 100.0
"""The navigation GPF's ``flattening_horizon``, s: on the lunar descent every horizon from 100 to 400 s
kept the covariance honest where the data cannot determine the state, and a single time ahead did not
(docs/results.md, *Honest when the data cannot tell*); 100 s is the cheapest of them."""
NAVIGATION_GPF = MappingProxyType({"linearization": "flattened", "flattening_horizon": FLATTENING_HORIZON})
"""Options of the navigation GPF (``gpf``, the node's default) on top of :class:`GeometricProjectionPF`'s
defaults: the update in the coordinates where the measurement, now and along the flow, is linear
(:mod:`gpf_nav.filters.flattening`)."""


MEMBER_OPTIONS = frozenset({"switch_time", "nominal_switch_time", "compensation_scales", "compensation_times",
                            "nesting_gate", "size_gate", "narrow_filter", "nominal_acceleration_noise"})
"""Options of the multiple-model GPF's members (:class:`MultipleModelGPF`)."""
ONE_MEMBER = MappingProxyType({"compensation_scales": (1.0,), "compensation_times": (1.0,), "nesting_gate": 0.0,
                               "size_gate": 0.0, "nominal_switch_time": 0.0, "nominal_acceleration_noise": 0.0})
"""Member options of ``gpf-pair``: the nominal member on the user's model as it is and one compensated member
sized for the paper's mismatch (0.1 m/s^2, 1e6 s), without the nesting and size gates or the nominal
model's own switch."""


@dataclass(frozen=True)
class FilterEntry:
    """One named filter configuration.

    Attributes:
        name: short name (lower case): the node's ``filter`` parameter, ``--filters``, the bench.
        label: the row label in reports (Monte Carlo table, sweeps, stress); oracle-tuned rows say so.
        build: ``build(model, n_particles, seed, **options) -> Filter``; ``options`` are among ``options``.
        kind: one of :data:`KINDS` (which node parameters apply, whether the filter has particles).
        options: the tuning keywords ``build`` takes; :func:`make` drops the others.
        table: ``"navigation"`` or ``"paper"`` (rows of the default Monte Carlo table, in this order) or
            ``"extra"`` (asked for by name only).
        node: the estimator node offers it (parameter ``filter``).
        node_options: options the node always adds (where its filter differs from the campaigns' row).
        aliases: other short names it answers to.
        tunes: for an oracle-tuned row, the name of the entry whose process noise the campaigns tune over
            the grid (the row is the best member, chosen knowing the truth: not a filter a user can run).
        description: one line for help texts and docs.
    """

    name: str
    label: str
    build: Callable[..., Filter]
    kind: str
    options: frozenset[str] = frozenset()
    table: str = "extra"
    node: bool = False
    node_options: Mapping[str, object] = field(default_factory=dict)
    aliases: tuple[str, ...] = ()
    tunes: str | None = None
    description: str = ""

    @property
    def particles(self) -> bool:
        """A weighted-particle filter (ESS, co-state, resampling)."""
        return self.kind in ("gpf", "particle")

    @property
    def min_particles(self) -> int | None:
        """Fewest particles or members ``build`` accepts (None: it has none)."""
        return {"gpf": 1, "particle": 1, "ensemble": 2}.get(self.kind)


def _gpf(model, n_particles, seed, switch_time=SWITCH_TIME, nominal_switch_time=NOMINAL_SWITCH_TIME,
         compensation_scales=COMPENSATION_SCALES, compensation_times=COMPENSATION_TIMES, nesting_gate=NESTING_GATE,
         size_gate=SIZE_GATE, narrow_filter=NARROW_FILTER, nominal_acceleration_noise=NOMINAL_ACCELERATION_NOISE,
         **options):
    """The multiple model of the nominal and the compensated GPFs, or the GPF on the user's model as it is
    when the compensation is switched off (``unmodelled_acceleration_std`` 0)."""
    if options.get("unmodelled_acceleration_std", UNMODELLED_ACCELERATION_STD) == 0.0:
        return GeometricProjectionPF(model, n_particles, seed=seed, **options)
    return MultipleModelGPF(model, n_particles, switch_time=switch_time, nominal_switch_time=nominal_switch_time,
                            nominal_acceleration_noise=nominal_acceleration_noise, seed=seed,
                            compensation_scales=compensation_scales, compensation_times=compensation_times,
                            nesting_gate=nesting_gate, size_gate=size_gate, narrow_filter=narrow_filter, **options)


def _gpf_variant(**fixed) -> Callable[..., Filter]:
    """``build`` of a :class:`GeometricProjectionPF` with ``fixed`` options (overridable)."""
    return lambda model, n_particles, seed, **options: GeometricProjectionPF(
        model, n_particles, seed=seed, **{**fixed, **options})


def _spf(model, n_particles, seed, **options):
    return BootstrapPF(model, n_particles, seed=seed, **options)


def _ekf(model, n_particles, seed, **options):
    return ExtendedKF(model, seed=seed, **options)


def _ukf(model, n_particles, seed, **options):
    return UnscentedKF(model, seed=seed, **options)


def _enkf(model, n_particles, seed, **options):
    return EnsembleKF(model, n_particles, seed=seed, **options)


def _ekf_white(model, n_particles, seed, **options):
    return ExtendedKF(WhiteAccelerationNoise(model, NOMINAL_ACCELERATION_NOISE), seed=seed, **options)


def _ekf_compensated(**fixed) -> Callable[..., Filter]:
    return lambda model, n_particles, seed, **options: CompensatedEKF(model, seed=seed, **{**fixed, **options})


ENTRIES: dict[str, FilterEntry] = {}
"""Every entry by name, in table order (:func:`register` adds to it)."""


def register(entry: FilterEntry) -> FilterEntry:
    """Add ``entry``; raises ValueError when its name, an alias or its label is taken, or its kind or
    table is unknown."""
    if entry.kind not in KINDS or entry.table not in ("navigation", "paper", "extra"):
        raise ValueError(f"filter {entry.name!r}: kind must be one of {KINDS} and table navigation, paper "
                         f"or extra; got {entry.kind!r}, {entry.table!r}")
    taken = {key for e in ENTRIES.values() for key in (e.name, e.label, *e.aliases)}
    clash = taken & {entry.name, entry.label, *entry.aliases}
    if clash:
        raise ValueError(f"filter {entry.name!r}: {sorted(clash)} already registered")
    ENTRIES[entry.name] = entry
    return entry


for _entry in (
    FilterEntry("gpf", "GPF navigation (default)",
                lambda model, n_particles, seed, **options: _gpf(
                    model, n_particles, seed, **{**NAVIGATION_GPF, **options}),
                "gpf", GPF_OPTIONS | MEMBER_OPTIONS, "navigation", node=True, aliases=("gpf-mm", "gpf-ladder"),
                description="the multiple-model GPF: navigation-grade GPFs (cloud metric, exact weights, "
                            "tempering, the update flattened along the flow) on the nominal model, its process "
                            "noise widened by a white acceleration of 1e-5 m^2/s^3, and on a compensated model "
                            "of 0.1 m/s^2, a compensated EKF of 2e-3 m/s^2, with the nesting and size gates; the "
                            "node's default"),
    FilterEntry("gpf-pair", "GPF navigation, one compensated member",
                lambda model, n_particles, seed, **options: _gpf(
                    model, n_particles, seed, **{**NAVIGATION_GPF, **options, **ONE_MEMBER}),
                "gpf", GPF_OPTIONS | {"switch_time"},
                description="gpf with the nominal member and one compensated member (0.1 m/s^2, 1e6 s), "
                            "no nesting gate: sized for the paper's mismatch, overconfident under a force "
                            "far below it (the Moon's J2)"),
    FilterEntry("ekf-comp", "EKF + compensation", _ekf_compensated(), "kalman", table="navigation",
                description="EKF with the same unmodelled-acceleration compensation and tuning as gpf"),
    FilterEntry("ekf-oracle", "EKF, oracle-tuned Q", _ekf, "kalman", table="navigation", tunes="ekf",
                description="the EKF whose process noise is the best of the grid for the truth"),
    FilterEntry("ukf-oracle", "UKF, oracle-tuned Q", _ukf, "kalman", table="navigation", tunes="ukf",
                description="the UKF whose process noise is the best of the grid for the truth"),
    FilterEntry("gpf-paper", "GPF (innovation, likelihood)", _gpf_variant(reference="innovation", **PAPER_GPF),
                "gpf", GPF_OPTIONS, "paper",
                description="the paper's GPF as its experiments run it (the reference row of Table 1)"),
    FilterEntry("gpf-printed", "GPF as printed (increment, likelihood)",
                _gpf_variant(reference="increment", **PAPER_GPF), "gpf", GPF_OPTIONS, "paper",
                description="the paper's GPF as its equations are printed (increment reference)"),
    FilterEntry("gpf-exact", "GPF exact (innovation, corrected)",
                _gpf_variant(reference="innovation", **{**PAPER_GPF, "weighting": "corrected"}), "gpf",
                GPF_OPTIONS, "paper", description="the paper's GPF with exact (corrected) weights"),
    FilterEntry("spf", "SPF", _spf, "particle",
                PARTICLE_OPTIONS | {"compute_costate", "observability_constraint"}, "paper", node=True,
                node_options={"observability_constraint": OBSERVABILITY_CONSTRAINT},
                description="the bootstrap particle filter (the paper's SPF); the node's keeps the prior "
                            "along the directions the data have not determined"),
    FilterEntry("ekf", "EKF", _ekf, "kalman", table="paper", node=True, description="extended Kalman filter"),
    FilterEntry("ukf", "UKF", _ukf, "kalman", frozenset({"alpha", "beta", "kappa"}), "paper", node=True,
                description="unscented Kalman filter"),
    FilterEntry("enkf", "EnKF", _enkf, "ensemble", table="paper", node=True,
                description="ensemble Kalman filter"),
    FilterEntry("gpf-single", "GPF single model (compensated)", _gpf_variant(), "gpf",
                GPF_OPTIONS | {"nominal_prior"}, node=True,
                description="one navigation-grade GPF on the compensated model, averaged with the nominal "
                            "hypothesis by Savage-Dickey"),
    FilterEntry("gpf-mean", "GPF navigation, mean-linearised update",
                lambda model, n_particles, seed, **options: _gpf(model, n_particles, seed, **{**options, **ONE_MEMBER}),
                "gpf", GPF_OPTIONS | {"switch_time"},
                description="gpf-pair with the measurement linearised once at each member's mean (linearization "
                            "mean; it narrows what the data cannot see)"),
    FilterEntry("gpf-qmetric", "GPF Q-metric (innovation, corrected, eps=1)",
                _gpf_variant(reference="innovation", weighting="corrected", metric="process_noise",
                             regularization=1.0, unmodelled_acceleration_std=0.0), "gpf", GPF_OPTIONS,
                description="GPF projecting in the process-noise metric, regularization 1, exact weights"),
    FilterEntry("ekf-comp-gated", "EKF + compensation, gated",
                _ekf_compensated(outlier_gate=OUTLIER_GATE, outlier_gate_limit=OUTLIER_GATE_LIMIT), "kalman",
                description="ekf-comp with the GPF's innovation gate (same gate and limit)"),
    FilterEntry("ekf-white", "EKF + white acceleration", _ekf_white, "kalman",
                description="EKF on the model with gpf's nominal white acceleration added to its process noise "
                            "(nominal_acceleration_noise, 1e-5 m^2/s^3)"),
):
    register(_entry)


def lookup(key: str) -> FilterEntry:
    """The entry whose name, alias (any case) or label is ``key``; ValueError naming the known ones."""
    for entry in ENTRIES.values():
        if key == entry.label or key.lower() in (entry.name, *entry.aliases):
            return entry
    raise ValueError(f"unknown filter {key!r}; known: "
                     + ", ".join(f"{e.name} = {e.label}" for e in ENTRIES.values()))


def label(key: str) -> str:
    """The report label of the filter ``key`` (name, alias or label)."""
    return lookup(key).label


def make(key: str, model: StateSpaceModel, n_particles: int = N_PARTICLES, seed=None, **options) -> Filter:
    """Build the filter ``key`` (name, alias or label) on ``model`` with ``n_particles`` particles or
    members (ignored by the Gaussian filters) and ``seed``; options the entry does not take are dropped."""
    entry = lookup(key)
    return entry.build(model, n_particles, seed, **{k: v for k, v in options.items() if k in entry.options})


def node_names() -> tuple[str, ...]:
    """The names (aliases included) the estimator node accepts for its ``filter`` parameter."""
    return tuple(n for e in ENTRIES.values() if e.node for n in (e.name, *e.aliases))


def short_names() -> tuple[str, ...]:
    """Every short name and alias, in table order."""
    return tuple(n for e in ENTRIES.values() for n in (e.name, *e.aliases))


def labels(*tables: str) -> tuple[str, ...]:
    """Labels of the entries in ``tables`` (``navigation``, ``paper``, ``extra``), in table order."""
    return tuple(e.label for e in ENTRIES.values() if e.table in tables)
