"""``gpf-nav bench`` (run small) and the heap and OpenMP tuning the command applies."""
import json
import os
import platform

import numpy as np
import pytest

from gpf_nav import allocator, cli, openmp
from gpf_nav.experiments import bench, peer_particles


def test_bench_reports_every_filter_and_the_ratio_of_the_same_run(capsys):
    assert cli.main(["bench", "--json", "--particles", "200", "--repeats", "1", "--warmup", "5"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["warmup"] == 5
    names = [(r["filter"], r["particles"]) for r in report["results"]]
    peer = [("particles", 200)] if peer_particles.available() else []  # the peer row when installed
    assert names == [("gpf", 200), ("gpf-paper", 200), ("gpf-single", 200), ("spf", 200), *peer, ("ekf", None),
                     ("ukf", None), ("enkf", 500)]
    times = {name: r["us_per_step"] for name, r in zip(names, report["results"])}
    blocks = {name: np.array(r["blocks_us"]) for name, r in zip(names, report["results"])}
    assert all(np.isfinite(t) and t > 0 for t in times.values())
    assert all(times[name] == pytest.approx(np.median(b)) and b.size == 1 for name, b in blocks.items())
    # each time comes with the estimate's accuracy at the block's end (the prior's spread is 1 km): every
    # filter stays within a few kilometres; the default, compensated, is also honest (the others are not
    # told of the scenario's 9 % gravity mismatch)
    for r in report["results"]:
        assert r["position_rms_m"] == pytest.approx(r["position_worst_m"]), r  # (one block)
        assert 0.0 < r["position_worst_m"] < 10_000.0 and 0.0 < r["velocity_rms_m_s"] < 100.0, r
        assert 0.0 < r["nees_mean"] < np.inf, r
    default = report["results"][0]
    assert default["position_worst_m"] < 2_000.0 and default["nees_mean"] < 50.0, default
    # the ratios are the medians over rounds of the ratio of the two filters' blocks of a round
    assert report["gpf_over_spf"]["200"] == pytest.approx(
        np.median(blocks[("gpf", 200)] / blocks[("spf", 200)]))
    assert report["gpf_over_paper_gpf"]["200"] == pytest.approx(
        np.median(blocks[("gpf", 200)] / blocks[("gpf-paper", 200)]))
    for key, numerator in (("gpf_over_particles", "gpf"), ("spf_over_particles", "spf"),
                           ("paper_gpf_over_particles", "gpf-paper")):
        if peer:
            assert report[key]["200"] == pytest.approx(
                np.median(blocks[(numerator, 200)] / blocks[("particles", 200)]))
        else:
            assert report[key] == {}
    expected = "retain_freed_memory" if allocator.retained else "default"
    assert report["machine"]["allocator"] == expected
    text = bench.format_table(report)
    assert "position m" in text and "after 5 steps" in text and "GPF/SPF: N=200:" in text
    assert "GPF/GPF-paper: N=200:" in text and f"allocator: {expected}" in text
    assert report["machine"]["omp_wait_policy"] == os.environ.get("OMP_WAIT_POLICY", "default")
    if peer:
        assert "SPF/particles: N=200:" in text and "GPF-paper/particles: N=200:" in text


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_retain_freed_memory_applies_on_glibc():
    assert allocator.retain_freed_memory() is True
    assert allocator.retained
    assert np.ones((4, 10_000_000 // 4)).sum() == 10_000_000  # the heap still works with big blocks


def test_openmp_waits_are_made_passive_unless_the_user_chose_or_the_threads_run(monkeypatch):
    from numba.np.ufunc import parallel

    monkeypatch.setattr(parallel, "_is_initialized", False)
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    assert openmp.passive_openmp_waits() is False and os.environ["OMP_WAIT_POLICY"] == "ACTIVE"
    monkeypatch.delenv("OMP_WAIT_POLICY")
    monkeypatch.setattr(parallel, "_is_initialized", True)
    assert openmp.passive_openmp_waits() is False and "OMP_WAIT_POLICY" not in os.environ
    monkeypatch.setattr(parallel, "_is_initialized", False)
    assert openmp.passive_openmp_waits() is True and os.environ["OMP_WAIT_POLICY"] == "PASSIVE"


def test_bench_steps_follow_the_measurements_in_order():
    """Each timed step takes the next measurement (none twice), so the filter tracks the truth: no
    measurement is gated as an outlier, as it would be if the sequence restarted."""
    from dataclasses import replace

    from gpf_nav.filters import GeometricProjectionPF
    from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

    config = replace(ScenarioConfig(), duration=2.0 * (bench.WARMUP + 2 * 10 + 1))
    scenario, model = generate(config, 0), filter_model(config)
    made = []
    bench.time_filter(lambda m, seed: made.append(GeometricProjectionPF(m, 200, seed=seed)) or made[-1],
                      scenario, model, steps=10, repeats=2)
    assert made[0].gated == 0 and made[0].time == pytest.approx(2.0 * (bench.WARMUP + 20))
    with pytest.raises(ValueError, match="measurements"):
        bench.time_filter(lambda m, seed: GeometricProjectionPF(m, 200, seed=seed), scenario, model,
                          steps=10, repeats=3)
    later = []  # after a longer warm-up the blocks start further along the descent
    bench.time_filter(lambda m, seed: later.append(GeometricProjectionPF(m, 200, seed=seed)) or later[-1],
                      scenario, model, steps=10, repeats=1, warmup=bench.WARMUP + 10)
    assert later[0].time == pytest.approx(made[0].time)


def test_with_reports_every_filters_observability_recursions_run_inside_the_timed_blocks():
    """A bootstrap PF's tracker queues its recursions until its report is read: without ``reports`` the blocks
    leave them queued (untimed), with it none is left; a filter without a report runs either way; the estimates
    are the same."""
    from dataclasses import replace

    from gpf_nav.filters import BootstrapPF
    from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

    config = replace(ScenarioConfig(), duration=2.0 * (bench.WARMUP + 2 * 10 + 1))
    scenario, model = generate(config, 0), filter_model(config)
    made = {}
    for reports in (False, True):
        made[reports] = []
        bench.time_filters([lambda m, seed, out=made[reports]: out.append(BootstrapPF(m, 200, seed=seed)) or out[-1],
                            lambda m, seed: _Recorder([])], scenario, model, steps=10, repeats=2, reports=reports)
    quiet, read = made[False][0], made[True][0]
    assert len(quiet._observability._queue) == 2 * (bench.WARMUP + 20)  # (a prediction and an update a step)
    assert len(read._observability._queue) == 0
    np.testing.assert_array_equal(quiet.mean, read.mean)
    assert quiet.observability.updates == read.observability.updates == bench.WARMUP + 20
    report = bench.run((200,), repeats=1, filters=("spf",), warmup=2, reports=True)
    assert report["reports"] is True and "observability report read at each step" in bench.format_table(report)


class _Recorder:
    """A filter that records which measurement each of its updates got, and when (a shared counter)."""

    clock = 0
    observability = None

    def __init__(self, log):
        self.log = log

    def initialize(self, mean, cov):
        pass

    def predict(self, dt):
        pass

    def update(self, y):
        _Recorder.clock += 1
        self.log.append((_Recorder.clock, float(y[0])))


def test_filters_of_a_group_are_timed_in_turn_each_on_its_own_measurements_in_order():
    from dataclasses import replace

    from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

    config = replace(ScenarioConfig(), duration=2.0 * (bench.WARMUP + 3 * 4 + 1))
    scenario = generate(config, 0)
    logs = [[], [], []]
    makers = [lambda model, seed, log=log: _Recorder(log) for log in logs]
    blocks = bench.time_filters(makers, scenario, filter_model(config), steps=4, repeats=3)
    assert [len(b) for b in blocks] == [3, 3, 3] and all(t >= 0.0 for b in blocks for t in b)
    ranges = scenario.measurements[:bench.WARMUP + 12, 0].tolist()
    for log in logs:  # every filter: each measurement once, in order
        assert [y for _, y in log] == ranges
    # round r starts with filter r (mod 3): the first timed update of each filter in each round, in time order
    for round_ in range(3):
        starts = [log[bench.WARMUP + 4 * round_][0] for log in logs]
        assert int(np.argmin(starts)) == round_


@pytest.mark.skipif(not peer_particles.available(), reason="particles is not installed")
def test_particles_bootstrap_tracks_the_descent():
    """The peer row runs a real filter: ``particles``' bootstrap filter on our lunar model stays within a
    few kilometres of the truth over 20 steps (the prior's spread is 1 km)."""
    from dataclasses import replace

    from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

    config = replace(ScenarioConfig(), duration=2.0 * 21)
    scenario, model = generate(config, 0), filter_model(config)
    f = peer_particles.ParticlesBootstrap(model, 2000, seed=1)
    f.initialize(scenario.prior_mean, scenario.prior_cov)
    for k in range(20):
        f.predict(config.dt)
        f.update(scenario.measurements[k])
    assert np.linalg.norm(f.mean[:3] - scenario.truth[20, :3]) < 3e3


def test_the_model_call_timer_counts_outermost_calls_and_leaves_the_model_as_it_was():
    """Every public method of the model instance is timed while the timer is installed; a model method that
    calls another (the default ``measure_and_jacobian`` calls ``measure`` and ``measurement_jacobian``)
    counts once; each block records its calls per step; afterwards the class's methods answer again."""
    from gpf_nav.experiments.model_calls import ModelCallTimer
    from gpf_nav.models.linear import LinearGaussianModel

    model = LinearGaussianModel(A=[[0.0, 1.0], [0.0, 0.0]], G=[[0.0], [1.0]], C=[[1.0, 0.0]], R=[[1.0]])
    x = np.ones((3, 2))
    with ModelCallTimer(model) as timer:
        assert "measure" in vars(model) and "transition" in vars(model)
        np.testing.assert_array_equal(model.measure(x), x[:, :1])  # (the model's own answer)
        assert timer.calls == 1
        model.measure_and_jacobian(x)
        assert timer.calls == 2 and timer.seconds > 0.0
        timer.start_block()
        for _ in range(4):
            model.transition(x, 1.0)
        model.measure_and_jacobian(x)
        timer.end_block(7, steps=5)
        assert [calls for _, calls in timer.blocks[7]] == [1.0] and timer.blocks[7][0][0] > 0.0
    assert not {"measure", "transition", "measure_and_jacobian"} & set(vars(model)) and timer.calls == 7
    model.measure(x)
    assert timer.calls == 7


def test_bench_splits_each_step_into_the_model_and_the_filter_with_model_calls():
    """``--model-calls``: every row has the time and calls per step inside the lunar model, part of its step:
    a bootstrap PF calls it at least to propagate and to weigh, the default many times more (its flows ahead);
    without the option the rows have neither."""
    report = bench.run((200,), repeats=2, filters=("gpf", "spf", "ekf"), warmup=2, model_calls=True)
    rows = {r["filter"]: r for r in report["results"]}
    for r in rows.values():
        assert 0.0 < r["model_us_per_step"] < r["us_per_step"] and r["model_calls_per_step"] >= 2.0, r
    assert rows["gpf"]["model_calls_per_step"] > 5 * rows["spf"]["model_calls_per_step"]
    assert report["model_calls"] is True and "in the model" in bench.format_table(report)
    plain = bench.run((200,), repeats=1, filters=("spf",), warmup=2)
    assert "model_us_per_step" not in plain["results"][0] and "in the model" not in bench.format_table(plain)
