"""Honesty where the data cannot tell (issue 23): the observability report, the observability-constrained
update, the consistency monitor, and the linear-Gaussian test every filter must pass.

The linear-Gaussian problem: a 1-D constant-velocity target ``[p, v]`` whose position is measured, beside
a constant ``z`` that no measurement sees. The Kalman filter is the exact posterior, and along ``z`` that
posterior is the prior: ``z``'s mean and variance never move. Every filter must keep them.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from gpf_nav.estimator.factory import FILTERS, make_filter
from gpf_nav.filters import ExtendedKF, GeometricProjectionPF
from gpf_nav.integrity import ConsistencyMonitor, ObservabilityTracker, innovation_moments
from gpf_nav.models import LinearGaussianModel
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate, initial_state, undetermined_subspace
from gpf_nav.sensors.model import ModelSensor
from linear_reference import kalman, simulate

DT = 1.0
STEPS = 30
PRIOR_MEAN = np.array([0.0, 1.0, 3.0])
PRIOR_COV = np.diag([4.0, 1.0, 4.0])


def hidden_constant_model(measure_z: bool = False) -> LinearGaussianModel:
    """``[p, v, z]``: constant velocity with white acceleration, ``z`` constant; ``p`` measured (and ``z``
    too when ``measure_z``). ``p`` and ``v`` are declared as position and velocity, so a compensated filter
    puts its unmodelled acceleration on ``v`` (a model that declares no velocity gets an unmodelled drift
    on every component, ``z`` included: docs/filters.md)."""
    C = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]] if measure_z else [[1.0, 0.0, 0.0]]
    R = np.diag([1.0, 1.0]) if measure_z else [[1.0]]
    model = LinearGaussianModel(A=[[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
                                G=[[0.0], [0.5], [0.0]], C=C, R=R)
    model.position_index, model.velocity_index = (0,), (1,)
    return model


def _run(flt, model, seed=3):
    ys = simulate(model, [0.5, 1.2, 2.0], STEPS, DT, seed)
    flt.initialize(PRIOR_MEAN, PRIOR_COV)
    for y in ys:
        flt.predict(DT)
        flt.update(y)
    return ys


def test_the_kalman_filter_keeps_the_prior_along_a_component_no_measurement_sees():
    model = hidden_constant_model()
    ys = simulate(model, [0.5, 1.2, 2.0], STEPS, DT, 3)
    m, P = kalman(model, PRIOR_MEAN, PRIOR_COV, ys, DT)[-1]
    assert m[2] == pytest.approx(PRIOR_MEAN[2], abs=1e-12)
    assert P[2, 2] == pytest.approx(PRIOR_COV[2, 2], rel=1e-12)
    assert P[0, 0] < 0.5 * PRIOR_COV[0, 0]  # the measured component did learn


@pytest.mark.parametrize("name", FILTERS)
def test_every_filter_keeps_the_prior_along_a_component_no_measurement_sees(name):
    """Mean within 4 Monte Carlo standard errors of the prior mean, variance within 12 % of the prior's
    (N = 2000: a sample variance's relative standard error is 3 %); the measured position learns. A
    resampling draws the cloud again, so its error adds up over the resamplings: the standard error of the
    mean is taken as ``sigma sqrt((1 + resamplings) / N)``."""
    model = hidden_constant_model()
    flt = make_filter(name, model, n_particles=2000, seed=5)
    _run(flt, model)
    mean, cov = np.asarray(flt.mean), np.asarray(flt.covariance)
    draws = 1 + getattr(flt, "resample_count", 0)
    sigma = math.sqrt(PRIOR_COV[2, 2])
    assert abs(mean[2] - PRIOR_MEAN[2]) < 4.0 * sigma * math.sqrt(draws / 2000), (name, mean[2], draws)
    assert cov[2, 2] == pytest.approx(PRIOR_COV[2, 2], rel=0.12), (name, cov[2, 2])
    assert cov[0, 0] < 0.5 * PRIOR_COV[0, 0], name


@pytest.mark.parametrize("name", FILTERS)
def test_every_filter_reports_the_hidden_component_and_only_it(name):
    model = hidden_constant_model()
    flt = make_filter(name, model, n_particles=300, seed=5)
    _run(flt, model)
    report = flt.observability
    user = report.directions[:, :3]
    hidden = [d for d in user if abs(d[2]) > 0.99 * np.linalg.norm(d)]
    assert len(hidden) == 1, (name, report.describe())
    # a compensated filter may also leave its own acceleration undetermined, never p or v
    assert all(np.linalg.norm(d[:2]) < 0.1 * max(np.linalg.norm(d), 1e-300) for d in user), name
    assert report.information[-1] > 10.0  # the measured position is determined


def test_a_measured_component_is_determined_and_the_report_reads_it():
    model = hidden_constant_model(measure_z=True)
    flt = ExtendedKF(model)
    _run(flt, model)
    report = flt.observability
    assert report.determined and report.undetermined == 0
    assert report.information.min() > 1.0 and report.describe() == []
    assert flt.observability.updates == STEPS


def test_the_tracker_refuses_a_nonpositive_threshold_and_reports_nothing_before_a_prior():
    with pytest.raises(ValueError):
        ObservabilityTracker(hidden_constant_model(), threshold=0.0)
    tracker = ObservabilityTracker(hidden_constant_model())
    assert tracker.report() is None and tracker.basis().shape == (0, 0)


def _ekf_through(config: ScenarioConfig, seed: int) -> tuple[ExtendedKF, object]:
    """An EKF run through the lunar scenario of ``config`` (seed ``seed``): ``(filter, scenario)``."""
    scenario = generate(config, seed)
    flt = ExtendedKF(filter_model(config))
    flt.initialize(scenario.prior_mean, scenario.prior_cov)
    for k in range(scenario.times.size):
        flt.predict(config.dt)
        flt.update(scenario.measurements[k])
    return flt, scenario


def _spans(expected: np.ndarray, directions: np.ndarray, scale: np.ndarray) -> bool:
    """Whether the report's ``directions`` ``(d, n)`` span the ``expected`` columns ``(n, d)`` (principal
    angles within 8°, in the report's ``scale``)."""
    a = np.linalg.qr(expected / scale[:, None])[0]
    b = np.linalg.qr(directions.T / scale[:, None])[0]
    return np.linalg.svd(a.T @ b, compute_uv=False).min() > 0.99


@pytest.mark.parametrize("case, d", [("range", 3), ("partial", 1), ("full", 0)])
def test_the_lunar_report_names_the_rotations_about_the_centre(case, d):
    """Range only: the three rotations of the whole trajectory about the Moon's centre; no azimuth: the
    rotation about the polar axis; the full case: none (after the first 100 s)."""
    config = ScenarioConfig(case=case, epsilon=0.0, duration=240.0)
    flt, scenario = _ekf_through(config, 4)
    report = flt.observability
    assert report.undetermined == d
    if d:
        assert _spans(undetermined_subspace(config, scenario.truth[-1]), report.directions, report.scale)


@pytest.mark.parametrize("case, d", [("range", 3), ("partial", 1), ("full", 0)])
def test_the_undetermined_rotations_of_many_states_are_each_states_own(case, d):
    """States ``(K, 6)`` give ``(K, 6, d)``, each the single state's subspace bit for bit (the campaign runner
    takes a whole trajectory's in one call); a rotation about the axis ``a`` moves the state along
    ``(a x r, a x v)``."""
    config = ScenarioConfig(case=case)
    states = generate(config, 0).truth[:50]
    batch = undetermined_subspace(config, states)
    assert batch.shape == (50, 6, d)
    for state, subspace in zip(states, batch):
        assert subspace.tobytes() == undetermined_subspace(config, state).tobytes()
    axes = np.eye(3)[:, 3 - d:] if d == 1 else np.eye(3)[:, :d]
    for j in range(d):
        np.testing.assert_allclose(batch[:, :3, j], np.cross(axes[:, j], states[:, :3]))
        np.testing.assert_allclose(batch[:, 3:, j], np.cross(axes[:, j], states[:, 3:]))


@pytest.mark.parametrize("rebuild", [True, False])
def test_a_moved_reference_keeps_the_polar_rotation_undetermined(monkeypatch, rebuild):
    """Case 2 with the 9 % gravity error: the nominal model's reference drifts and is moved to the filter's
    mean; rebuilt along the model's trajectory through the new reference, the polar rotation (which no
    measurement sees) stays undetermined. Moved but not rebuilt (the tracker before), the Jacobians turn
    against the carried information and the rotation reads as determined."""
    from gpf_nav.integrity import observability
    if not rebuild:
        monkeypatch.setattr(ObservabilityTracker, "_rebuild", lambda self: None)
    config = ScenarioConfig(case="partial", epsilon=0.09, duration=700.0)
    flt, scenario = _ekf_through(config, 1)
    assert flt._observability.reanchors >= 1
    report = flt.observability
    if rebuild:
        assert report.undetermined == 1 and report.information[0] < 1e-2 * observability.UNDETERMINED_INFORMATION
        assert _spans(undetermined_subspace(config, scenario.truth[-1]), report.directions[:, :6],
                      report.scale[:6])
    else:
        assert report.information[0] > observability.UNDETERMINED_INFORMATION


def test_the_constrained_gpf_keeps_the_range_only_rotations_that_the_unconstrained_one_narrows():
    """A 20 km / 20 m/s prior, range only: along the rotations the constrained GPF's covariance stays at
    the prior's size; switched off (``observability_constraint=0``), the same filter narrows them."""
    config = ScenarioConfig(case="range", epsilon=0.0, prior_position_std=20e3, prior_velocity_std=20.0,
                            duration=300.0)
    scenario = generate(config, 2)

    def rotation_spread(constraint):
        flt = GeometricProjectionPF(filter_model(config), 300, seed=1, unmodelled_acceleration_std=0.0,
                                    observability_constraint=constraint)
        flt.initialize(scenario.prior_mean, scenario.prior_cov)
        for k in range(scenario.times.size):
            flt.predict(config.dt)
            flt.update(scenario.measurements[k])
        G = undetermined_subspace(config, flt.mean)
        A = np.linalg.pinv(G)
        return np.sqrt(np.diag(A @ flt.covariance @ A.T)) * np.linalg.norm(flt.mean[:3])

    constrained, free = rotation_spread(1e-3), rotation_spread(0.0)
    assert (constrained > 12e3).all(), constrained
    assert free.min() < 0.7 * constrained.min(), (free, constrained)


def test_the_consistency_monitor_holds_its_false_alarm_rate_on_consistent_innovations():
    rng = np.random.default_rng(0)
    monitor = ConsistencyMonitor(false_alarm_rate=1e-2, window=5)
    S = np.array([[4.0, 1.0], [1.0, 2.0]])
    L = np.linalg.cholesky(S)
    faults = sum(monitor.update(L @ rng.standard_normal(2), S).level == "FAULT" for _ in range(20000))
    # 2e4 correlated tests at 1e-2: the count's spread is a few times sqrt(200)
    assert 100 < faults < 320, faults
    assert monitor.updates == 20000 and monitor.faults == faults


def test_the_consistency_monitor_flags_a_covariance_four_times_too_small():
    rng = np.random.default_rng(1)
    monitor = ConsistencyMonitor()
    S = np.eye(3)
    levels = [monitor.update(2.0 * rng.standard_normal(3), S).level for _ in range(200)]
    assert levels.count("FAULT") > 150
    assert levels.index("FAULT") < 15


def test_the_consistency_monitor_skips_what_it_cannot_test_and_refuses_bad_settings():
    monitor = ConsistencyMonitor()
    monitor.update(np.array([np.nan]), np.eye(1))
    monitor.update(np.ones(2), np.zeros((2, 2)))
    assert monitor.rejected == 2 and monitor.updates == 0 and monitor.status.level == "OK"
    for bad in ({"false_alarm_rate": 0.0}, {"false_alarm_rate": 0.1, "warn_false_alarm_rate": 0.01},
                {"window": 0}):
        with pytest.raises(ValueError):
            ConsistencyMonitor(**bad)


def test_innovation_moments_are_the_linearised_prediction():
    config = ScenarioConfig()
    model = filter_model(config)
    sensor = ModelSensor(model)
    x = np.array([1.8e6, 1e4, 2e4, 0.0, 1500.0, 800.0])
    P = np.diag([100.0, 100.0, 100.0, 1.0, 1.0, 1.0]) ** 2
    y = model.measure(x[None])[0] + np.array([30.0, 0.0, np.nan])
    r, S = innovation_moments(sensor, y, x, P)
    H = model.measurement_jacobian(x[None])[0][:2]
    assert r == pytest.approx([30.0, 0.0], abs=1e-9)
    assert S == pytest.approx(H @ P @ H.T + model.measurement_noise()[:2, :2])
    assert stats.chi2.sf(float(r @ np.linalg.solve(S, r)), 2) > 0.0


@pytest.mark.parametrize("case, duration, warns", [("range", 150.0, True), ("full", 150.0, False),
                                                  ("range", 60.0, False)])
def test_the_estimator_diagnostics_warn_while_a_direction_is_undetermined(case, duration, warns):
    """The engine behind the node (no DDS): with range only the ``/diagnostics`` status is WARN, its
    message names the undetermined directions and its values list them; the full case, after 150 s, is
    not warned about; before 100 s the level ignores the report, and the values show it."""
    from gpf_nav.estimator.engine import EngineConfig, EstimatorEngine
    from gpf_nav.ros import diagnostics as diag

    scenario = generate(ScenarioConfig(case=case, epsilon=0.0, duration=duration), 0)
    model = filter_model(scenario.config)
    config = EngineConfig(initial_state=scenario.prior_mean, initial_std=np.sqrt(np.diag(scenario.prior_cov)),
                          initial_stamp=scenario.start_time)
    engine = EstimatorEngine(lambda: make_filter("gpf", model, n_particles=200, seed=1), model, config,
                             lambda: 0.0)
    for k in range(scenario.times.size):
        stamp = int(round(scenario.times[k] * 1e9))
        assert engine.measurement(stamp, scenario.measurements[k], None) == (True, "")
    level, message, values = diag.filter_status(engine, stamp, diag.Thresholds(costate_warn=1e12), "gpf")
    kv = dict(values)
    if warns:
        assert level == diag.WARN and "3 undetermined directions" in message
        assert kv["observability"] == "UNDETERMINED" and kv["observability undetermined directions"] == "3"
        assert {"observability direction 1", "observability direction 3"} <= set(kv)
    elif case == "full":
        assert "undetermined" not in message and level == diag.OK, message
        assert kv["observability"] == "determined" and kv["observability undetermined directions"] == "0"
    else:
        assert "undetermined" not in message and level == diag.OK, message
        assert kv["observability"] == "UNDETERMINED" and duration < diag.OBSERVABILITY_WARN_AFTER
        # (simulated seconds: the time the tracker predicted over, the measurements' stamps)
        assert float(kv["observability elapsed [s]"]) == pytest.approx(scenario.times[-1] - scenario.start_time,
                                                                       abs=1e-3)


@pytest.mark.parametrize("name", ["gpf", "ekf"])
def test_the_estimator_diagnostics_warn_when_the_innovations_outgrow_the_covariance(name):
    """The engine behind the node (no DDS) runs the consistency monitor on every accepted measurement:
    on a consistent stream its FAULTs stay at its rate and ``/diagnostics`` does not name it; started
    with a covariance 1000 times too small (a 1 m / 1 mm/s prior while the truth is kilometres away) it
    raises a FAULT within a few updates, the status is WARN with the monitor as the cause, and held
    ``monitor_hold`` s; ``consistency_enabled: false`` (``consistency=None``) turns it off."""
    from gpf_nav.estimator.engine import EngineConfig, EstimatorEngine
    from gpf_nav.ros import diagnostics as diag

    scenario = generate(ScenarioConfig(epsilon=0.0, duration=200.0), 0)
    model = filter_model(scenario.config)
    clock = [0.0]

    def run(initial_std, **config):
        cfg = EngineConfig(initial_state=scenario.prior_mean, initial_std=initial_std,
                           initial_stamp=scenario.start_time, monitor_hold=5.0, **config)
        engine = EstimatorEngine(lambda: make_filter(name, model, n_particles=200, seed=1), model, cfg,
                                 lambda: clock[0])
        for k in range(scenario.times.size):
            engine.measurement(int(round(scenario.times[k] * 1e9)), scenario.measurements[k], None)
        return engine, *diag.filter_status(engine, None, diag.Thresholds(costate_warn=1e12), name)

    engine, level, message, values = run(np.sqrt(np.diag(scenario.prior_cov)))
    kv = dict(values)
    assert int(kv["consistency updates"]) == scenario.times.size
    assert int(kv["consistency fault updates"]) <= 2 and "consistency" not in message, message
    assert kv["consistency level"] == "OK" and 0.0 < float(kv["consistency p-value"]) <= 1.0

    engine, level, message, values = run(np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3]))
    kv = dict(values)
    assert int(kv["consistency fault updates"]) >= 3
    first = engine.consistency.status
    assert level >= diag.WARN and "consistency FAULT" in message, message
    assert kv["consistency level"] == "FAULT" and float(kv["consistency window statistic"]) > 0.0
    clock[0] += 10.0  # held 5 s on the steady clock: the last update's own level shows again after that
    level, message, values = diag.filter_status(engine, None, diag.Thresholds(costate_warn=1e12), name)
    assert dict(values)["consistency level"] == first.level

    engine, level, message, values = run(np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3]), consistency=None)
    assert dict(values)["consistency level"] == "disabled" and "consistency" not in message


