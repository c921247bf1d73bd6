"""ROS adapter logic without DDS: validation, conversions, diagnostics, factory, parameters, engine,
batch initialisation and the simulator's event schedule."""
import math
from pathlib import Path

import numpy as np
import pytest

from gpf_nav.estimator import input_checks as val
from gpf_nav.estimator.engine import EngineConfig, EstimatorEngine
from gpf_nav.estimator.factory import FILTERS, make_filter, make_lunar_model
from gpf_nav.estimator.initialization import batch_initial_state, inverse_rae
from gpf_nav.sim.playback import build_events, hermite_state
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

ROOT = Path(__file__).resolve().parents[1]
SHORT = ScenarioConfig(duration=60.0)
S = 1_000_000_000


# --- validation --------------------------------------------------------------------------------------
def test_stamp_and_frame_checks():
    assert val.check_stamp(10, 999_999_999) == (True, "")
    assert val.check_stamp(10, 1_000_000_000) == (False, "bad_stamp")
    assert val.check_stamp(-1, 0) == (False, "bad_stamp")
    assert val.check_frame("station", "station")[0]
    assert val.check_frame("map", "station") == (False, "wrong_frame")
    assert val.check_frame("anything", "")[0]


@pytest.mark.parametrize("values, reason", [
    ((1e6, 0.1, 0.2), ""),
    ((1e6, math.nan, 0.2), ""),                    # masked, not refused
    ((math.inf, 0.1, 0.2), "non_finite"),
    ((1e6, -math.inf, 0.2), "non_finite"),
    ((math.nan, math.nan, math.nan), "no_measured_component"),
    ((-5.0, 0.1, 0.2), "non_positive_range"),
    ((0.0, 0.1, 0.2), "non_positive_range"),
    ((1e6, 3.5, 0.2), "angle_out_of_range"),
    ((1e6, 0.1, 1.6), "angle_out_of_range"),
    ((1e6, math.pi, -math.pi / 2), ""),
])
def test_check_rae(values, reason):
    ok, why, out = val.check_rae(*values)
    assert ok == (reason == "") and why == reason
    np.testing.assert_array_equal(out, values)


def test_check_range_limits():
    assert val.check_range(10.0, 1.0, 100.0)[0]
    assert val.check_range(200.0, 1.0, 100.0) == (False, "range_out_of_limits")
    assert val.check_range(0.5, 1.0, 100.0) == (False, "range_out_of_limits")
    assert val.check_range(math.inf, 1.0, 100.0) == (False, "range_out_of_limits")
    assert val.check_range(math.nan, 1.0, 100.0) == (False, "non_finite")
    assert val.check_range(-3.0, 0.0, 0.0) == (False, "non_positive_range")
    assert val.check_range(5e6, 0.0, 0.0)[0]  # limits not given


def test_quaternion_timing_and_rate():
    assert val.check_quaternion(0, 0, 0, 1, 0.01)[0]
    assert val.check_quaternion(0, 0, 0, 1.1, 0.01) == (False, "non_unit_quaternion")
    assert val.check_quaternion(0, 0, math.nan, 1, 0.01) == (False, "non_finite")
    assert val.check_timing(5 * S, 6 * S, 10 * S, S) == (False, "stale_stamp")
    assert val.check_timing(12 * S, 6 * S, 10 * S, S) == (False, "future_stamp")
    assert val.check_timing(6 * S, 6 * S, 10 * S, S)[0]          # equal stamps are fine
    assert val.check_timing(99 * S, None, 0, S)[0]               # sim clock not started: no future check
    limiter = val.RateLimiter(3)
    assert [limiter.allow(0.1 * i) for i in range(5)] == [True, True, True, False, False]
    assert limiter.allow(1.2)


# --- conversions -------------------------------------------------------------------------------------
def test_odometry_roundtrip_and_covariance_layout():
    from gpf_nav.ros import conversions as conv
    mean = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    cov = np.arange(36.0).reshape(6, 6)
    msg = conv.odometry_msg(mean, cov, 1_500_000_000, "w", "b")
    assert msg.header.frame_id == "w" and msg.child_frame_id == "b"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_000)
    np.testing.assert_array_equal(conv.odometry_state(msg), mean)
    pose = np.array(msg.pose.covariance).reshape(6, 6)
    twist = np.array(msg.twist.covariance).reshape(6, 6)
    np.testing.assert_array_equal(pose[:3, :3], cov[:3, :3])
    np.testing.assert_array_equal(twist[:3, :3], cov[3:, 3:])
    assert np.all(np.diag(pose)[3:] == conv.UNKNOWN_ROTATION_VARIANCE)
    assert msg.pose.pose.orientation.w == 1.0


