"""Lunar-descent truth and measurement generator of the paper's Section 7 (no ROS).

:func:`generate` integrates the truth under the mismatched gravity ``mu (1 + epsilon)`` and draws the
range/azimuth/elevation measurements, the prior, the dropouts and the outliers from independent seeded
streams;
:func:`load_csv` replays a recorded truth instead. Every choice the paper leaves open is a field of
:class:`ScenarioConfig` (defaults in ``config/scenario.yaml``, rationale in ``docs/scenario.md``).
All quantities are SI (m, m/s, m/s^2, s, rad) unless a field name ends in ``_deg``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gpf_nav.models.gravity import FIELDS, GravityField, make_field
from gpf_nav.models.state_space import wrap_angle
from gpf_nav.models.lunar import MOON_RADIUS, MU_MOON, LunarDescentModel

CASES = ("full", "partial", "range")
ORBIT_DESIGNS = ("truth", "filter")
_CSV_HEADER = "t,x,y,z,vx,vy,vz,ax,ay,az"


@dataclass(frozen=True)
class ScenarioConfig:
    """Every scenario choice, SI units.

    The paper gives ``sigma = 0.03 km`` for all three measurement channels; a 0.03 km (0.03 rad) angle
    noise would be ~55 km of cross-range error at 1800 km, so the angle sigma is read as 0.03 degrees
    (``angle_noise_std = radians(0.03) = 5.236e-4 rad``) and the range sigma as 30 m.

    Start state (exactly): the descent ellipse with apolune radius ``MOON_RADIUS + apolune_altitude`` and
    perilune radius ``MOON_RADIUS + perilune_altitude`` is first placed in the x-y plane with apolune on
    the +x axis and motion towards +y, then rotated about the x axis (the line of nodes) by
    ``inclination_deg``. Hence ``r0 = [r_a, 0, 0]`` and ``v0 = v_a [0, cos i, sin i]`` with the vis-viva
    apolune speed ``v_a = sqrt(2 gm r_p / (r_a (r_a + r_p)))``. ``orbit_design`` picks the ``gm`` of that
    speed: ``"truth"`` uses ``mu (1 + epsilon)`` so the truth really flies the 100 km x 15 km ellipse;
    ``"filter"`` uses ``mu``, so the truth, pulled harder, falls far below the planned perilune (it
    reaches the surface after ~1140 s with ``epsilon = 0.09``; :func:`generate` refuses that).

    Attributes:
        epsilon: truth gravity is ``mu (1 + epsilon)``; filters use ``mu``.
        apolune_altitude: start (apolune) altitude, m.
        perilune_altitude: planned perilune altitude, m.
        inclination_deg: orbit inclination, degrees.
        orbit_design: ``"truth"`` or ``"filter"``, the gravity the start velocity is designed with.
        duration: length of the run, s (``K = floor(duration / dt)`` measurements).
        dt: measurement (and filter) step, s.
        truth_step: longest RK4 sub-step of the truth integration, s.
        truth_accel_noise_density: truth white-acceleration density, m/s^1.5.
        filter_accel_noise_density: process-noise density the filters assume, m/s^1.5.
        range_noise_std: range noise standard deviation, m.
        angle_noise_std: azimuth and elevation noise standard deviation, rad.
        station: observer position ``(3,)``, m (the Moon's centre).
        prior_position_std: prior standard deviation of each position component, m.
        prior_velocity_std: prior standard deviation of each velocity component, m/s.
        case: ``"full"`` (range, azimuth, elevation), ``"partial"`` (azimuth never measured) or
            ``"range"`` (range only: azimuth and elevation never measured).
        measurement_noise_scale: multiplies both noise standard deviations (noise sweeps).
        dropout_probability: probability that a whole measurement vector is lost (all NaN).
        outlier_probability: probability that one component of a measurement is an outlier (each
            component of each vector independently).
        outlier_size: an outlier's extra error, in standard deviations of its channel (after
            ``measurement_noise_scale``), with a random sign.
        measurement_bias_sigma: a constant error ``(3,)`` added to range, azimuth and elevation, in
            standard deviations of each channel (after ``measurement_noise_scale``).
        thrust: None for a coasting descent, else the magnitude (m/s^2) of a retrograde specific force
            ``-thrust v / |v|`` evaluated at the start of each step and held over it.
        thrust_known: the filters are given the thrust as the IMU's specific force (default); False
            hides it from them: an unmodelled retrograde force like drag (a model error other than
            the gravity scale).
        disturbance: a constant acceleration ``(3,)`` in the world frame, m/s^2, added to the truth's
            gravity and never given to the filters (nor to the IMU, like a gravity-field error): an
            unmodelled force fixed in inertial space, which turns in the orbit frame.
        truth_gravity: the truth's gravity field beyond the point mass (:data:`gpf_nav.models.gravity.FIELDS`:
            ``point``, ``j2``, ``zonal`` for J2-J4, ``degree4`` for DE430's field through degree 4).
        filter_gravity: the field of the filters' model (the same names); it may differ from the truth's.
        thrust_drift_rate: with a ``thrust``, the rate, rad/s, at which its direction turns in the orbit
            plane from retrograde towards the radial: ``-cos(w t) v/|v| + sin(w t) n``, ``n`` the unit
            component of ``r`` normal to ``v`` (0: retrograde throughout).
        surface_stations: beacons on the rotating Moon that replace the station at ``station``: latitude
            (rad), longitude (rad, east positive) and height (m above the mean radius) of each in turn, 3
            numbers per beacon (:mod:`gpf_nav.sim.surface_stations`; empty: the paper's one station).
            They measure all three channels with the scenario's noise (times ``measurement_noise_scale``);
            ``case``, dropouts, outliers and bias act on the centre station's ``measurements`` only.
    """

    epsilon: float = 0.09
    apolune_altitude: float = 100e3
    perilune_altitude: float = 15e3
    inclination_deg: float = 30.0
    orbit_design: str = "truth"
    duration: float = 2400.0
    dt: float = 2.0
    truth_step: float = 0.5
    truth_accel_noise_density: float = 1e-3
    filter_accel_noise_density: float = 1e-3
    range_noise_std: float = 30.0
    angle_noise_std: float = math.radians(0.03)
    station: tuple[float, float, float] = (0.0, 0.0, 0.0)
    prior_position_std: float = 1e3
    prior_velocity_std: float = 1.0
    case: str = "full"
    measurement_noise_scale: float = 1.0
    dropout_probability: float = 0.0
    outlier_probability: float = 0.0
    outlier_size: float = 20.0
    measurement_bias_sigma: tuple[float, float, float] = (0.0, 0.0, 0.0)
    thrust: float | None = None
    thrust_known: bool = True
    disturbance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    truth_gravity: str = "point"
    filter_gravity: str = "point"
    thrust_drift_rate: float = 0.0
    surface_stations: tuple[float, ...] = ()

    def __post_init__(self):
        if self.case not in CASES:
            raise ValueError(f"case must be one of {CASES}, got {self.case!r}")
        for name in ("truth_gravity", "filter_gravity"):
            if getattr(self, name) not in FIELDS:
                raise ValueError(f"{name} must be one of {FIELDS}, got {getattr(self, name)!r}")
        if not math.isfinite(self.thrust_drift_rate):
            raise ValueError("thrust_drift_rate must be finite")
        if self.orbit_design not in ORBIT_DESIGNS:
            raise ValueError(f"orbit_design must be one of {ORBIT_DESIGNS}, got {self.orbit_design!r}")
        if not 0.0 <= self.dropout_probability <= 1.0:
            raise ValueError("dropout_probability must lie in [0, 1]")
        if not 0.0 <= self.outlier_probability <= 1.0:
            raise ValueError("outlier_probability must lie in [0, 1]")
        if not 0.0 <= self.outlier_size < math.inf:
            raise ValueError("outlier_size must be finite and non-negative")
        if min(self.dt, self.truth_step, self.range_noise_std, self.angle_noise_std,
               self.measurement_noise_scale, self.prior_position_std, self.prior_velocity_std) <= 0:
            raise ValueError("dt, truth_step, noise and prior standard deviations and the noise scale "
                             "must be positive")
        if self.duration < self.dt:
            raise ValueError("duration must cover at least one measurement step")
        if min(self.truth_accel_noise_density, self.filter_accel_noise_density) < 0:
            raise ValueError("acceleration noise densities must be non-negative")
        if not 0 < self.perilune_altitude <= self.apolune_altitude:
            raise ValueError("need 0 < perilune_altitude <= apolune_altitude")
        if len(self.station) != 3:
            raise ValueError("station must have three components")
        for name in ("disturbance", "measurement_bias_sigma"):
            value = getattr(self, name)
            if len(value) != 3 or not all(math.isfinite(a) for a in value):
                raise ValueError(f"{name} must have three finite components")
        beacons = self.surface_stations
        if len(beacons) % 3 or not all(math.isfinite(a) for a in beacons) \
                or not all(abs(lat) <= math.pi / 2 for lat in beacons[::3]):
            raise ValueError("surface_stations must be finite latitude (in [-pi/2, pi/2] rad), longitude, "
                             "height triples")

    @property
    def steps(self) -> int:
        """Number of measurement steps ``K``."""
        return int(math.floor(self.duration / self.dt + 1e-9))

    def to_dict(self) -> dict:
        """Plain dict of the fields (the tuples as lists)."""
        out = dataclasses.asdict(self)
        for name in ("station", "disturbance", "measurement_bias_sigma", "surface_stations"):
            out[name] = list(getattr(self, name))
        return out

    @classmethod
    def from_dict(cls, data: dict) -> ScenarioConfig:
        """Build from a dict of (a subset of) the fields; unknown keys raise ValueError."""
        fields = {f.name: f for f in dataclasses.fields(cls)}
        unknown = set(data) - set(fields)
        if unknown:
            raise ValueError(f"unknown scenario keys: {sorted(unknown)}")
        return cls(**{k: _coerce(fields[k].default, v) for k, v in data.items()})

    @classmethod
    def from_yaml(cls, path: str | Path) -> ScenarioConfig:
        """Read a flat ``key: value`` YAML file (see :func:`parse_flat_yaml`)."""
        return cls.from_dict(parse_flat_yaml(Path(path).read_text()))


def _coerce(default, value):
    """Convert a parsed value to the type of the field whose default is ``default``."""
    if value is None or isinstance(default, str):
        return value
    if isinstance(default, bool):
        return bool(value)
    if isinstance(default, tuple):
        return tuple(float(v) for v in value)
    return float(value)


def parse_flat_yaml(text: str) -> dict:
    """Parse the flat YAML subset of ``config/scenario.yaml``.

    One ``key: value`` per line; ``#`` starts a comment; values are ``null``/``~``, ``true``/``false``,
    numbers, quoted or bare strings, or flat ``[a, b, c]`` lists of those. Nesting raises ValueError.
    """
    out = {}
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].rstrip()
        if not line.strip():
            continue
        if line[0].isspace() or ":" not in line:
            raise ValueError(f"line {number}: expected a top-level 'key: value', got {raw!r}")
        key, value = (s.strip() for s in line.split(":", 1))
        if key in out:
            raise ValueError(f"line {number}: duplicate key {key!r}")
        out[key] = _parse_scalar(value)
    return out


def _parse_scalar(s: str):
    if s.startswith("[") and s.endswith("]"):
        inner = s[1:-1].strip()
        return [_parse_scalar(p.strip()) for p in inner.split(",")] if inner else []
    if s in ("", "null", "~", "None"):
        return None
    if s in ("true", "false"):
        return s == "true"
    if len(s) >= 2 and s[0] == s[-1] and s[0] in "'\"":
        return s[1:-1]
    for kind in (int, float):
        try:
            return kind(s)
        except ValueError:
            pass
    return s


def filter_model(config: ScenarioConfig) -> LunarDescentModel:
    """The model the filters run on: gravity ``mu`` with the field ``filter_gravity``, density
    ``filter_accel_noise_density``, true ``R``."""
    return _model(config, 1.0, config.filter_accel_noise_density, config.filter_gravity)


def truth_model(config: ScenarioConfig) -> LunarDescentModel:
    """The truth model: gravity ``mu (1 + epsilon)`` with the field ``truth_gravity``, density
    ``truth_accel_noise_density``."""
    return _model(config, 1.0 + config.epsilon, config.truth_accel_noise_density, config.truth_gravity)


def _model(config: ScenarioConfig, mu_scale: float, density: float, field: str) -> LunarDescentModel:
    return LunarDescentModel(mu=MU_MOON, mu_scale=mu_scale, station=config.station,
                             range_noise_std=config.range_noise_std * config.measurement_noise_scale,
                             angle_noise_std=config.angle_noise_std * config.measurement_noise_scale,
                             accel_noise_density=density, gravity=make_field(field, MU_MOON * mu_scale))


@dataclass
class Scenario:
    """One run: truth, measurements, IMU input and prior.

    Step ``k`` (0-based) goes from ``truth[k]`` at ``t_k`` to ``truth[k + 1]`` at ``times[k]`` under the
    specific force ``specific_force[k]`` held constant; ``measurements[k]`` is taken at ``times[k]``.

    Attributes:
        times: ``(K,)`` measurement times, s (``dt, 2 dt, ...`` for :func:`generate`).
        truth: ``(K + 1, 6)`` true states at ``start_time, times[0], ..., times[-1]``.
        measurements: ``(K, 3)`` range (m), azimuth, elevation (rad); NaN where not measured.
        specific_force: ``(K, 3)`` world-frame IMU specific force per step, m/s^2 (zeros when coasting).
        prior_mean: ``(6,)`` filter prior mean.
        prior_cov: ``(6, 6)`` filter prior covariance.
        config: the configuration that produced the run.
        start_time: time of ``truth[0]``, s.
    """

    times: np.ndarray
    truth: np.ndarray
    measurements: np.ndarray
    specific_force: np.ndarray
    prior_mean: np.ndarray
    prior_cov: np.ndarray
    config: ScenarioConfig
    start_time: float = 0.0


def initial_state(config: ScenarioConfig) -> np.ndarray:
    """True start state ``(6,)`` at apolune (see :class:`ScenarioConfig` for the exact geometry)."""
    gm = MU_MOON * (1.0 + config.epsilon if config.orbit_design == "truth" else 1.0)
    r_a = MOON_RADIUS + config.apolune_altitude
    r_p = MOON_RADIUS + config.perilune_altitude
    v_a = math.sqrt(2.0 * gm * r_p / (r_a * (r_a + r_p)))
    inc = math.radians(config.inclination_deg)
    return np.array([r_a, 0.0, 0.0, 0.0, v_a * math.cos(inc), v_a * math.sin(inc)])


def undetermined_subspace(config: ScenarioConfig, state: np.ndarray) -> np.ndarray | None:
    """The directions ``(6, d)`` of the state ``(6,)`` that the scenario's measurements cannot determine
    from the Moon's centre (columns, state units): any rotation of the whole trajectory about the centre
    for range only (``d = 3``), the rotation about the polar axis without azimuth (``d = 1``), none for
    the full case (``(6, 0)``); for states ``(K, 6)``, each one's ``(K, 6, d)``. None when the station is
    not at the centre or surface stations replace it (no such symmetry)."""
    if any(config.station) or config.surface_stations:
        return None
    axes = {"range": np.eye(3), "partial": np.eye(3)[:, 2:], "full": np.zeros((3, 0))}[config.case].T  # (d, 3)
    state = np.asarray(state, dtype=float)
    if not axes.size:
        return np.zeros(state.shape[:-1] + (6, 0))
    p, v = state[..., None, :3], state[..., None, 3:6]  # (..., 1, 3): each axis crossed with them
    return np.concatenate([np.cross(axes, p), np.cross(axes, v)], axis=-1).swapaxes(-1, -2)


def _streams(seed: int) -> list[np.random.Generator]:
    """Independent generators for truth noise, measurement noise, prior, dropouts and outliers (in that
    order; the first four are the children a four-stream spawn gave, so adding the fifth changed no
    draw of theirs)."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(5)]


def generate(config: ScenarioConfig, seed: int) -> Scenario:
    """Integrate the truth, draw measurements, dropouts, outliers and prior; same seed gives identical
    arrays.

    Raises:
        ValueError: if the truth reaches the lunar surface within ``config.duration``.
    """
    truth_rng, *measurement_streams = _streams(seed)
    model = truth_model(config)
    steps = config.steps
    dt = config.dt
    q = model.process_noise(dt)
    sqrt_q = np.linalg.cholesky(q) if model.accel_noise_density > 0 else np.zeros_like(q)
    noise = truth_rng.standard_normal((steps, 6)) @ sqrt_q.T
    substeps = max(1, math.ceil(dt / config.truth_step - 1e-9))
    truth, force = _integrate_truth(initial_state(config), steps, dt, substeps, model.gm,
                                    config.thrust, noise, config.disturbance, model.gravity,
                                    config.thrust_drift_rate)
    altitude = np.linalg.norm(truth[:, :3], axis=1) - MOON_RADIUS
    if altitude.min() < 0.0:
        hit = int(np.argmax(altitude < 0.0)) * dt
        raise ValueError(f"truth reaches the lunar surface at t = {hit:.0f} s; shorten duration "
                         f"or use orbit_design='truth'")
    times = dt * np.arange(1, steps + 1)
    return _finish(config, times, truth, force, model, *measurement_streams, 0.0)


def _integrate_truth(x0: np.ndarray, steps: int, dt: float, substeps: int, gm: float,
                     thrust: float | None, noise: np.ndarray, disturbance=(0.0, 0.0, 0.0),
                     field: GravityField | None = None, thrust_drift_rate: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """RK4 two-body flow with held specific force, the constant ``disturbance`` acceleration and the
    gravity ``field``'s perturbation (None: none), plus ``noise[k]`` ``(K, 6)`` added after each step;
    ``truth[0]`` is at ``t = 0``.

    Scalar Python arithmetic: a single 6-state is far faster this way than with numpy calls.
    Returns truth ``(K + 1, 6)`` and specific force ``(K, 3)``.
    """
    h = dt / substeps
    truth = np.empty((steps + 1, 6))
    force = np.zeros((steps, 3))
    truth[0] = x0
    x, y, z, vx, vy, vz = (float(c) for c in x0)

    dx, dy, dz = (float(a) for a in disturbance)

    def acc(px, py, pz, t):
        k = -gm / (px * px + py * py + pz * pz) ** 1.5
        ax, ay, az = k * px + ux + dx, k * py + uy + dy, k * pz + uz + dz
        if field is None:
            return ax, ay, az
        fx, fy, fz = field.acceleration(np.array([[px], [py], [pz]]), t)[:, 0].tolist()
        return ax + fx, ay + fy, az + fz

    for step in range(steps):
        ux = uy = uz = 0.0
        if thrust:
            ux, uy, uz = _thrust(thrust, thrust_drift_rate * step * dt, (x, y, z), (vx, vy, vz))
            force[step] = ux, uy, uz
        for sub in range(substeps):
            t = (step * substeps + sub) * h
            a1x, a1y, a1z = acc(x, y, z, t)
            b2x, b2y, b2z = vx + 0.5 * h * a1x, vy + 0.5 * h * a1y, vz + 0.5 * h * a1z
            a2x, a2y, a2z = acc(x + 0.5 * h * vx, y + 0.5 * h * vy, z + 0.5 * h * vz, t + 0.5 * h)
            b3x, b3y, b3z = vx + 0.5 * h * a2x, vy + 0.5 * h * a2y, vz + 0.5 * h * a2z
            a3x, a3y, a3z = acc(x + 0.5 * h * b2x, y + 0.5 * h * b2y, z + 0.5 * h * b2z, t + 0.5 * h)
            b4x, b4y, b4z = vx + h * a3x, vy + h * a3y, vz + h * a3z
            a4x, a4y, a4z = acc(x + h * b3x, y + h * b3y, z + h * b3z, t + h)
            x += h / 6.0 * (vx + 2.0 * (b2x + b3x) + b4x)
            y += h / 6.0 * (vy + 2.0 * (b2y + b3y) + b4y)
            z += h / 6.0 * (vz + 2.0 * (b2z + b3z) + b4z)
            vx += h / 6.0 * (a1x + 2.0 * (a2x + a3x) + a4x)
            vy += h / 6.0 * (a1y + 2.0 * (a2y + a3y) + a4y)
            vz += h / 6.0 * (a1z + 2.0 * (a2z + a3z) + a4z)
        w = noise[step]
        x, y, z = x + w[0], y + w[1], z + w[2]
        vx, vy, vz = vx + w[3], vy + w[4], vz + w[5]
        truth[step + 1] = x, y, z, vx, vy, vz
    return truth, force


def _thrust(magnitude: float, angle: float, r: tuple, v: tuple) -> tuple[float, float, float]:
    """The specific force of ``magnitude`` turned by ``angle`` in the orbit plane from retrograde
    (``-v/|v|``) towards the unit component of ``r`` normal to ``v`` (:class:`ScenarioConfig`,
    ``thrust_drift_rate``)."""
    vx, vy, vz = v
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    if angle == 0.0:
        return -magnitude * vx / speed, -magnitude * vy / speed, -magnitude * vz / speed
    back = [-c / speed for c in v]
    along = sum(a * -b for a, b in zip(r, back))  # r . v/|v|
    normal = [a + along * b for a, b in zip(r, back)]  # r minus its component along v
    size = math.sqrt(sum(c * c for c in normal))
    cos, sin = math.cos(angle), math.sin(angle)
    return tuple(magnitude * (cos * b + sin * n / size) for b, n in zip(back, normal))


def _finish(config: ScenarioConfig, times: np.ndarray, truth: np.ndarray, force: np.ndarray,
            model: LunarDescentModel, meas_rng: np.random.Generator, prior_rng: np.random.Generator,
            drop_rng: np.random.Generator, outlier_rng: np.random.Generator, start_time: float) -> Scenario:
    """Draw measurements (noise from ``model``), bias, outliers, case mask, dropouts and prior; assemble
    the Scenario."""
    steps = times.shape[0]
    std = np.sqrt(np.diag(model.measurement_noise()))
    y = model.measure(truth[1:]) + meas_rng.standard_normal((steps, 3)) * std
    if any(config.measurement_bias_sigma):
        y += np.asarray(config.measurement_bias_sigma) * std
    if config.outlier_probability > 0.0:
        hit, sign = outlier_rng.random((2, steps, 3))  # the same draws for any probability and size
        y += np.where(hit < config.outlier_probability, config.outlier_size, 0.0) * np.where(sign < 0.5, -std, std)
    y[:, 1] = wrap_angle(y[:, 1])
    if config.case != "full":
        y[:, 1] = np.nan
    if config.case == "range":
        y[:, 2] = np.nan
    y[drop_rng.random(steps) < config.dropout_probability] = np.nan
    if not config.thrust_known:
        force = np.zeros_like(force)
    prior_std = np.repeat([config.prior_position_std, config.prior_velocity_std], 3)
    prior_mean = truth[0] + prior_std * prior_rng.standard_normal(6)
    return Scenario(times=times, truth=truth, measurements=y, specific_force=force,
                    prior_mean=prior_mean, prior_cov=np.diag(prior_std ** 2), config=config,
                    start_time=float(start_time))


def load_csv(path: str | Path, config: ScenarioConfig = ScenarioConfig(), seed: int = 0) -> Scenario:
    """Replay a recorded truth; measurements, dropouts, outliers and prior are drawn as in :func:`generate`.

    The file has rows ``t, x, y, z, vx, vy, vz[, ax, ay, az]`` (SI, optional header line, strictly
    increasing ``t``). Row ``k``'s ``a`` columns are the specific force held over ``[t_k, t_{k+1}]``
    (the last row's are unused). Measurements come from :func:`filter_model` noise at rows ``1..K``.
    ``config.duration``, ``dt`` and the orbit fields are ignored; the same ``seed`` gives the same
    measurement noise, prior, dropouts and outliers as :func:`generate` would.
    """
    with open(path) as f:
        first = f.readline().split(",")[0].strip()
    try:
        float(first)
        skip = 0
    except ValueError:
        skip = 1
    data = np.loadtxt(path, delimiter=",", skiprows=skip, ndmin=2)
    if data.shape[1] not in (7, 10) or data.shape[0] < 2:
        raise ValueError(f"expected >= 2 rows of 7 or 10 columns, got shape {data.shape}")
    t = data[:, 0]
    if np.any(np.diff(t) <= 0):
        raise ValueError("times must be strictly increasing")
    force = data[:-1, 7:10] if data.shape[1] == 10 else np.zeros((data.shape[0] - 1, 3))
    return _finish(config, t[1:].copy(), data[:, 1:7].copy(), np.ascontiguousarray(force),
                   filter_model(config), *_streams(seed)[1:], t[0])


def save_csv(scenario: Scenario, path: str | Path) -> None:
    """Write the truth and specific force in the format :func:`load_csv` reads (exact round trip)."""
    t = np.concatenate([[scenario.start_time], scenario.times])
    force = np.vstack([scenario.specific_force, np.zeros((1, 3))])
    np.savetxt(path, np.column_stack([t, scenario.truth, force]), delimiter=",", fmt="%.17g",
               header=_CSV_HEADER, comments="")