def _rebuilt_one_call_at_a_time(tracker: ObservabilityTracker) -> tuple[np.ndarray, np.ndarray]:
    """The oracle of the batched rebuild: the reference carried back one transition at a time, then every
    Jacobian and recursion of the log in turn (how the tracker rebuilt before ``transition_chain``,
    ``transition_jacobian_along``, ``jacobian_along`` and the replay kernel)."""
    from gpf_nav.kernels import information
    log, model = tracker._log, tracker.model
    store, k = log.store, log.predictions
    steps = list(zip(store.dt[:k].tolist(), store.t[:k].tolist(), store.inputs[:k]))
    points = [tracker.reference[None]]
    for dt, t, u in reversed(steps):
        points.append(model.transition(points[-1], -dt, t + dt, u))
    points.reverse()
    free, data, step, j = tracker._prior, tracker._prior.copy(), 0, 0
    for predicted in store.predicted[:log.size]:
        x = points[step]
        if predicted:
            dt, t, u = steps[step]
            F = np.ascontiguousarray(model.transition_jacobian(x, dt, t, u)[0])
            step += 1
            _, free, data = information.propagate(F, np.array(model.process_noise(dt, t)),
                                                  np.ascontiguousarray(points[step][0]), free, data)
        else:
            sensor, rows, t = store.sensors[store.group[j]], store.rows[j, :store.count[j]], float(store.times[j])
            j += 1
            H, R = sensor.jacobian(x, t)[0][rows], sensor.noise(t)[np.ix_(rows, rows)]
            outcome, updated = information.update(np.ascontiguousarray(H), np.ascontiguousarray(R), np.zeros(0),
                                                  free, data, 0.0)
            data = updated if outcome == information.UPDATED else data
    return free, data