def test_imu_rotation_and_decimation():
    from sensor_msgs.msg import Imu
    from gpf_nav.ros import conversions as conv
    msg = Imu()
    msg.linear_acceleration.x = 1.0
    s = math.sqrt(0.5)
    msg.orientation.z, msg.orientation.w = s, s  # 90 deg about z: body x -> world y
    np.testing.assert_allclose(conv.imu_specific_force(msg), [0.0, 1.0, 0.0], atol=1e-12)
    msg.orientation_covariance[0] = -1.0          # orientation not provided: taken as world axes
    np.testing.assert_allclose(conv.imu_specific_force(msg), [1.0, 0.0, 0.0])
    particles = np.arange(20.0).reshape(10, 2)
    weights = np.zeros(10)
    weights[3] = 1.0
    assert set(conv.decimate(particles, weights, 4).tolist()) == {3}
    assert len(conv.decimate(particles, np.full(10, 0.1), 20)) == 10


# --- factory and parameters --------------------------------------------------------------------------
@pytest.mark.parametrize("name", FILTERS)
def test_make_filter_runs_every_filter(name):
    s = generate(SHORT, 0)
    f = make_filter(name, filter_model(SHORT), n_particles=50)
    f.initialize(s.prior_mean, s.prior_cov)
    f.predict(2.0)
    f.update(s.measurements[0])
    assert np.all(np.isfinite(f.mean))


def test_the_default_gpf_is_the_multiple_model_gpf():
    from gpf_nav.filters import GeometricProjectionPF, MultipleModelGPF
    model = filter_model(SHORT)
    assert isinstance(make_filter("gpf", model, n_particles=50), MultipleModelGPF)
    assert isinstance(make_filter("gpf-mm", model, n_particles=50), MultipleModelGPF)
    single = make_filter("gpf-single", model, n_particles=50, nominal_prior=0.3)
    assert isinstance(single, GeometricProjectionPF) and single.nominal_prior == 0.3
    nominal = make_filter("gpf", model, n_particles=50, unmodelled_acceleration_std=0.0)
    assert isinstance(nominal, GeometricProjectionPF) and not nominal.compensated
    assert make_filter("gpf", model, n_particles=50, model_switch_time=7.0).switch_time == 7.0


@pytest.mark.parametrize("options, text", [
    (dict(name="bogus"), "'filter' = 'bogus' is not a known filter"),
    (dict(name="gpf", n_particles=-5), "'n_particles' = -5"),
    (dict(name="spf", ess_threshold=0.0), "'ess_threshold' (tau) = 0.0 must lie in (0, 1]"),
    (dict(name="gpf", ess_threshold=1.5), "(0, 1]"),
    (dict(name="gpf", weighting="nope"), "'weighting'"),
    (dict(name="enkf", n_particles=1), "'n_particles' = 1 must be an integer >= 2"),
    (dict(name="gpf-mm", unmodelled_acceleration_std=0.0), "'unmodelled_acceleration_std' = 0.0 must be positive"),
    (dict(name="gpf-mm", model_switch_time=-1.0), "'model_switch_time' = -1.0 must be positive"),
])
def test_make_filter_refuses_with_the_parameter_name(options, text):
    name = options.pop("name")
    with pytest.raises(ValueError, match=None) as err:
        make_filter(name, filter_model(SHORT), **options)
    assert text in str(err.value)


def test_make_lunar_model_refuses_bad_values():
    with pytest.raises(ValueError, match="'range_noise_std'"):
        make_lunar_model(mu=4.9e12, station=[0, 0, 0], range_noise_std=-1.0, angle_noise_std=1e-3,
                         accel_noise_density=1e-3, max_step=10.0)


def _flatten(d, prefix=""):
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, prefix + k + "."))
        else:
            out[prefix + k] = v
    return out


@pytest.mark.parametrize("file, node, specs", [("estimator.yaml", "gpf_estimator", "ESTIMATOR"),
                                                ("simulator.yaml", "lunar_simulator", "simulator")])
