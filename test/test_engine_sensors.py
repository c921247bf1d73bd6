"""The estimator engine with sensors of their own, late measurements and innovation gates (no ROS):
a TRN fix delivered after later measurements is fused at its stamp and gives, bit for bit, the
estimate of in-order delivery; stamps older than the history are refused and counted."""
import numpy as np
import pytest

from gpf_nav.estimator.engine import EngineConfig, EstimatorEngine
from gpf_nav.estimator.factory import make_filter
from gpf_nav.estimator.history import SNAPSHOT_EVERY, configuration
from gpf_nav.estimator.measurements import InnovationGate
from gpf_nav.filters import ExtendedKF, SensorBiasFilter
from gpf_nav.models import LinearGaussianModel
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate
from gpf_nav.sim.sensor_suite import SuiteConfig, generate_suite, suite_sensors
from gpf_nav.sensors import Bias, PositionSensor

S = 1_000_000_000
T0 = 100 * S


class _Clock:
    def __call__(self):
        return 0.0


def _setup(name, history_length=10.0, **kw):
    scenario = generate(ScenarioConfig(duration=120.0), 3)
    suite = generate_suite(scenario, SuiteConfig(trn_outlier_probability=0.0, altimeter_max_altitude=1e9,
                                                 velocimeter_max_altitude=1e9), 3)
    model = filter_model(scenario.config)
    cfg = EngineConfig(initial_state=scenario.prior_mean, initial_std=np.sqrt(np.diag(scenario.prior_cov)),
                       initial_stamp=T0 * 1e-9, history_length=history_length, **kw)
    engine = EstimatorEngine(lambda: make_filter(name, model, n_particles=200, seed=5), model, cfg, _Clock())
    return scenario, suite, suite_sensors(suite.config), engine


def _events(scenario, suite):
    """(stamp, stream, y) in stamp order: rae every step, the suite's sensors where they measure."""
    out = []
    for k, t in enumerate(scenario.times):
        stamp = T0 + int(round(t * S))
        out.append((stamp, "rae", scenario.measurements[k]))
        for stream in ("altitude", "velocity", "position"):  # a late fix goes after equal stamps
            y = getattr(suite, stream)[k]
            if np.all(np.isfinite(y)):
                out.append((stamp, stream, y))
    return out


def _run(engine, sensors, events):
    for stamp, stream, y in events:
        ok, reason = engine.measurement(stamp, y, None, stream, sensors.get(stream))
        assert ok, (stream, stamp, reason)
    return engine.mean.copy(), engine.cov.copy()


@pytest.mark.parametrize("name", ["ekf", "gpf", "spf", "ukf"])
def test_a_late_fix_gives_the_estimate_of_in_order_delivery(name):
    scenario, suite, sensors, in_order = _setup(name)
    events = _events(scenario, suite)
    mean, cov = _run(in_order, sensors, events)
    assert in_order.late_count == 0 and in_order.counters.accepted["position"] >= 5

    *_, late = _setup(name)
    latency = 4 * S  # every fix delivered 4 s after its stamp: after the later rae measurements
    arrival = sorted(events, key=lambda e: e[0] + (latency if e[1] == "position" else 0))
    late_mean, late_cov = _run(late, sensors, arrival)
    last = events[-1][0]
    delayed = sum(1 for stamp, stream, _ in events if stream == "position" and stamp + latency < last)
    assert late.late_count == delayed >= 5 and late.replayed_count > 0
    np.testing.assert_array_equal(late_mean, mean)
    np.testing.assert_array_equal(late_cov, cov)
    assert late.counters.accepted == in_order.counters.accepted


def test_stamps_older_than_the_history_or_the_start_are_refused():
    scenario, suite, sensors, engine = _setup("ekf", history_length=5.0)
    events = [e for e in _events(scenario, suite) if e[1] == "rae"][:20]
    fix = suite.position[np.flatnonzero(np.isfinite(suite.position[:, 0]))[0]]
    _run(engine, sensors, events[:1])
    assert engine.measurement(T0 - S, fix, None, "position", sensors["position"]) == (False, "stale_stamp")
    _run(engine, sensors, events[1:])
    t = engine.t_ns
    assert engine.measurement(t - 6 * S, fix, None, "position", sensors["position"]) == (False, "older_than_history")
    ok, _ = engine.measurement(t - 4 * S, fix, None, "position", sensors["position"])
    assert ok and engine.late_count == 1 and engine.t_ns == t
    assert engine.counters.rejected_by_stream[("position", "older_than_history")] == 1
    # the window's inputs, and those back to the last snapshot before them
    assert len(engine.history) <= 5 / scenario.config.dt + 2 + SNAPSHOT_EVERY - 1
    snapshots = [k for k, e in enumerate(engine.history.entries) if e.before is not None]
    assert snapshots[0] == 0 and np.all(np.diff(snapshots) <= SNAPSHOT_EVERY)