@pytest.mark.parametrize("kind", ["lunar", "compensated lunar", "user model"])
def test_the_rebuild_gives_the_numbers_of_its_calls_one_at_a_time(kind):
    """A reanchoring's rebuild, batched (the reference carried back in one call, the Jacobians along the
    trajectory in one call per model and sensor, the recursions in one kernel), equals the calls one at a
    time bit for bit: with IMU inputs on some predictions and none on others, two step lengths, updates
    with the azimuth masked, and two more sensors; a user model through the default (one call per state)."""
    from gpf_nav.models.compensation import ModelErrorCompensation
    from gpf_nav.sensors.kinematic import AltitudeSensor, VelocitySensor
    from gpf_nav.sensors.sensor import Padded
    rng = np.random.default_rng(5)
    if kind == "user model":
        model, sensors = hidden_constant_model(measure_z=True), []
        mean, cov = PRIOR_MEAN, PRIOR_COV
    else:
        config = ScenarioConfig(epsilon=0.0)
        model = filter_model(config)
        mean, cov = initial_state(config), np.diag([1e6, 1e6, 1e6, 1.0, 1.0, 1.0])
        sensors = [AltitudeSensor(30.0), VelocitySensor(0.1)]
        if kind == "compensated lunar":
            model = ModelErrorCompensation(model)
            mean, cov = np.r_[mean, 1e-5, 0.0, -1e-5], np.diag(np.r_[np.diag(cov), 1e-8, 1e-8, 1e-8])
            sensors = [Padded(sensor, 6, 9) for sensor in sensors]
    sensors.insert(0, ModelSensor(model))
    tracker = ObservabilityTracker(model)
    tracker.reset(mean, cov)
    t = 0.0
    for k in range(60):
        dt = 2.0 if k % 3 else 0.5
        u = None if kind == "user model" or k % 2 else rng.normal(size=3) * 0.05
        tracker.predict(dt, t, u)
        t += dt
        for j, sensor in enumerate(sensors):
            if j and k % 4:
                continue
            rows = np.ones(sensor.dim, bool)
            if kind != "user model" and j == 0 and k % 5 == 1:
                rows[1] = False  # no azimuth
            tracker.update(sensor, sensor.measure(tracker.reference[None], t)[0], rows, t, tracker.reference)
    tracker.report()  # (runs the queued calls)
    before = tracker._data.copy()
    moved = tracker.reference * (1.0 + 1e-3 * rng.standard_normal(tracker.reference.size))
    tracker.reanchor(moved)
    free, data = _rebuilt_one_call_at_a_time(tracker)
    assert tracker.reanchors == 1 and tracker._log.size > 100
    if kind != "user model":  # (a linear model's Jacobians do not depend on the reference)
        assert not np.array_equal(tracker._data, before)  # the rebuild moved the recursions
    assert np.array_equal(tracker._free, free) and np.array_equal(tracker._data, data)