def test_config_files_match_code_defaults(file, node, specs):
    yaml = pytest.importorskip("yaml")
    from gpf_nav.estimator.params import ESTIMATOR
    from gpf_nav.sim.simulator_params import simulator_specs
    table = ESTIMATOR if specs == "ESTIMATOR" else simulator_specs()
    data = yaml.safe_load((ROOT / "config" / file).read_text())
    values = _flatten(data["/**/" + node]["ros__parameters"])  # the shipped files match any namespace
    expected = {s.name: s.default for s in table if s.default is not None}
    assert set(values) == set(expected)
    for name, default in expected.items():
        assert values[name] == pytest.approx(default) if isinstance(default, float) else values[name] == default, name


# --- batch initialisation ----------------------------------------------------------------------------
def test_inverse_rae_inverts_the_model():
    model = filter_model(SHORT)
    x = np.array([[1.8e6, -2e5, 3e5, 0, 0, 0]])
    np.testing.assert_allclose(inverse_rae(model.measure(x)[0], model.station), x[0, :3], rtol=1e-12)


def test_batch_initial_state_is_consistent():
    s = generate(ScenarioConfig(duration=40.0), 3)
    model = filter_model(s.config)
    mean, cov = batch_initial_state(model, s.times - s.times[0], s.measurements)
    err = mean - s.truth[-1]
    assert np.linalg.norm(err[:3]) < 3e3 and np.linalg.norm(err[3:]) < 300.0
    assert err @ np.linalg.solve(cov, err) < 50.0  # consistent with its covariance
    partial = s.measurements.copy()
    partial[:, :] = np.nan
    partial[:, 0] = s.measurements[:, 0]
    assert batch_initial_state(model, s.times, partial) is None  # range only: not determined


# --- engine ------------------------------------------------------------------------------------------
class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _engine(scenario, initial=True, **kw):
    model = filter_model(scenario.config)
    cfg = EngineConfig(initial_state=scenario.prior_mean if initial else None,
                       initial_std=np.sqrt(np.diag(scenario.prior_cov)), initial_stamp=100.0 if initial else -1,
                       **kw)
    clock = _Clock()
    return EstimatorEngine(lambda: make_filter("gpf", model, n_particles=100), model, cfg, clock), clock


def _stamp(scenario, k):
    return 100 * S + int(round(scenario.times[k] * S))


def test_engine_tracks_and_refuses_stale_and_future():
    s = generate(SHORT, 1)
    eng, _ = _engine(s, history_length=0.0)  # without a history (late stamps: test_engine_sensors.py)
    assert eng.initialized and eng.init_source == "parameters"
    for k in range(10):
        assert eng.measurement(_stamp(s, k), s.measurements[k], _stamp(s, k)) == (True, "")
    assert np.linalg.norm(eng.mean[:3] - s.truth[10, :3]) < 5e3
    assert eng.measurement(_stamp(s, 5), s.measurements[5], None) == (False, "stale_stamp")
    far = _stamp(s, 20)
    assert eng.measurement(far, s.measurements[20], _stamp(s, 10)) == (False, "future_stamp")
    assert eng.counters.accepted["rae"] == 10
    assert eng.counters.rejected["stale_stamp"] == 1 and eng.counters.rejected["future_stamp"] == 1


def test_engine_extrapolation_leaves_the_filter_alone():
    s = generate(SHORT, 2)
    eng, _ = _engine(s)
    eng.measurement(_stamp(s, 0), s.measurements[0], None)
    before = eng.mean.copy()
    mean, cov = eng.extrapolate(_stamp(s, 0) + S // 2)
    assert np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))
    assert not np.allclose(mean[:3], before[:3])
    np.testing.assert_array_equal(eng.mean, before)
    assert eng.t_ns == _stamp(s, 0)
    # a measurement whose stamp lies before the extrapolation time is still used
    assert eng.measurement(_stamp(s, 1), s.measurements[1], None)[0]


def test_engine_initialises_from_measurements():
    s = generate(SHORT, 4)
    eng, _ = _engine(s, initial=False, init_window=5)
    results = [eng.measurement(_stamp(s, k), s.measurements[k], None) for k in range(6)]
    assert [r[1] for r in results[:4]] == ["buffered"] * 4
    assert results[4] == (True, "") and results[5] == (True, "")
    assert eng.init_source == "measurements"
    assert np.linalg.norm(eng.mean[:3] - s.truth[6, :3]) < 5e3