def test_a_late_input_restarts_from_the_last_snapshot_before_it():
    """Snapshots every SNAPSHOT_EVERY inputs: a late input re-applies the kept inputs from the last one
    with a snapshot, those before it included, and the estimate is that of in-order delivery."""
    scenario, suite, sensors, engine = _setup("gpf", history_length=60.0)
    *_, in_order = _setup("gpf", history_length=60.0)
    events = [e for e in _events(scenario, suite) if e[1] == "rae"][:12]
    fix = suite.position[np.flatnonzero(np.isfinite(suite.position[:, 0]))[0]]
    late = (events[5][0] + S // 2, "position", fix)  # between the 6th and the 7th input
    _run(engine, sensors, events)
    assert [e.before is not None for e in engine.history.entries] == [k % SNAPSHOT_EVERY == 0 for k in range(12)]
    _run(engine, sensors, [late])
    assert engine.late_count == 1 and engine.replayed_count == 12 - 4  # from the 5th input (a snapshot) on
    mean, cov = _run(in_order, sensors, sorted(events + [late], key=lambda e: e[0]))
    np.testing.assert_array_equal(engine.mean, mean)
    np.testing.assert_array_equal(engine.cov, cov)


def test_snapshots_share_the_packages_models_and_sensors_and_copy_the_state():
    scenario, suite, sensors, engine = _setup("gpf")
    _run(engine, sensors, [e for e in _events(scenario, suite) if e[1] == "rae"][:SNAPSHOT_EVERY + 1])
    live, snapshot = engine.filter, engine.history.entries[SNAPSHOT_EVERY].before
    for member, copied in zip(live.members, snapshot.members):
        assert copied.model is member.model and copied._own_sensor is member._own_sensor
        assert copied.rng is not member.rng and copied.time < member.time  # (the state before the input)
    assert snapshot.nominal._x is not live.nominal._x


class _UsersModel(LinearGaussianModel):
    """A model class of the user's own: it may keep state that a snapshot must restore."""


def test_a_users_model_is_copied_with_the_snapshot():
    users = _UsersModel(np.eye(2), np.eye(2), 0.1 * np.eye(2), 0.1 * np.eye(2))
    assert configuration(ExtendedKF(users)) == {}
    ours = configuration(ExtendedKF(LinearGaussianModel(np.eye(2), np.eye(2), 0.1 * np.eye(2), 0.1 * np.eye(2))))
    assert len(ours) == 2  # the model and its own sensor


@pytest.mark.parametrize("name", ["ekf", "gpf"])
def test_an_imu_sample_delivered_after_the_measurement_it_precedes_gives_the_in_order_estimate(name):
    """The IMU and the measurements are two topics: a measurement may be handled before the sample stamped
    just before it. The history is then re-applied with that sample, and the estimate is that of stamp
    order bit for bit; a sample too old to be any measurement's input (imu_timeout) changes nothing."""
    scenario, suite, sensors, in_order = _setup(name)
    *_, swapped = _setup(name)
    rae = [e for e in _events(scenario, suite) if e[1] == "rae"][:15]
    imu = [(stamp - S // 10, np.array([0.02 * (-1) ** k, 0.01 * k, 0.0])) for k, (stamp, _, _) in enumerate(rae)]
    for (stamp, force), event in zip(imu, rae):
        assert in_order.imu(stamp, force, None) == (True, "")
        _run(in_order, sensors, [event])
    for (stamp, force), event in zip(imu, rae):
        _run(swapped, sensors, [event])
        assert swapped.imu(stamp, force, None) == (True, "")
    assert swapped.late_imu_count == len(rae) and in_order.late_imu_count == 0
    for engine in (swapped, in_order):  # the IMU catches up with the filter's time: the last one is applied
        assert engine.imu(rae[-1][0], np.zeros(3), None) == (True, "")
    # while samples come late the newest input keeps a snapshot: each re-applies that input only
    assert swapped.replayed_count == len(rae)
    np.testing.assert_array_equal(swapped.mean, in_order.mean)
    np.testing.assert_array_equal(swapped.cov, in_order.cov)
    _run(swapped, sensors, [(rae[-1][0] + 3 * S, "rae", rae[-1][2])])
    mean = swapped.mean.copy()
    assert swapped.imu(rae[-1][0] + S, np.ones(3), None) == (True, "")  # 2 s before it: beyond imu_timeout
    assert swapped.late_imu_count == len(rae)
    np.testing.assert_array_equal(swapped.mean, mean)


def test_an_imu_stream_that_lags_by_seconds_is_re_applied_once_per_measurement_not_once_per_sample():
    """A backlog of IMU samples (delivered 3 measurements late) re-applies the history when a measurement
    comes or the stream catches up, from the earliest late sample, not at every sample: per-sample
    re-application cost about 10 times more, enough to keep a node too busy to drain the backlog. The
    estimate is that of stamp order bit for bit once the stream has caught up."""
    lag = 3
    scenario, suite, sensors, in_order = _setup("gpf")
    *_, lagging = _setup("gpf")
    rae = [e for e in _events(scenario, suite) if e[1] == "rae"][:15]
    samples = [[(stamp - k * S // 10, np.array([0.01 * k, -0.02, 0.005 * j])) for k in range(19, -1, -1)]
               for j, (stamp, _, _) in enumerate(rae)]  # 10 Hz, up to each measurement's stamp
    for interval, event in zip(samples, rae):
        for stamp, force in interval:
            assert in_order.imu(stamp, force, None) == (True, "")
        _run(in_order, sensors, [event])
    for j, event in enumerate(rae):
        _run(lagging, sensors, [event])
        for stamp, force in samples[j - lag] if j >= lag else ():
            assert lagging.imu(stamp, force, None) == (True, "")
    assert lagging.replayed_count <= (lag + SNAPSHOT_EVERY) * len(rae)  # (once per sample: about 10 times this)
    for interval in samples[-lag:]:
        for stamp, force in interval:
            assert lagging.imu(stamp, force, None) == (True, "")
    assert lagging.late_imu_count > len(rae)
    np.testing.assert_array_equal(lagging.mean, in_order.mean)
    np.testing.assert_array_equal(lagging.cov, in_order.cov)


def test_without_history_a_late_stamp_is_stale():
    scenario, suite, sensors, engine = _setup("ekf", history_length=0.0)
    events = [e for e in _events(scenario, suite) if e[1] == "rae"][:5]
    _run(engine, sensors, events)
    assert len(engine.history) == 0
    assert engine.measurement(events[2][0], events[2][2], None) == (False, "stale_stamp")


def test_the_innovation_gate_refuses_an_outlier_then_yields_after_the_limit():
    scenario, suite, sensors, engine = _setup("ekf", gates={"position": 0.999}, gate_limit=2)
    events = _events(scenario, suite)
    _run(engine, sensors, [e for e in events if e[0] <= T0 + 30 * S])
    t = engine.t_ns
    truth = scenario.truth[1 + int(round((t - T0) / S / scenario.config.dt)), :3]
    outlier = truth + 5e3
    for k in (1, 2):
        assert engine.measurement(t + k * S, outlier, None, "position", sensors["position"]) == \
            (False, "innovation_gate")
    assert engine.measurement(t + 3 * S, outlier, None, "position", sensors["position"]) == (True, "")
    assert engine.counters.rejected_by_stream[("position", "innovation_gate")] == 2
    assert np.all(np.isfinite(engine.mean))


class _Hypotheses:
    """A filter holding two models at known predicted estimates of a 3-state position."""

    time = 0.0

    def __init__(self, *means):
        self.means = means

    def predicted_estimates(self, sensor):
        return [(sensor, np.array(mean, dtype=float), np.eye(3)) for mean in self.means]


def test_the_gate_refuses_only_what_no_model_of_the_filter_explains():
    """A multiple-model filter's hypotheses are tested one by one: a fix 10 sigmas from the first model and
    at the second passes; 10 sigmas from both, it is refused; and a real multiple-model filter gives every
    member of positive probability, the most probable first."""
    gate = InnovationGate(EngineConfig(gates={"position": 0.9999}, gate_limit=5))
    sensor = PositionSensor(1e-6)
    far = np.array([10.0, 0.0, 0.0])
    assert not gate.refuses(_Hypotheses([0.0] * 3, far), "position", sensor, far)
    assert gate.refuses(_Hypotheses([0.0] * 3, -far), "position", sensor, far)
    scenario = generate(ScenarioConfig(duration=20.0), 3)
    flt = make_filter("gpf", filter_model(scenario.config), n_particles=100, seed=5)
    flt.initialize(scenario.prior_mean, scenario.prior_cov)
    flt.predict(2.0)
    flt.update(scenario.measurements[1])
    estimates = flt.predicted_estimates(sensor)
    order = np.argsort(-flt.model_probabilities, kind="stable")
    assert len(estimates) == len(flt.members)
    for (lifted, mean, cov), j in zip(estimates, order):
        assert lifted is sensor
        np.testing.assert_array_equal(mean, flt.members[j].mean)
        np.testing.assert_array_equal(cov, flt.members[j].covariance)


def test_the_gate_of_a_biased_sensor_subtracts_its_estimated_bias():
    """The suite's TRN fixes offset by (300, -200, 100) m, 6 of their sigma, the offset estimated as a
    bias of prior sigma 500 m (a consistent model, epsilon 0): the gate tests the innovation of the
    biased prediction, with the bias sigma, so no fix is refused and the bias is learnt. Gated on the
    user's state alone, at most one fix in gate_limit + 1 would pass."""
    scenario = generate(ScenarioConfig(duration=200.0, epsilon=0.0), 3)
    suite = generate_suite(scenario, SuiteConfig(trn_outlier_probability=0.0), 3)
    model = filter_model(scenario.config)
    trn = PositionSensor(suite.config.trn_noise_std, bias=Bias((500.0,) * 3, (np.inf,) * 3))
    cfg = EngineConfig(initial_state=scenario.prior_mean, initial_std=np.sqrt(np.diag(scenario.prior_cov)),
                       initial_stamp=T0 * 1e-9, gates={"position": 0.9999}, gate_limit=5)
    engine = EstimatorEngine(lambda: SensorBiasFilter(lambda m: make_filter("ekf", m), model, [trn]),
                             model, cfg, _Clock())
    offset = np.array([300.0, -200.0, 100.0])
    fixes = 0
    for stamp, stream, y in _events(scenario, suite):
        if stream == "rae":
            assert engine.measurement(stamp, y, None) == (True, "")
        elif stream == "position":
            assert engine.measurement(stamp, y + offset, None, "position", trn) == (True, ""), fixes
            fixes += 1
    assert fixes >= 15 and engine.counters.rejected_by_stream[("position", "innovation_gate")] == 0
    bias, sigma = engine.filter.sensor_bias("position")
    assert np.all(np.abs(bias - offset) < 4.0 * sigma) and sigma.max() < 100.0, (bias, sigma)


def test_a_sensor_measurement_does_not_initialise_from_data():
    scenario, suite, sensors, _ = _setup("ekf")
    model = filter_model(scenario.config)
    engine = EstimatorEngine(lambda: make_filter("ekf", model), model, EngineConfig(), _Clock())
    assert engine.measurement(T0, suite.velocity[1], None, "velocity", sensors["velocity"]) == \
        (False, "not_initialized")
    assert not engine.initialized


class _Uncopyable:
    """A filter wrapper that cannot be deep-copied."""

    def __init__(self, inner):
        self.__dict__["inner"] = inner

    def __getattr__(self, name):
        return getattr(self.__dict__["inner"], name)

    def __deepcopy__(self, memo):
        raise TypeError("not copyable")


def test_a_filter_that_cannot_be_copied_runs_without_late_fusion():
    scenario, suite, sensors, engine = _setup("ekf")
    model = engine.model
    engine.factory = lambda: _Uncopyable(make_filter("ekf", model))
    engine.reset()
    events = [e for e in _events(scenario, suite) if e[1] == "rae"][:6]
    _run(engine, sensors, events)
    assert engine.snapshot_failures == 6 and len(engine.history) == 0
    assert engine.measurement(events[3][0], events[3][2], None) == (False, "older_than_history")