def test_the_reference_moves_only_to_a_mean_that_explains_the_measurement():
    """A measurement far beyond the no-data prediction from the reference moves the reference to the filter's
    mean when the mean explains it; when the mean does not either (a gross outlier, a diverged filter) the
    reference stays, and the measurement's information is still counted (a diverged bootstrap filter would
    otherwise rebuild the whole log at every update)."""
    model = hidden_constant_model()
    sensor = ModelSensor(model)
    tracker = ObservabilityTracker(model)
    tracker.reset(PRIOR_MEAN, PRIOR_COV)
    rows = np.ones(1, bool)
    t = 0.0
    for _ in range(10):
        tracker.predict(DT, t)
        t += DT
        tracker.update(sensor, sensor.measure(tracker.reference[None], t)[0], rows, t, tracker.reference)
    far = sensor.measure(tracker.reference[None], t)[0] + 1e4  # ~1000 no-data standard deviations
    tracker.update(sensor, far, rows, t, tracker.reference)  # the filter's mean is no nearer
    assert tracker.reanchors == 0 and tracker.updates == 11
    explained = tracker.reference + np.array([1e4, 0.0, 0.0])
    tracker.update(sensor, far, rows, t, explained)
    assert tracker.reanchors == 1 and tracker.updates == 12
    np.testing.assert_allclose(tracker.reference, explained)


