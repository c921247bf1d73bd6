"""The filter interface (gpf_nav/filters/interface.py): every filter the registry and the node's factory
make is a ``Filter``, declares its optional capabilities and answers each of them; nothing in gpf_nav
finds a filter's extras (or the estimator engine's) by probing (``hasattr``/``getattr``) or forwards them
with ``__getattr__``."""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from gpf_nav import registry
from gpf_nav.estimator.factory import FILTERS, make_filter
from gpf_nav.filters import Filter, SensorBiasFilter
from gpf_nav.filters.composite import Composite
from gpf_nav.filters.multiple_model import MultipleModelGPF
from gpf_nav.filters.interface import (ATTRIBUTES, CAPABILITIES, CLOUD, COMPENSATION, COSTATE, GATE, MODEL_PROBABILITIES,
                                       RESAMPLING, SENSOR_BIAS, TEMPERING)
from gpf_nav.sensors import ModelSensor, random_constant_bias
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

PACKAGE = Path(__file__).resolve().parents[1] / "gpf_nav"
FILTER_NAMES = {"f", "flt", "filter", "fresh", "self.filter", "engine.filter", "self.filter.filter",
                "engine", "self.engine"}
"""How gpf_nav spells a filter object, or the estimator engine around one (the first argument a probe of
one would have)."""


def _probes(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef) and node.name == "__getattr__":
            found.append(f"{path.name}:{node.lineno} defines __getattr__")
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ("hasattr", "getattr") and node.args
              and ast.unparse(node.args[0]) in FILTER_NAMES):
            found.append(f"{path.name}:{node.lineno} {ast.unparse(node)}")
    return found


def test_no_filter_is_probed_or_forwarded_by_getattr():
    found = [p for path in sorted(PACKAGE.rglob("*.py")) for p in _probes(path)]
    assert not found, "declare a capability on Filter instead: " + "; ".join(found)


def test_the_probe_check_sees_a_probe(tmp_path):
    path = tmp_path / "probe.py"
    path.write_text("def stats(f):\n    return getattr(f, 'ess', None)\n"
                    "class W:\n    def __getattr__(self, name):\n        return 0\n")
    assert len(_probes(path)) == 2


ANSWERS = {
    CLOUD: lambda f: f.particles.ndim == 2 and (f.weights is None or f.weights.shape == f.particles.shape[:1]),
    RESAMPLING: lambda f: 0.0 < f.ess <= 1.0 and f.resample_count >= 0 and f.resampled in (True, False),
    COSTATE: lambda f: (f.costate_mean.ndim == 1 and f.costate_measured.dtype == bool
                        and np.isfinite(f.costate_norm_mean) and np.isfinite(f.costate_norm_max)),
    GATE: lambda f: f.gated >= 0,
    TEMPERING: lambda f: f.tempered_updates >= 0,
    MODEL_PROBABILITIES: lambda f: (f.model_probabilities.ndim == 1 and f.model_probabilities.size >= 2
                                    and np.isclose(f.model_probabilities.sum(), 1)),
    COMPENSATION: lambda f: (f.unmodelled_acceleration.size > 0 and f.unmodelled_acceleration_covariance.shape
                             == (f.unmodelled_acceleration.size,) * 2),
    SENSOR_BIAS: lambda f: all(len(f.sensor_bias(name)) == 2 for name in f.sensor_names) and f.sensor_names,
}
ABSENT = {
    CLOUD: lambda f: f.particles is None and f.weights is None,
    RESAMPLING: lambda f: f.ess is None,
    COSTATE: lambda f: f.costate_mean is None or not f.costate_measured.any(),  # an SPF not computing it
    GATE: lambda f: f.gated == 0,
    TEMPERING: lambda f: f.tempered_updates == 0,
    MODEL_PROBABILITIES: lambda f: f.model_probabilities is None,
    COMPENSATION: lambda f: f.unmodelled_acceleration.size == 0,
    SENSOR_BIAS: lambda f: f.sensor_names == (),
}


def test_every_capability_has_a_check():
    assert set(ANSWERS) == set(ABSENT) == set(CAPABILITIES)


def _run(flt: Filter) -> Filter:
    config = ScenarioConfig(duration=10.0)
    scenario = generate(config, 0)
    flt.initialize(scenario.prior_mean, scenario.prior_cov)
    for k in range(len(scenario.measurements)):
        flt.predict(config.dt, scenario.specific_force[k])
        flt.update(scenario.measurements[k])
    return flt


def _biased(name: str) -> SensorBiasFilter:
    model = filter_model(ScenarioConfig())
    rae = ModelSensor(model, "rae", bias=random_constant_bias([30.0, 0.0, 0.0]))
    return SensorBiasFilter(lambda m: registry.make(name, m, 60, 0), model, [rae])


CASES = ([(f"registry {name}", lambda name=name: registry.make(name, filter_model(ScenarioConfig()), 60, 0))
          for name in registry.ENTRIES]
         + [(f"factory {name}", lambda name=name: make_filter(name, filter_model(ScenarioConfig()), n_particles=60))
            for name in FILTERS]
         + [(f"biased {name}", lambda name=name: _biased(name)) for name in ("gpf", "spf", "ekf", "enkf")])


@pytest.mark.parametrize("make", [m for _, m in CASES], ids=[i for i, _ in CASES])
def test_every_filter_is_a_filter_and_answers_what_it_declares(make):
    flt = _run(make())
    assert isinstance(flt, Filter)
    assert flt.capabilities <= set(CAPABILITIES)
    for capability in CAPABILITIES:
        if capability in flt.capabilities:
            assert ANSWERS[capability](flt), capability
        else:
            assert ABSENT[capability](flt), capability
    assert flt.recoveries == 0 and flt.initialized and flt.time > 0 and flt.observability is not None
    # the last update's log evidence
    assert isinstance(flt.last_log_likelihood, float) and np.isfinite(flt.last_log_likelihood)
    # the trackers it runs (a multiple-model filter's: one per member); one of them makes its report
    trackers = flt.observability_trackers()
    assert trackers and all(tracker.ready and tracker.updates > 0 for tracker in trackers)
    assert any(tracker.report() is flt.observability for tracker in trackers)
    assert len(trackers) == len([leaf for leaf in _leaves(flt) if leaf.observability is not None])


def _leaves(flt: Filter) -> list[Filter]:
    """The filters that run: ``flt``, or its members' leaves if it is a composite (a member that forgoes
    its observability recursions has no tracker)."""
    return [leaf for m in flt.members for leaf in _leaves(m)] if isinstance(flt, Composite) else [flt]


def test_every_capability_attribute_is_declared_on_filter_and_read_through_composites():
    assert set(ATTRIBUTES) == set(CAPABILITIES)
    assert all(hasattr(Filter, name) for names in ATTRIBUTES.values() for name in names)
    flt = _run(_biased("gpf"))
    imm = flt.filter
    assert isinstance(imm, MultipleModelGPF)
    assert flt.capabilities == imm.capabilities | {SENSOR_BIAS}
    assert flt.ess == imm.ess and flt.gated == imm.gated and flt.particles.shape == imm.particles.shape
    assert np.array_equal(flt.costate_mean, imm.compensated.costate_mean)  # the member the IMM delegates the co-state to
    assert flt.recoveries == imm.recoveries and flt.time == imm.time == imm.compensated.time
    assert flt.observability is imm.observability is imm.nominal.observability
