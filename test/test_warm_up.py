"""The estimator's warm-up (:mod:`gpf_nav.estimator.warm_up`): run in a fresh process before any message,
it loads every compiled kernel the first minutes of the Section 7 descent and a reanchoring of the
observability trackers then call, and it leaves the node's own engine untouched."""
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from gpf_nav.estimator.engine import EngineConfig, EstimatorEngine
from gpf_nav.estimator.factory import make_filter
from gpf_nav.estimator.warm_up import warm_up
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, initial_state

_FRESH_PROCESS = textwrap.dedent("""
    import importlib, json, pkgutil, sys
    import numpy as np
    import gpf_nav.kernels
    from gpf_nav.estimator.params import ESTIMATOR
    from gpf_nav.ros.message_layer import MessageLayer
    from gpf_nav.sim.playback import build_events
    from gpf_nav.sim.scenario import ScenarioConfig, generate

    class Log:
        def info(self, line): pass
        warning = error = info

    def signatures():
        found = {}
        for info in pkgutil.iter_modules(gpf_nav.kernels.__path__):
            module = importlib.import_module("gpf_nav.kernels." + info.name)
            for name, value in vars(module).items():
                if hasattr(value, "py_func") and hasattr(value, "signatures"):
                    found[info.name + "." + name] = [str(s) for s in value.signatures]
        return found

    params = {spec.name: spec.default for spec in ESTIMATOR}
    params["filter"] = sys.argv[1]
    layer = MessageLayer(params, lambda topic, msg: None, Log())
    before = signatures()
    ok, line = layer.warm_up()
    warmed = signatures()
    events = build_events(generate(ScenarioConfig(duration=300.0), 0), 10.0, 0.0, 1.0, 0)
    accepted = 0
    for event in events:
        if event.kind == "imu":
            layer.engine.imu(event.t_ns, event.data, None)
        elif event.kind == "measurement":
            accepted += layer.engine.measurement(event.t_ns, list(event.data), None)[0]
            layer.engine.extrapolate(event.t_ns + 100_000_000)
    # a reanchoring, minutes in: every tracker of the filter (its members') moved to the filter's mean
    mean = layer.engine.filter.mean
    for tracker in layer.engine.filter.observability_trackers():
        tracker.reanchor(np.r_[mean, tracker.reference[mean.size:]])
    print(json.dumps(dict(ok=ok, line=line, before=before, warmed=warmed, after=signatures(),
                          accepted=accepted, initialized=layer.engine.initialized)))
""")


@pytest.mark.parametrize("name", ["gpf", "spf"])
def test_after_the_warm_up_the_descent_compiles_no_kernel(name):
    import json
    out = subprocess.run([sys.executable, "-c", _FRESH_PROCESS, name], capture_output=True, text=True,
                         check=True).stdout
    result = json.loads(out.splitlines()[-1])
    assert result["ok"], result["line"]
    assert not any(result["before"].values())  # a fresh process: nothing loaded yet
    assert result["initialized"] and result["accepted"] >= 140
    new = {kernel: sorted(set(after) - set(result["warmed"][kernel]))
           for kernel, after in result["after"].items() if set(after) - set(result["warmed"][kernel])}
    assert not new, f"kernels first called after the warm-up: {new}"


@pytest.mark.parametrize("name", ["gpf", "ekf"])
def test_the_warm_up_leaves_the_engine_untouched(name):
    model = filter_model(ScenarioConfig())
    engine = EstimatorEngine(lambda: make_filter(name, model, n_particles=100, seed=1), model, EngineConfig())
    seconds, error = warm_up(engine, initial_state(ScenarioConfig()))
    assert error == ""
    assert not engine.initialized and engine.counters.total_rejected == 0 and not engine.counters.accepted


def test_a_failed_warm_up_is_reported_not_raised():
    model = filter_model(ScenarioConfig())
    engine = EstimatorEngine(lambda: make_filter("gpf", model, n_particles=100, seed=1), model, EngineConfig())
    seconds, error = warm_up(engine, np.full(6, np.nan))  # nothing measured: no initialisation
    assert error.startswith("RuntimeError: 0 updates") and not engine.initialized
    broken = EstimatorEngine(lambda: make_filter("gpf", model, n_particles=100, seed=1), model, EngineConfig())
    broken.factory = lambda: make_filter("no-such-filter", model)
    seconds, error = warm_up(broken, initial_state(ScenarioConfig()))
    assert error.startswith(("ValueError", "KeyError")) and not broken.initialized


@pytest.mark.parametrize("name", ["gpf", "ekf"])
def test_the_warm_up_runs_with_a_prior_handed_over_at_a_stamp(name):
    """``initial_state`` at ``initial_stamp`` (a prior given at a ROS time, as ``gpf-nav bench --node``
    gives it): the rehearsal's stamps start there. They started at 0 and were refused as older than the
    prior, so the warm-up failed and the first updates waited for the kernels."""
    model = filter_model(ScenarioConfig())
    state = initial_state(ScenarioConfig())
    config = EngineConfig(initial_state=state, initial_std=np.array([1e3, 1e3, 1e3, 1.0, 1.0, 1.0]),
                          initial_stamp=1.7e9)
    engine = EstimatorEngine(lambda: make_filter(name, model, n_particles=100, seed=1), model, config)
    mean, stamp = engine.mean.copy(), engine.t_ns  # (initialised from the parameters already)
    seconds, error = warm_up(engine, state)
    assert error == ""
    assert np.array_equal(engine.mean, mean) and engine.t_ns == stamp and not engine.counters.accepted
