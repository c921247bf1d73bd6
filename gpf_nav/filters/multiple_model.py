"""Interacting multiple models: the GPF on the nominal model and compensated models of several scales.

Model-error compensation (:mod:`gpf_nav.models.compensation`) makes a filter robust to an unmodelled
acceleration, and costs accuracy when there is none: it estimates three extra states that a correct
model does not need. It also has a scale: its prior, the acceleration's stationary standard deviation
``sigma``, says how large a force it expects. A force far below ``sigma`` is not worth the extra states
by the evidence, so the nominal model wins and ignores it, overconfident (the Moon's J2, 4.6e-4 m/s^2,
against a compensation sized for the paper's 9 % gravity mismatch, 0.13 m/s^2); a force far above it
cannot be followed. :class:`MultipleModelGPF` tests the hypotheses instead of assuming one: filters run in
parallel, one on the user's model (``nominal``) and one per compensation scale, with
``sigma_j = compensation_scales[j] * unmodelled_acceleration_std`` and correlation time
``tau_j = compensation_times[j] * unmodelled_acceleration_time``: by default two compensated members, 2e-3
m/s^2 with 400 s and 0.1 m/s^2 with 1e6 s, so that a force of a few mm/s^2 that changes along the orbit
and a mismatch up to 0.2 m/s^2 each have a member of their size, or between two members is the wider
one's (step 5). A Markov chain switches between the ``K`` models with mean sojourn ``switch_time``, a
switch going to each other model alike.

**Forces below every member's size.** That no force acts is never established by the data: a force far
below the measurements' noise (the Moon's J2, 4.6e-4 m/s^2, seen in range, azimuth and elevation) changes
the next measurement by less than the nominal model's narrower prediction gains in evidence, so the nominal
model wins the evidence and, with no process noise for the force, its covariance shrinks below its error
(NEES 40 to 100 over the last third of a J2 descent while it held 97 % of the probability). The nominal
member therefore runs on the user's model with a white acceleration of spectral density
``nominal_acceleration_noise`` added to its process noise
(:class:`~gpf_nav.models.acceleration_noise.WhiteAccelerationNoise`): its covariance holds what such a
force can do between measurements, and, unlike a compensated member of that size, it carries no
acceleration learnt from noise across a gap in the data. ``nominal_switch_time`` > 0 instead (or as well)
switches the nominal model to the narrowest compensated one with that mean sojourn, which keeps a member
whose covariance holds the force in the mixture.

**Which filter each member is.** The nominal member and the widest compensated one are GPFs: between
them they carry the estimate wherever the data leave the state far from linear (a large prior, range
only, no azimuth), and the widest one's co-state is the filter's. The narrower compensated members
(``narrow_filter``) are by default compensated EKFs (:class:`~gpf_nav.filters.compensated.CompensatedEKF`,
with the GPF's innovation gate): a narrow member wins the evidence only for a force of its own small size,
which the data can see, so its posterior is close to Gaussian and the EKF's costs a few per cent of a GPF
member's; where the data leave a direction undetermined, the nesting gate (step 4) keeps a narrow member
only inside the widest GPF's posterior. ``narrow_filter="gpf"`` makes them GPFs too.

Each cycle is Blom's interacting multiple model (IMM):

1. **Mixing**, at the first ``predict`` after an update: with ``mu`` the model probabilities and
   ``p = 1 - exp(-dt / switch_time)`` the switching probability over that ``dt``, ``p_ii = 1 - p`` and
   ``p_ij = p / (K - 1)``, and ``q = (1 - p) (1 - exp(-dt / nominal_switch_time))`` moved from the
   nominal model's ``p_00`` to ``p_01`` (the narrowest compensated model), the predicted probabilities are
   ``c_j = sum_i p_ij mu_i``, and the nominal
   member's cloud is moved (an affine map, :func:`gpf_nav.filters.kernel.match_moments`) to the mean and
   covariance of the mixture ``sum_i mu_{i|0} N(m_i, P_i)``, ``mu_{i|0} = p_i0 mu_i / c_0``. The
   compensated members are not mixed: each model contains the nominal one (``a = 0`` is a state it can
   be in), so a switch to the nominal model needs no hand-over. Mixing them too (Blom's symmetric IMM)
   resets their acceleration towards the compensation's prior whenever the nominal model is the more
   probable, so a small, slowly observable force is never learnt.
2. Each member predicts and updates on its own model.
3. **Model probabilities** ``mu_j ∝ c_j p(y | j)``, ``p(y | j)`` the member's incremental evidence
   (:attr:`~gpf_nav.filters.interface.Filter.last_log_likelihood`: the GPF's from its corrected weights,
   the EKF's Gaussian ``log N(r; 0, S)``), and the filter's evidence ``log sum_j c_j p(y | j)``. A member
   that did
   not weigh the whole measurement (its gate refused a component, or it re-initialised) has no
   evidence comparable with the others': it takes the lowest of theirs, since it found the measurement
   no more probable than the least of the members that used it, and a member whose gate refused takes
   less when its own evidence with the refused components at its gate's edge is less
   (:attr:`~gpf_nav.filters.gating.InnovationGated.refused_log_likelihood`: a refused component lies
   beyond the edge, so that bounds what it would have found). Leaving every probability at ``c``
   instead would let one member that cannot follow the data (a 1e-3 m/s² member under the paper's
   9 % mismatch refuses a component in a quarter of the updates) stop the others' evidence; the lowest
   of the users' alone, with one member using a component that the others refuse, ties them with it
   whatever it found, so members that the data have left would keep their probability while they refuse.
   An outlier that every member refuses still leaves ``mu = c``.
4. **Nesting gate** (``nesting_gate`` > 0), while the data leave a direction of the user's state
   undetermined (the observability report, :attr:`observability`): the widest member's model contains
   every other's, so its posterior should admit their estimates. A member whose estimate of the user's
   state lies outside the widest member's chi-square gate (``d^T P^-1 d`` above the ``nesting_gate``
   quantile, ``n`` degrees of freedom) gets probability 0 for that update, whatever its evidence: where
   the data cannot see a direction (no azimuth), a narrow, fast member explains the error it leaves
   there with a wrong state and would otherwise win, and the dynamics carry that wrong state into the
   directions the data do see, so the gate is on the whole state. Zeroed, not merely denied this
   update's evidence: a refused member keeping its probability keeps its wrong state in the mixture.
   When the data determine every direction the evidence checks every member along all of them and the
   gate is off: there the widest member can be the wrong one (an early gross outlier absorbed in its
   acceleration), and a gate would let it refuse the better members.
   The gate also checks the spread: a compensated member's model contains the nominal one, so along
   each undetermined direction its posterior is at least as wide as the nominal member's. A narrow
   member whose variance there is below :data:`NESTING_SPREAD` of the nominal member's has lost what the
   data never determined (an EKF linearised across a cloud far wider than the measurement's curvature
   allows, e.g. a 20 km prior with range only, collapses along the unseen rotations to a few per cent
   of the prior's variance) and is zeroed too.
5. **Size gate** (``size_gate`` > 0), in every update: a narrow member whose estimated acceleration lies
   beyond the ``size_gate`` quantile of its own prior (``a^T a / sigma_j^2`` above ``chi^2_p``) gets
   probability 0 for that update, like the nesting gate's refusals. Its estimate says the force is of a
   wider member's size: a force beyond about two of a member's sigmas lies inside the next member's
   prior. Without the gate a member too small for the force can still win the evidence (it follows the
   measured part of the force with a shrunk, lagging acceleration) and turn the rest into an error where
   the data are weakest: a 2 % gravity mismatch (0.03 m/s^2) without azimuth, where a 1e-2 m/s^2
   member, its acceleration beyond two of its sigmas, won against the widest member.

The estimate is the mixture ``sum_j mu_j N(m_j, P_j)`` (mean and covariance of the user's state); the
unmodelled acceleration is the mixture of the compensated members' and the nominal model's zero.

It is the default GPF (``make_filter("gpf")``, the node). What it buys and costs on the lunar descent is
measured in ``docs/results.md``: the accuracy of the nominal filter when the model is right, the
compensated filter's when it is not (a force of the size of its compensation), and the
nominal filter's where the compensation cannot be observed (range only), at the cost of two GPFs and
an EKF per narrow member.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

from gpf_nav.filters.compensated import (UNMODELLED_ACCELERATION_STD, UNMODELLED_ACCELERATION_TIME,
                                         CompensatedEKF)
from gpf_nav.filters.gating import OUTLIER_GATE, OUTLIER_GATE_LIMIT
from gpf_nav.filters.gpf import GeometricProjectionPF
from gpf_nav.filters.composite import Composite
from gpf_nav.filters.interface import (CLOUD, COMPENSATION, COSTATE, GATE, MODEL_PROBABILITIES, RESAMPLING,
                                       TEMPERING, N_PARTICLES, Filter)
from gpf_nav.filters.model_averaging import mixture_moments
from gpf_nav.linalg import positive_definite
from gpf_nav.models.acceleration_noise import WhiteAccelerationNoise
from gpf_nav.models.state_space import StateSpaceModel

SWITCH_TIME = 2.0e5
"""Default mean sojourn time of the model chain, s (switching probability 1e-5 per 2 s step)."""
NOMINAL_ACCELERATION_NOISE = 1.0e-5
"""Default spectral density of the white acceleration added to the nominal member's process noise, m^2/s^3
(module docstring, *Forces below every member's size*; 0: the user's model as it is). A constant force
``a`` and this noise move the velocity alike over ``T = q / a^2``: 50 s for the Moon's J2, about 25
measurements of the lunar descent. Under J2 unmodelled, 20 runs each, at 3e-6 m^2/s^3 up to 21 % of the
steps were above the chi-square bound without azimuth; at 1e-5, 1-5 % on three campaign seeds (docs/results.md)."""
NOMINAL_SWITCH_TIME = 0.0
"""Default mean time after which the nominal model switches to the narrowest compensated one, s (0: only
as the chain's other switches; module docstring). Across a long gap in the data the narrowest member
carries the acceleration it learnt from noise (two surface beacons 1 400 s apart), which the nominal
member's white acceleration does not."""
COMPENSATION_SCALES = (0.02, 1.0)
"""Default compensation scales: the compensated members' ``sigma`` as fractions of
``unmodelled_acceleration_std`` (module docstring): with its default 0.1 m/s^2, members of 2e-3 and 0.1
m/s^2, so that a force of a few mm/s^2 that changes along the orbit and the paper's 9 % mismatch (0.13
m/s^2) each have a member of their size; forces below them are the nominal member's white acceleration's.
A force between two members (a 5 mm/s^2 thrust, a 0.02 m/s^2 drag, a 2 % gravity mismatch of 0.03 m/s^2)
is the wider one's: the size gate (step 5) refuses the narrower one, whose estimate says the force is
beyond its prior. A member of 0.03 m/s^2 between them, an EKF, won the evidence against that force
without azimuth, honest but with 1.22 times the widest GPF member's position error (the EKF's
linearisation across a cloud kilometres wide); as a GPF it would cost a third GPF member. A member of
1e-3 m/s^2 and 2e4 s carried the acceleration it learnt from noise across long gaps in the data."""
COMPENSATION_TIMES = (0.0004, 1.0)
"""Default correlation times of the compensated members as fractions of ``unmodelled_acceleration_time``
(with its default 1e6 s: 400 s and 1e6 s). A force of size ``sigma`` changes by about
``sigma sqrt(2 T / tau)`` over a time ``T``: the narrow member follows a force that changes along the
orbit, the widest one learns a constant mismatch and keeps it. Both change at the same pace,
``2 sigma^2 / tau`` (the intensity of the driving noise: 2e-8 m^2/s^5), so that the widest model contains
every other in pace as well as in size (step 4). Where no measurement sees a direction (no azimuth), a
narrow member's acceleration is also what it makes of the error in its state there, and it wins the
evidence by predicting the next measurement well while that state is wrong. A faster member wanders
along that direction inside the widest member's gate (1e-2 m/s^2 at 1e3 s, ten times the widest's pace:
an unmodelled drag in Case 2, 1.42 times the position error); a slower one keeps an acceleration fitted
to an early error for thousands of seconds (1e-2 m/s^2 at 1e4 s, under J2 without azimuth: a run whose
prior error lay at the 1 % tail of its distribution, 2.9 km against the EKF's 260 m, 7 km off for 2 000
s). A small member of short time holds such an acceleration for minutes, and it moves the state by
little."""
NESTING_GATE = 0.999
"""Probability of the chi-square gate by which the widest member's posterior must admit a narrower
member's estimate for that member to keep its probability, while the data leave a direction undetermined
(0: no gate). Without it, where the data cannot see a direction (no azimuth) a small, fast
member explains the error left there with a wrong state and wins the evidence."""
SIZE_GATE = 0.8
"""Probability of the size gate (step 5 of the module docstring; 0: no gate): a narrow member whose estimated
acceleration lies beyond this quantile of its own prior (``a^T a / sigma^2 > chi^2_p``, 2.15 sigmas for
``p = 3``) is refused. Members of the force's size keep theirs well inside it; at 0.99 (3.4 sigmas) the gate
never fired against a 2 % gravity mismatch (0.03 m/s^2), and a 1e-2 m/s^2 member, its acceleration shrunk
and lagging, kept winning there."""
NESTING_SPREAD = 0.5
"""Fraction of the nominal member's variance along each undetermined direction below which a narrow
compensated member is refused by the nesting gate (step 4 of the module docstring). The bound of exact
arithmetic is 1; the half leaves room for the Monte Carlo error of a cloud's variance."""
NARROW_FILTERS = ("ekf", "gpf")
"""Filters the compensated members narrower than the widest can be (module docstring)."""
NARROW_FILTER = "ekf"
"""Default ``narrow_filter``: compensated EKFs (module docstring, *Which filter each member is*)."""


class MultipleModelGPF(Composite):
    """IMM over a nominal and compensated :class:`GeometricProjectionPF` members (module docstring).

    A :class:`~gpf_nav.filters.composite.Composite` whose principal member is :attr:`compensated`: the
    co-state is that member's (:meth:`delegate`); the estimate, the particle diagnostics and the
    unmodelled acceleration are model averages over the members, the gate's count their sum, the
    resampling and tempering counts those of the GPF members.

    Args:
        model: the user's state-space model.
        n_particles: particles of each member.
        switch_time: mean sojourn time of the model chain, s (> 0).
        nominal_acceleration_noise: spectral density of the white acceleration added to the nominal
            member's process noise, m^2/s^3 (>= 0; 0: the user's model as it is; default
            :data:`NOMINAL_ACCELERATION_NOISE`); on the model's position/velocity pairs
            (:class:`~gpf_nav.models.acceleration_noise.WhiteAccelerationNoise`).
        nominal_switch_time: mean time after which the nominal model switches to the narrowest
            compensated one, s (>= 0; 0: no such switch; default :data:`NOMINAL_SWITCH_TIME`).
        compensation_scales: the compensated members' acceleration standard deviations as fractions of
            ``unmodelled_acceleration_std``, increasing, positive, the last 1 (default
            :data:`COMPENSATION_SCALES`).
        compensation_times: their correlation times as fractions of ``unmodelled_acceleration_time``,
            positive, the last 1, one per scale (default :data:`COMPENSATION_TIMES`).
        nesting_gate: probability of the nesting gate in [0, 1) (step 4; 0: none; default
            :data:`NESTING_GATE`).
        size_gate: probability of the size gate in [0, 1) (step 5; 0: none; default :data:`SIZE_GATE`).
        narrow_filter: the filter of the compensated members narrower than the widest, one of
            :data:`NARROW_FILTERS` (default :data:`NARROW_FILTER`): ``ekf`` a
            :class:`~gpf_nav.filters.compensated.CompensatedEKF` with the GPF members' ``outlier_gate`` and
            ``outlier_gate_limit``, ``gpf`` a :class:`GeometricProjectionPF` like the others.
        seed: seed of the members' random streams (spawned from it).
        **options: further options of every member (:class:`GeometricProjectionPF`); the compensation
            options (``unmodelled_acceleration_std`` > 0, ``unmodelled_acceleration_time``) apply to the
            compensated ones.

    Attributes:
        nominal: the member on the user's model, its white acceleration added (a GPF).
        scaled: the compensated members, by increasing ``sigma`` (the widest a GPF, the others
            ``narrow_filter``'s).
        compensated: the widest of them (``sigma = unmodelled_acceleration_std``): its model contains
            every other member's, so its co-state measures what none of them explains.
        model_probabilities: ``(K,)`` probabilities of the nominal model, then of :attr:`scaled`'s.
    """

    def __init__(self, model: StateSpaceModel, n_particles: int = N_PARTICLES, switch_time: float = SWITCH_TIME,
                 seed: int | np.random.Generator | None = None, nominal_switch_time: float = NOMINAL_SWITCH_TIME,
                 compensation_scales: tuple[float, ...] = COMPENSATION_SCALES,
                 compensation_times: tuple[float, ...] = COMPENSATION_TIMES,
                 nesting_gate: float = NESTING_GATE, size_gate: float = SIZE_GATE,
                 narrow_filter: str = NARROW_FILTER,
                 nominal_acceleration_noise: float = NOMINAL_ACCELERATION_NOISE, **options):
        if not (math.isfinite(switch_time) and switch_time > 0):
            raise ValueError(f"switch_time must be positive, got {switch_time}")
        if not (math.isfinite(nominal_switch_time) and nominal_switch_time >= 0):
            raise ValueError(f"nominal_switch_time must be >= 0, got {nominal_switch_time}")
        if not (math.isfinite(nominal_acceleration_noise) and nominal_acceleration_noise >= 0):
            raise ValueError(f"nominal_acceleration_noise must be >= 0, got {nominal_acceleration_noise}")
        scales = tuple(float(s) for s in compensation_scales)
        if not scales or scales[-1] != 1.0 or any(not a < b for a, b in zip((0.0,) + scales, scales)):
            raise ValueError(f"compensation_scales must increase from above 0 to 1, got {compensation_scales}")
        times = tuple(float(s) for s in compensation_times)
        if len(times) != len(scales) or times[-1] != 1.0 or not all(0.0 < t < math.inf for t in times):
            raise ValueError(f"compensation_times must be positive, one per scale, the last 1; got {compensation_times}")
        if not 0.0 <= nesting_gate < 1.0:
            raise ValueError(f"nesting_gate must lie in [0, 1), got {nesting_gate}")
        if not 0.0 <= size_gate < 1.0:
            raise ValueError(f"size_gate must lie in [0, 1), got {size_gate}")
        if narrow_filter not in NARROW_FILTERS:
            raise ValueError(f"narrow_filter must be one of {NARROW_FILTERS}, got {narrow_filter!r}")
        super().__init__(model)
        sigma = options.pop("unmodelled_acceleration_std", UNMODELLED_ACCELERATION_STD)
        tau = options.pop("unmodelled_acceleration_time", UNMODELLED_ACCELERATION_TIME)
        if not sigma > 0.0:
            raise ValueError("the compensated members need unmodelled_acceleration_std > 0")
        if options.pop("nominal_prior", 0.0):
            raise ValueError("the IMM tests the nominal model itself: its members take no nominal_prior")
        # the nominal and the widest member keep the first two streams whatever the number of scales
        streams = np.random.SeedSequence(np.random.default_rng(seed).integers(2 ** 63)).spawn(len(scales) + 1)
        nominal_options = {k: v for k, v in options.items() if not k.startswith("unmodelled_acceleration")}
        nominal_model = (WhiteAccelerationNoise(model, nominal_acceleration_noise) if nominal_acceleration_noise > 0
                         else model)
        self.nominal = GeometricProjectionPF(nominal_model, n_particles, unmodelled_acceleration_std=0.0,
                                             seed=np.random.default_rng(streams[0]), **nominal_options)
        stream_of = [*range(2, len(scales) + 1), 1]  # the widest member's is the second stream
        gate = {key: options.get(key, default) for key, default in
                (("outlier_gate", OUTLIER_GATE), ("outlier_gate_limit", OUTLIER_GATE_LIMIT))}

        def member(stream: int, scale: float, time: float, narrow: bool) -> Filter:
            rng = np.random.default_rng(streams[stream])
            if narrow and narrow_filter == "ekf":
                ekf = CompensatedEKF(model, scale * sigma, time * tau, nominal_prior=0.0, seed=rng, **gate)
                ekf.forgo_observability()  # (the nominal member's report is the mixture's)
                return ekf
            return GeometricProjectionPF(model, n_particles, seed=rng, nominal_prior=0.0,
                                         unmodelled_acceleration_std=scale * sigma,
                                         unmodelled_acceleration_time=time * tau, **options)

        self.scaled = tuple(member(stream, scale, time, narrow=stream != 1)
                            for stream, scale, time in zip(stream_of, scales, times))
        self.compensated = self.scaled[-1]
        self.narrow_filter = narrow_filter
        self.nesting_gate = float(nesting_gate)
        self._nesting_limit = float(chi2.ppf(nesting_gate, model.state_dim)) if nesting_gate else math.inf
        self.size_gate = float(size_gate)
        p = self.compensated.model.state_dim - model.state_dim  # (the acceleration's components)
        self._size_limit = float(chi2.ppf(size_gate, p)) if size_gate else math.inf
        self.compensation_scales, self.compensation_times = scales, times
        self.switch_time = float(switch_time)
        self.nominal_switch_time = float(nominal_switch_time)
        self.model_probabilities = np.full(len(self.members), 1.0 / len(self.members))
        self._predicted_probabilities = self.model_probabilities
        self._mix_due = False
        self._moments = self._acceleration_moments = None
        self.last_log_likelihood = 0.0

    own_capabilities = frozenset({CLOUD, RESAMPLING, GATE, TEMPERING, MODEL_PROBABILITIES, COMPENSATION})

    @property
    def members(self) -> tuple[Filter, ...]:
        """The nominal member, then the compensated ones by increasing scale (the principal,
        :attr:`compensated`, last)."""
        return (self.nominal, *self.scaled)

    def _particle_members(self) -> list[tuple[float, GeometricProjectionPF]]:
        """``(model probability, member)`` of the GPF members."""
        return [(mu, m) for mu, m in zip(self.model_probabilities, self.members)
                if isinstance(m, GeometricProjectionPF)]

    def delegate(self, capability: str) -> GeometricProjectionPF | None:
        """:attr:`compensated` answers the co-state: the co-state of the model that contains the others
        measures what no model explains (the integrity monitor tests its mean); a probability-weighted
        mix of the members' co-states is not stationary while the probabilities move."""
        return self.compensated if capability == COSTATE else None

    # --- the filter interface ------------------------------------------------------------------------
    def initialize(self, mean, cov, t0: float = 0.0) -> None:
        """Every member from the user's prior ``N(mean (n,), cov (n, n))``; model probabilities alike."""
        self._moments = self._acceleration_moments = None
        for member in self.members:
            member.initialize(mean, cov, t0)
        self.model_probabilities = np.full(len(self.members), 1.0 / len(self.members))
        self._predicted_probabilities = self.model_probabilities
        self._mix_due = False

    def predict(self, dt: float, u: np.ndarray | None = None) -> None:
        self._moments = self._acceleration_moments = None
        if self._mix_due and dt > 0.0:
            self._mix(dt)
        for member in self.members:
            member.predict(dt, u)

    def update(self, y: np.ndarray, sensor=None) -> None:
        """Every member updates with ``y`` of ``sensor`` (None: the model's); then the probabilities."""
        self._moments = self._acceleration_moments = None
        before = [(m.gated, m.recoveries) for m in self.members]
        for member in self.members:
            member.update(y, sensor)
        gated = np.array([m.gated != b[0] for m, b in zip(self.members, before)])
        recovered = np.array([m.recoveries != b[1] for m, b in zip(self.members, before)])
        refused = gated | recovered
        mu = self._predicted_probabilities
        self.last_log_likelihood = 0.0
        if not refused.all():
            evidence = np.array([m.last_log_likelihood for m in self.members])
            # (step 3 of the module docstring)
            bound = np.array([m.last_log_likelihood + m.refused_log_likelihood if g and not r else math.inf
                              for m, g, r in zip(self.members, gated, recovered)])
            evidence[refused] = np.minimum(evidence[~refused].min(), bound[refused])
            peak = evidence.max()
            posterior = mu * np.exp(evidence - peak)
            if np.isfinite(posterior).all() and posterior.sum() > 0.0:  # else the data cannot tell them apart
                mu = posterior
                self.last_log_likelihood = float(peak + math.log(posterior.sum()))
        if self.nesting_gate > 0.0 or self.size_gate > 0.0:
            admitted = self._sized()
            if self.nesting_gate > 0.0:
                admitted &= self._nested()
            admitted = np.where(admitted, mu, 0.0)
            mu = admitted if admitted.sum() > 0.0 else np.eye(mu.size)[-1]
        self.model_probabilities = mu / mu.sum()
        self._predicted_probabilities = self.model_probabilities
        self._mix_due = True

    def _sized(self) -> np.ndarray:
        """``(K,)`` bool: the members the size gate admits (step 5 of the module docstring): the nominal and
        the widest always, a narrow one while ``a^T a / sigma^2`` of its estimated acceleration ``a`` is
        within the gate."""
        admitted = np.ones(len(self.members), dtype=bool)
        for j, member in enumerate(self.scaled[:-1], 1):
            a = member.unmodelled_acceleration
            admitted[j] = bool(float(a @ a) / member.model.acceleration_std ** 2 <= self._size_limit)
        return admitted

    def _nested(self) -> np.ndarray:
        """``(K,)`` bool: the members whose estimate of the user's state the widest member's posterior
        admits and, for the narrow ones, whose spread along the undetermined directions the nominal
        member's does not exceed by more than ``1 / NESTING_SPREAD`` (step 4 of the module docstring); the
        widest always, and every member when the data have determined every direction."""
        report = self.observability
        if report is not None and report.determined:
            return np.ones(len(self.members), dtype=bool)
        mean, cov = self.compensated.mean, self.compensated.covariance
        distances = [float(d @ np.linalg.solve(cov, d)) for d in (m.mean - mean for m in self.members[:-1])]
        admitted = np.append(np.array(distances) <= self._nesting_limit, True)
        if report is not None:
            directions = report.directions.T  # (n, d)
            floor = NESTING_SPREAD * _variances(self.nominal.covariance, directions)
            for j, member in enumerate(self.scaled[:-1], 1):
                admitted[j] &= bool(np.all(_variances(member.covariance, directions) >= floor))
        return admitted

    def _mix(self, dt: float) -> None:
        """IMM mixing over ``dt`` s (module docstring, step 1)."""
        mu = self.model_probabilities
        count = mu.size
        p = 1.0 - math.exp(-dt / self.switch_time)
        chain = np.full((count, count), p / (count - 1))
        np.fill_diagonal(chain, 1.0 - p)
        if self.nominal_switch_time > 0.0:
            q = (1.0 - p) * (1.0 - math.exp(-dt / self.nominal_switch_time))
            chain[0, 0] -= q
            chain[0, 1] += q
        predicted = chain.T @ mu
        if predicted[0] > 0.0:  # (a nominal model of probability 0 keeps its own estimate)
            n = self.model.state_dim
            weights = chain[:, 0] * mu / predicted[0]  # mu_{i|0}
            moments = [(self.nominal.mean, self.nominal.covariance)] + [
                (m.augmented_mean[:n], m.augmented_covariance[:n, :n]) for m in self.scaled]
            self.nominal.set_moments(*mixture_moments(weights, moments))  # the compensated members are not
            # mixed (module docstring, step 1)
        self._predicted_probabilities = predicted
        self._mix_due = False
        self._moments = self._acceleration_moments = None

    # --- the estimate --------------------------------------------------------------------------------
    @property
    def mean(self) -> np.ndarray:
        return self._mixture()[0]

    @property
    def covariance(self) -> np.ndarray:
        """Covariance ``(n, n)`` of the mixture of the members' estimates, positive definite."""
        return self._mixture()[1]

    def _mixture(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mean, covariance)`` of the mixture, kept until the next step changes the members."""
        if self._moments is None:
            mean, cov = mixture_moments(self.model_probabilities, self._estimates())
            self._moments = (mean, positive_definite(cov))
            for array in self._moments:
                array.flags.writeable = False
        return self._moments

    def _estimates(self) -> list[tuple[np.ndarray, np.ndarray]]:
        return [(m.mean, m.covariance) for m in self.members]

    def predicted_estimates(self, sensor) -> list[tuple[object, np.ndarray, np.ndarray]]:
        """Each member's predicted estimate of the user's state, the members of positive probability only,
        the most probable first: a measurement that one model explains is not an outlier, however far it is
        from the mixture's moments (early in a 9 % mismatch the narrow members, most of the probability,
        are off together; the widest member is not)."""
        order = np.argsort(-self.model_probabilities, kind="stable")
        return [(sensor, self.members[j].mean, self.members[j].covariance)
                for j in order.tolist() if self.model_probabilities[j] > 0.0]

    @property
    def observability(self):
        """The nominal member's :class:`~gpf_nav.integrity.observability.ObservabilityReport`: what the
        data determined of the user's state (the compensated members' also count their accelerations)."""
        return self.nominal.observability

    def _accelerations(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Each model's unmodelled acceleration ``(p,)`` and covariance ``(p, p)`` (the nominal's zero)."""
        scaled = [(m.unmodelled_acceleration, m.unmodelled_acceleration_covariance) for m in self.scaled]
        p = scaled[0][0].size
        return [(np.zeros(p), np.zeros((p, p)))] + scaled

    @property
    def unmodelled_acceleration(self) -> np.ndarray:
        """Model-averaged unmodelled acceleration ``(p,)`` (the nominal model's is zero)."""
        return self._acceleration_mixture()[0]

    @property
    def unmodelled_acceleration_covariance(self) -> np.ndarray:
        """Its covariance ``(p, p)``."""
        return self._acceleration_mixture()[1]

    def _acceleration_mixture(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mean, covariance)`` of the models' accelerations, kept until the next step changes the members."""
        if self._acceleration_moments is None:
            self._acceleration_moments = mixture_moments(self.model_probabilities, self._accelerations())
            for array in self._acceleration_moments:
                array.flags.writeable = False
        return self._acceleration_moments

    # --- particle diagnostics, model-averaged ----------------------------------------------------------
    @property
    def particles(self) -> np.ndarray:
        """A weighted point set ``(M, n)`` of the mixture in the user's state: every GPF member's particles,
        and each EKF member's ``2 n`` points ``m +- sqrt(n) L e_j`` (``L L^T = P``: the member's mean and
        covariance exactly)."""
        n = self.model.state_dim
        return np.vstack([m.particles[:, :n] if isinstance(m, GeometricProjectionPF) else _sigma_points(m)
                          for m in self.members])

    @property
    def weights(self) -> np.ndarray:
        """Weights ``(M,)`` of :attr:`particles`: each member's (``1 / 2n`` for an EKF's points), times its
        model probability."""
        n = self.model.state_dim
        return np.concatenate([mu * m.weights if isinstance(m, GeometricProjectionPF) else np.full(2 * n, mu / (2 * n))
                               for mu, m in zip(self.model_probabilities, self.members)])

    @property
    def ess(self) -> float:
        """ESS/N of the GPF members' last updates, weighted by their model probabilities (an EKF member
        has no particles to degenerate)."""
        members = self._particle_members()
        total = sum(mu for mu, _ in members)
        if not total > 0.0:
            return float(np.mean([m.ess for _, m in members]))
        return float(sum(mu * m.ess for mu, m in members) / total)

    @property
    def resampled(self) -> bool:
        """Whether any GPF member resampled at the last update."""
        return any(m.resampled for _, m in self._particle_members())

    @property
    def resample_count(self) -> int:
        """Resamplings of every GPF member."""
        return sum(m.resample_count for _, m in self._particle_members())

    @property
    def tempered_updates(self) -> int:
        """Updates a GPF member split into tempering stages."""
        return sum(m.tempered_updates for _, m in self._particle_members())

    @property
    def gated(self) -> int:
        """Measurement components refused by the innovation gate, every member."""
        return sum(m.gated for m in self.members)


def _variances(cov: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """``(d,)`` variances ``v^T P v`` of the covariance ``cov`` ``(n, n)`` along each column ``v`` of
    ``directions`` ``(n, d)``."""
    return np.einsum("id,ij,jd->d", directions, cov, directions)


def _sigma_points(member: Filter) -> np.ndarray:
    """``(2 n, n)`` points ``m +- sqrt(n) L e_j`` of a Gaussian member's estimate of the user's state
    (``L L^T = P``): equally weighted, they have its mean and covariance."""
    mean, cov = member.mean, member.covariance
    spread = math.sqrt(mean.size) * np.linalg.cholesky(cov).T  # rows: the columns of sqrt(n) L
    return np.vstack([mean + spread, mean - spread])