def test_engine_says_why_it_cannot_initialise_without_azimuth():
    s = generate(ScenarioConfig(duration=60.0, case="partial"), 4)
    eng, _ = _engine(s, initial=False, init_window=3)
    for k in range(6):
        assert eng.measurement(_stamp(s, k), s.measurements[k], None) == (True, "buffered")
    assert not eng.initialized and eng.init_failures == 4
    assert "range, azimuth and elevation" in eng.waiting_for()


def test_engine_imu_zero_order_hold_uses_samples_before_the_stamp():
    s = generate(SHORT, 5)
    eng, _ = _engine(s)
    eng.imu(_stamp(s, 0) - S // 2, np.array([0.1, 0.0, 0.0]), None)
    eng.imu(_stamp(s, 0), np.array([9.0, 9.0, 9.0]), None)   # at the stamp itself: not for this interval
    assert np.allclose(eng.imu_hold.input_at(_stamp(s, 0)), [0.1, 0.0, 0.0])
    assert eng.imu_hold.input_at(_stamp(s, 0) + 5 * S) is None           # older than imu_timeout
    assert eng.imu(_stamp(s, 0) - S, np.zeros(3), None) == (False, "stale_stamp")


def test_engine_set_pose_and_reset():
    s = generate(SHORT, 6)
    eng, _ = _engine(s, initial=False)
    assert eng.set_pose(_stamp(s, 0), s.truth[1, :3], None, None) == (False, "no_velocity")
    eng2, _ = _engine(s)
    eng2.measurement(_stamp(s, 0), s.measurements[0], None)
    assert eng2.set_pose(_stamp(s, 1), s.truth[2, :3], np.eye(3) * 100.0, None) == (True, "")
    assert eng2.init_source == "set_pose"
    np.testing.assert_allclose(eng2.mean[:3], s.truth[2, :3], atol=100.0)
    eng2.reset()
    assert eng2.init_source == "parameters"  # initial_stamp >= 0: back to the start-up state


def test_engine_set_state_is_a_full_handover():
    s = generate(SHORT, 7)
    eng, _ = _engine(s, initial=False)  # no velocity anywhere: set_pose could not initialise it
    now = _stamp(s, 0)
    assert eng.set_state(now + 5 * S, s.prior_mean, s.prior_cov, now) == (False, "future_stamp")
    bad = s.prior_cov.copy()
    bad[0, 0] = np.nan
    assert eng.set_state(now, s.prior_mean, bad, now) == (False, "non_finite")
    assert not eng.initialized
    assert eng.set_state(now, s.prior_mean, s.prior_cov, now) == (True, "")
    assert eng.initialized and eng.init_source == "set_state" and eng.t_ns == now
    assert np.all(np.abs(eng.mean - s.prior_mean) <= 5 * np.sqrt(np.diag(s.prior_cov)))
    assert eng.measurement(_stamp(s, 1), s.measurements[1], None) == (True, "")  # used at once: no init window
    assert eng.set_state(now, s.prior_mean, s.prior_cov, None) == (False, "stale_stamp")
    c = eng.counters
    assert c.accepted["set_state"] == 1 and c.rejected_by_stream[("set_state", "future_stamp")] == 1


def test_engine_set_state_older_than_buffered_measurements_starts_the_filter_before_them():
    """The latched prior delivered just after the first live measurements (an estimator started late):
    not stale while those are only buffered for the batch fit; the filter starts from the prior and
    takes them, exactly as if the prior had come first."""
    s = generate(SHORT, 8)
    start = 100 * S  # the prior's time (truth[0])
    late, _ = _engine(s, initial=False)
    for k in range(2):
        assert late.measurement(_stamp(s, k), s.measurements[k], _stamp(s, k)) == (True, "buffered")
    assert late.set_state(start, s.prior_mean, s.prior_cov, _stamp(s, 1)) == (True, "")
    assert late.init_source == "set_state" and late.t_ns == late.last_update_ns == _stamp(s, 1)
    first, _ = _engine(s, initial=False)
    assert first.set_state(start, s.prior_mean, s.prior_cov, start) == (True, "")
    for k in range(2):
        assert first.measurement(_stamp(s, k), s.measurements[k], _stamp(s, k)) == (True, "")
    np.testing.assert_allclose(late.mean, first.mean, rtol=1e-12)
    np.testing.assert_allclose(late.cov, first.cov, rtol=1e-12)
    assert late.counters.accepted["rae"] == 2 and late.counters.accepted["set_state"] == 1
    assert late.measurement(_stamp(s, 2), s.measurements[2], _stamp(s, 2)) == (True, "")
    # once the filter runs, an older state is stale as before
    assert late.set_state(start, s.prior_mean, s.prior_cov, _stamp(s, 2)) == (False, "stale_stamp")


class _Exploding:
    """Wraps a filter; its estimate turns NaN on the ``after``-th update."""

    def __init__(self, inner, after):
        self.inner, self.after, self.updates = inner, after, 0

    def __getattr__(self, name):
        if name == "inner":  # not set yet (copy.deepcopy builds the copy without __init__)
            raise AttributeError(name)
        return getattr(self.inner, name)

    def update(self, y):
        self.updates += 1
        self.inner.update(y)

    @property
    def mean(self):
        return self.inner.mean * (np.nan if self.updates >= self.after else 1.0)

    @property
    def covariance(self):
        return self.inner.covariance


def test_engine_recovers_from_non_finite_output():
    s = generate(SHORT, 7)
    model = filter_model(SHORT)
    built = []

    def factory():
        f = _Exploding(make_filter("gpf", model, n_particles=100), after=3 if len(built) == 1 else 10 ** 9)  # the 2nd: the one initialised
        built.append(f)
        return f

    clock = _Clock()
    cfg = EngineConfig(initial_state=s.prior_mean, initial_std=np.sqrt(np.diag(s.prior_cov)), initial_stamp=100.0)
    eng = EstimatorEngine(factory, model, cfg, clock)
    results = [eng.measurement(_stamp(s, k), s.measurements[k], None) for k in range(6)]
    assert results[2] == (False, "filter_error")
    assert eng.reinit_count == 1 and eng.in_error and "non-finite" in eng.last_reinit_reason
    assert all(r == (True, "") for r in results[3:])
    assert np.all(np.isfinite(eng.mean))
    clock.t = 100.0
    assert not eng.in_error


def test_diagnostics_levels():
    from gpf_nav.ros import diagnostics as diag
    s = generate(SHORT, 8)
    eng, clock = _engine(s)
    eng.measurement(_stamp(s, 0), s.measurements[0], None)
    th = diag.Thresholds(ess_warn=0.05, costate_warn=1e12, sensor_timeout=10.0)
    level, message, values = diag.filter_status(eng, _stamp(s, 0) + S, th, "gpf")
    assert level == diag.OK and message == "tracking"
    kv = dict(values)
    assert kv["measurements accepted"] == "1" and kv["rejected stale_stamp"] == "0"
    assert diag.filter_status(eng, _stamp(s, 0) + 20 * S, th, "gpf")[0] == diag.WARN  # stale stream
    assert diag.filter_status(eng, _stamp(s, 0) + S, diag.Thresholds(ess_warn=1.1), "gpf")[0] == diag.WARN
    eng._last_reinit_time = clock.t
    assert diag.filter_status(eng, _stamp(s, 0) + S, th, "gpf")[0] == diag.ERROR


def test_diagnostics_warn_when_the_imu_falls_silent():
    """A silent sensor: an IMU heard, then silent for longer than ``imu_timeout`` (the filter then predicts
    without its input) is WARN, with the sample's age; never heard, it is no fault."""
    from gpf_nav.ros import diagnostics as diag
    s = generate(SHORT, 8)
    eng, _ = _engine(s)
    th = diag.Thresholds(ess_warn=0.05, costate_warn=1e12, sensor_timeout=10.0)
    eng.measurement(_stamp(s, 0), s.measurements[0], None)
    level, message, values = diag.filter_status(eng, _stamp(s, 0) + 5 * S, th, "gpf")
    assert level == diag.OK and dict(values)["last IMU sample age"] == "none yet"
    assert eng.imu(_stamp(s, 0) + S, np.array([0.0, 0.0, 0.5]), None) == (True, "")
    eng.measurement(_stamp(s, 1), s.measurements[1], None)
    level, message, values = diag.filter_status(eng, _stamp(s, 0) + int(1.5 * S), th, "gpf")
    assert level == diag.OK and dict(values)["last IMU sample age"] == "0.5"
    level, message, values = diag.filter_status(eng, _stamp(s, 0) + 4 * S, th, "gpf")
    assert level == diag.WARN and "no IMU sample for 3.0 s: predicting without input" in message
    assert dict(values)["last IMU sample age"] == "3"



def test_the_message_layer_logs_a_silent_imu_once_per_throttle_period():
    pytest.importorskip("rclpy")
    from gpf_nav.estimator.params import ESTIMATOR
    from gpf_nav.ros.message_layer import MessageLayer
    lines = []

    class Log:
        def info(self, line):
            lines.append(line)
        warning = error = info

    layer = MessageLayer({spec.name: spec.default for spec in ESTIMATOR}, lambda topic, msg: None, Log())
    assert layer.engine.imu(10 * S, np.array([0.0, 0.0, 0.5]), None) == (True, "")
    layer.diagnostics_tick(10 * S + S // 2, 1.0, "gpf_estimator")
    layer.diagnostics_tick(13 * S, 1.0, "gpf_estimator")
    layer.diagnostics_tick(14 * S, 1.0, "gpf_estimator")
    assert [line for line in lines if "IMU" in line] == [
        "no IMU sample for 3.0 s (imu_timeout 1 s): predicting without input"]


def test_the_message_layer_reports_its_processing_time_per_diagnostics_period():
    """Each measurement message is timed from its callback to its outputs; ``/diagnostics`` gives the
    count, mean and max of the period, then starts a new one (a test clock: 2 ms, then 5 ms)."""
    pytest.importorskip("rclpy")
    from gpf_nav.estimator.params import ESTIMATOR
    from gpf_nav.ros.conversions import vector3_stamped
    from gpf_nav.ros.diagnostics import parse_values
    from gpf_nav.ros.message_layer import MessageLayer
    from gpf_nav.ros.processing_time import ProcessingTime

    class Log:
        def info(self, line):
            pass
        warning = error = info

    s = generate(SHORT, 3)
    params = {spec.name: spec.default for spec in ESTIMATOR}
    params.update(initial_state=list(s.prior_mean), initial_std=list(np.sqrt(np.diag(s.prior_cov))),
                  initial_stamp=_stamp(s, 0) * 1e-9 - 1.0, n_particles=100)
    published = []
    layer = MessageLayer(params, lambda topic, msg: published.append((topic, msg)), Log())
    layer.processing = ProcessingTime(iter([0.0, 0.002, 1.0, 1.005]).__next__)
    for k in range(2):
        layer.handle("rae", vector3_stamped(s.measurements[k], _stamp(s, k), "station"), _stamp(s, k))
    assert any(topic == "odometry/filtered" for topic, _ in published)  # (the messages were processed)

    def diagnostics(now_ns):
        layer.diagnostics_tick(now_ns, 1.0, "gpf_estimator")
        return parse_values([msg for topic, msg in published if topic == "/diagnostics"][-1].status[0])

    values = diagnostics(_stamp(s, 1))
    assert values["measurements timed"] == "2"
    assert float(values["measurement processing mean [ms]"]) == pytest.approx(3.5)
    assert float(values["measurement processing max [ms]"]) == pytest.approx(5.0)
    values = diagnostics(_stamp(s, 1) + S)
    assert values["measurements timed"] == "0" and values["measurement processing max [ms]"] == "n/a"


# --- simulator schedule ------------------------------------------------------------------------------
def test_playback_is_deterministic_and_ordered():
    cfg = ScenarioConfig(duration=20.0, case="partial")
    a = build_events(generate(cfg, 3), 10.0, 1e-4, 5.0, 3)
    b = build_events(generate(cfg, 3), 10.0, 1e-4, 5.0, 3)
    assert repr(a) == repr(b)  # repr: NaN != NaN, but float reprs are exact
    assert [e.t_ns for e in a] == sorted(e.t_ns for e in a)
    meas = [e for e in a if e.kind == "measurement"]
    assert len(meas) == 10 and all(math.isnan(e.data[1]) for e in meas)  # partial: azimuth not measured
    assert sum(e.kind == "imu" for e in a) == 201
    truth_times = {e.t_ns for e in a if e.kind == "truth"}
    assert {e.t_ns for e in meas} <= truth_times
    c = build_events(generate(cfg, 4), 10.0, 1e-4, 5.0, 4)
    assert repr(a) != repr(c)


def test_hermite_interpolation_matches_the_orbit():
    s = generate(ScenarioConfig(duration=4.0, truth_accel_noise_density=0.0), 0)
    mid = hermite_state(0.0, s.truth[0], 2.0, s.truth[1], 1.0)
    from gpf_nav.sim.scenario import truth_model
    exact = truth_model(s.config).transition(s.truth[:1], 1.0)[0]
    assert np.linalg.norm(mid[:3] - exact[:3]) < 0.05 and np.linalg.norm(mid[3:] - exact[3:]) < 0.05
