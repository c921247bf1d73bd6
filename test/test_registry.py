"""The filter registry (gpf_nav/registry.py): one entry makes a filter known to the node's factory, the
campaigns and the bench; labels and oracle-tuned rows belong to the entries."""
from __future__ import annotations

import pytest

from gpf_nav import registry
from gpf_nav.estimator.factory import make_filter
from gpf_nav.experiments import bench, runner
from gpf_nav.filters import GeometricProjectionPF
from gpf_nav.sim.scenario import ScenarioConfig, filter_model


@pytest.fixture
def wide_gpf():
    """A new filter, registered for the test only (the table is restored afterwards)."""
    saved = dict(registry.ENTRIES)
    entry = registry.register(registry.FilterEntry(
        "gpf-wide", "GPF, wide kernel (test)",
        lambda model, n_particles, seed, **options: GeometricProjectionPF(
            model, n_particles, seed=seed, **{"kernel_bandwidth": 0.5, **options}),
        "gpf", registry.GPF_OPTIONS, node=True, description="a GPF with a wide regularisation kernel"))
    yield entry
    registry.ENTRIES.clear()
    registry.ENTRIES.update(saved)


def test_one_entry_reaches_the_factory_a_campaign_and_the_bench(wide_gpf):
    model = filter_model(ScenarioConfig())
    flt = make_filter("gpf-wide", model, n_particles=50, seed=1)
    assert isinstance(flt, GeometricProjectionPF) and flt.n_particles == 50
    task = runner.RunTask(0, 0, 3, ScenarioConfig(duration=20.0), filters=(wide_gpf.label,), n_particles=40)
    summary = runner.run_task(task)["filters"][wide_gpf.label]
    assert summary["error"] is None and summary["position_rmse"] > 0 and summary["ess"] > 0
    report = bench.run(particle_counts=(30,), repeats=1, filters=("gpf-wide", "ekf"))
    assert [(r["filter"], r["particles"]) for r in report["results"]] == [("gpf-wide", 30), ("ekf", None)]


def test_the_fixture_restores_the_table():
    assert "gpf-wide" not in registry.ENTRIES


def test_names_aliases_and_labels_are_unique_and_refused_twice():
    keys = [k for e in registry.ENTRIES.values() for k in (e.name, e.label, *e.aliases)]
    assert len(keys) == len(set(keys))
    entry = registry.lookup("gpf")
    with pytest.raises(ValueError, match="already registered"):
        registry.register(entry)
    assert "gpf-wide" not in registry.ENTRIES


def test_lookup_by_name_alias_or_label():
    assert registry.lookup("GPF-MM") is registry.lookup("gpf") is registry.lookup("GPF navigation (default)")
    with pytest.raises(ValueError, match="unknown filter 'nope'"):
        registry.lookup("nope")


def test_oracle_rows_are_labelled_as_such_and_name_what_they_tune():
    oracle = [e for e in registry.ENTRIES.values() if e.tunes]
    assert {e.name for e in oracle} == {"ekf-oracle", "ukf-oracle"}
    assert all("oracle-tuned" in e.label and not e.node for e in oracle)
    assert runner.ORACLE_FAMILIES == {"EKF, oracle-tuned Q": "EKF", "UKF, oracle-tuned Q": "UKF"}