def test_the_rebuild_cost_tool_times_a_full_log():
    from gpf_nav.tools import rebuild_cost
    row = rebuild_cost.measure("ekf-comp", 30, repeats=1)
    assert row["state"] == 9 and row["predictions"] == 30 and row["updates"] == 30 and row["rebuild_ms"] > 0


def test_copies_of_a_tracker_share_their_log_and_diverge_without_touching_each_other():
    """The estimator's history deep-copies filters: a copy shares the log's arrays, and a copy and its
    original that go on differently (the copy first, then the original; a second copy of the copy) each
    rebuild exactly as a tracker that saw only its own steps."""
    import copy
    from gpf_nav.sensors.kinematic import AltitudeSensor
    config = ScenarioConfig(epsilon=0.0)
    model = filter_model(config)
    mean, cov = initial_state(config), np.diag([1e6, 1e6, 1e6, 1.0, 1.0, 1.0])
    sensors = [ModelSensor(model), AltitudeSensor(30.0)]

    def steps(tracker, first, last):
        for k in range(first, last):
            tracker.predict(2.0, 2.0 * k, None)
            sensor = sensors[k % 3 == 0]
            rows = np.ones(sensor.dim, bool)
            rows[1:] = k % 2 == 0  # only the range on odd steps
            tracker.update(sensor, sensor.measure(tracker.reference[None], 2.0 * (k + 1))[0], rows,
                           2.0 * (k + 1), tracker.reference)

    def fresh(*spans):
        tracker = ObservabilityTracker(model)
        tracker.reset(mean, cov)
        for first, last in spans:
            steps(tracker, first, last)
        return tracker

    original = fresh((0, 40))
    copied = copy.deepcopy(original)
    assert copied._log.store is original._log.store
    steps(copied, 40, 90)  # in place: the original has not written past the copy
    assert copied._log.store is original._log.store
    steps(original, 100, 120)  # the copy wrote past the original: the original appends to its own prefix
    assert copied._log.store is not original._log.store
    second = copy.deepcopy(copied)
    steps(second, 200, 210)
    steps(copied, 300, 305)
    for tracker, spans in ((original, [(0, 40), (100, 120)]), (copied, [(0, 40), (40, 90), (300, 305)]),
                           (second, [(0, 40), (40, 90), (200, 210)])):
        oracle = fresh(*spans)
        assert tracker._log.size == oracle._log.size
        moved = tracker.reference * (1.0 + 1e-4)
        for t in (tracker, oracle):
            t.reanchor(moved)
        assert np.array_equal(tracker._free, oracle._free) and np.array_equal(tracker._data, oracle._data)
