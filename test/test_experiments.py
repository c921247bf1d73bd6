"""Smoke and determinism tests of ``gpf-nav montecarlo`` / ``gpf-nav sweep`` (short scenarios)."""
import json
import math

import numpy as np
import pytest

from gpf_nav import cli, registry
from gpf_nav.experiments import montecarlo, runner
from gpf_nav.experiments.parallel import map_tasks
from gpf_nav.sim.scenario import ScenarioConfig

SHORT = ["--duration", "100", "--no-progress"]  # 50 filter steps instead of 1200


def _finite(entry):
    return entry["mean"] is not None and math.isfinite(entry["mean"]) and math.isfinite(entry["std"])


def _strip_meta(report):
    return {k: v for k, v in report.items() if k != "meta"}


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out = tmp_path_factory.mktemp("mc")
    assert cli.main(["montecarlo", "--runs", "5", "--workers", "2", "--out", str(out)] + SHORT) == 0
    return out, json.loads((out / "results.json").read_text())


def test_montecarlo_smoke_json_schema_and_finite_numbers(smoke):
    out, report = smoke
    assert report["schema"] == montecarlo.SCHEMA
    assert set(report["cases"]) == {"full", "partial"}
    assert report["settings"]["runs"] == 5 and report["settings"]["n_particles"] == 500
    assert report["settings"]["filters"] == list(runner.FILTERS)
    for case, data in report["cases"].items():
        assert set(data["filters"]) == set(runner.FILTERS)
        for name, row in data["filters"].items():
            for metric in montecarlo.METRICS:
                assert set(row[metric]) >= {"mean", "std"}, (case, name, metric)
            for metric in ("position_rmse_km", "velocity_rmse_mps", "max_position_error_km"):
                assert _finite(row[metric]) and row[metric]["n"] == 5, (case, name, metric)
            if registry.lookup(name).particles:
                for metric in ("ess", "costate_norm", "resample_rate"):
                    assert _finite(row[metric]), (case, name, metric)
                assert 0.0 < row["ess"]["mean"] <= 1.0
            else:
                assert row["ess"]["mean"] is None
            # NEES is finite unless the filter's covariance was never positive definite (then it is null)
            assert _finite(row["nees"]) or (row["nees"]["mean"] is None and row["nees_defined"]["mean"] == 0)
            assert data["failures"][name]["nonfinite"] == 0
        assert set(data["wilcoxon"]) == set(runner.FILTERS) - {registry.label("gpf")}
        assert set(data["oracle_multiplier"]) == set(runner.ORACLE_FAMILIES)
        assert all(m in runner.ORACLE_GRID for m in data["oracle_multiplier"].values())
        for p in data["wilcoxon"].values():
            assert p is None or 0.0 <= p <= 1.0
        band = data["nees_band"]
        assert band["lower"] < 6.0 < band["upper"] and band["runs"] == 5
        assert set(data["correlations"]) == {n for n in runner.FILTERS if registry.lookup(n).particles}
    for case in report["per_run"]:
        assert all(len(v["position_rmse_km"]) == 5 for v in report["per_run"][case].values())
    assert report["meta"]["wall_seconds"] > 0
    text = (out / "results.md").read_text()
    assert "| GPF (innovation, likelihood) |" in text and "Wilcoxon" in text


def test_montecarlo_writes_figures(smoke):
    pytest.importorskip("matplotlib")
    out, _ = smoke
    for name in ("error_evolution", "ess", "nees", "rmse_per_run", "costate_degeneracy"):
        path = out / f"{name}.png"
        assert path.exists() and path.stat().st_size > 10_000, name


def test_same_seed_same_numbers_for_any_worker_count(smoke, tmp_path):
    _, report = smoke
    assert cli.main(["montecarlo", "--runs", "5", "--workers", "1", "--no-plots", "--out", str(tmp_path)]
                    + SHORT) == 0
    again = json.loads((tmp_path / "results.json").read_text())
    assert _strip_meta(again) == _strip_meta(report)


def test_different_seed_different_numbers(tmp_path):
    config = ScenarioConfig(duration=40.0)
    tasks = [runner.RunTask(0, 0, seed, config, filters=("SPF",)) for seed in (0, 1)]
    a, b = (runner.run_task(t)["filters"]["SPF"]["position_rmse"] for t in tasks)
    assert a != b


def test_run_task_is_reproducible_and_paired_across_cases():
    full = runner.RunTask(0, 3, 7, ScenarioConfig(duration=40.0), filters=("EKF", "SPF"), series=True)
    first, second = runner.run_task(full), runner.run_task(full)
    for name in ("EKF", "SPF"):
        assert first["filters"][name]["position_rmse"] == second["filters"][name]["position_rmse"]
        np.testing.assert_array_equal(first["filters"][name]["series"]["ess"],
                                      second["filters"][name]["series"]["ess"])
    assert runner.run_seeds(7, 3) == runner.run_seeds(7, 3) != runner.run_seeds(7, 4)


def test_dask_scheduler_gives_the_same_results_as_the_local_pool(smoke, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    _, report = smoke
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        assert cli.main(["montecarlo", "--runs", "5", "--scheduler", cluster.scheduler_address,
                         "--no-plots", "--out", str(tmp_path)] + SHORT) == 0
    via_dask = json.loads((tmp_path / "results.json").read_text())
    assert via_dask["meta"]["scheduler"].startswith("tcp://")
    assert _strip_meta(via_dask) == _strip_meta(report)


def _square(x):
    return x * x


def test_map_tasks_keeps_input_order():
    tasks = list(range(7, 0, -1))
    expected = [t * t for t in tasks]
    assert map_tasks(_square, tasks, workers=1, progress=False) == expected
    assert map_tasks(_square, tasks, workers=2, progress=False) == expected
    with pytest.raises(ValueError):
        map_tasks(_square, tasks, workers=0, progress=False)


def test_failure_accounting_divergence_kept_nonfinite_excluded():
    ok = {"position_rmse": 1000.0, "velocity_rmse": 1.0, "diverged": False, "nonfinite": False, "error": None}
    div = dict(ok, position_rmse=5e6, diverged=True)
    bad = dict(ok, position_rmse=math.nan, nonfinite=True, error="LinAlgError: x")
    results = [{"filters": {"F": r}} for r in (ok, div, bad)]
    values = montecarlo.per_run_values(results, "F", "position_rmse", 1e-3)
    np.testing.assert_array_equal(np.isnan(values), [False, False, True])
    assert values[1] == pytest.approx(5000.0)  # the diverged run stays in the statistics


def test_sweep_smoke(tmp_path):
    assert cli.main(["sweep", "--param", "mismatch", "--values", "0,0.2", "--runs", "2", "--workers", "2",
                     "--filters", "gpf,ekf", "--out", str(tmp_path)] + SHORT) == 0
    report = json.loads((tmp_path / "sweep_mismatch.json").read_text())
    assert report["values"] == [0.0, 0.2] and report["field"] == "epsilon"
    for case in ("full", "partial"):
        for name in (registry.label("gpf"), "EKF"):
            for key in ("position_rmse_km", "velocity_rmse_mps", "nees"):
                rows = report["cases"][case]["filters"][name][key]
                assert len(rows) == 2 and all(_finite(r) for r in rows)
            for point in report["cases"][case]["filters"][name]["position_rmse_km"]:  # two runs: the larger
                worst, other = point["worst"]["value"], 2 * point["mean"] - point["worst"]["value"]
                assert point["worst"]["run"] in (0, 1) and worst >= other
                assert worst - other == pytest.approx(point["std"] * 2 ** 0.5)
    assert "; worst " in (tmp_path / "sweep_mismatch.md").read_text()
    if pytest.importorskip("matplotlib"):
        assert (tmp_path / "sweep_mismatch.png").stat().st_size > 10_000


def test_sweep_merge_reruns_only_the_named_rows(tmp_path, capsys):
    first, second = tmp_path / "first", tmp_path / "second"
    common = ["sweep", "--param", "mismatch", "--values", "0.1", "--runs", "2", "--workers", "1", "--cases",
              "full", "--no-plots", "--no-progress"] + SHORT
    assert cli.main(common + ["--filters", "ekf,spf", "--out", str(first)]) == 0
    earlier = json.loads((first / "sweep_mismatch.json").read_text())
    # a row of a filter this version no longer knows (a renamed one) is dropped by the merge
    earlier["settings"]["filters"].append("GPF of an older name")
    for key in ("filters", "failures"):
        earlier["cases"]["full"][key]["GPF of an older name"] = earlier["cases"]["full"][key]["SPF"]
    (first / "sweep_mismatch.json").write_text(json.dumps(earlier))
    assert cli.main(common + ["--filters", "ekf,ekf-comp", "--out", str(second),
                              "--merge", str(first / "sweep_mismatch.json")]) == 0
    merged = json.loads((second / "sweep_mismatch.json").read_text())
    rows = merged["cases"]["full"]["filters"]
    assert list(rows) == ["EKF", "SPF", registry.label("ekf-comp")]
    assert rows["SPF"] == earlier["cases"]["full"]["filters"]["SPF"]  # kept
    assert rows["EKF"] == earlier["cases"]["full"]["filters"]["EKF"]  # re-run: deterministic
    assert rows[registry.label("ekf-comp")]["position_rmse_km"][0]["n"] == 2
    assert merged["meta"]["rerun"] == ["EKF", registry.label("ekf-comp")]
    assert merged["meta"]["dropped"] == ["GPF of an older name"]
    assert "GPF of an older name" not in merged["settings"]["filters"]
    assert merged["meta"]["earlier"] == earlier["meta"]
    with pytest.raises(SystemExit):  # not the same sweep: 3 runs against 2 (refused before running)
        sweep_main = common + ["--filters", "ekf", "--out", str(second), "--merge", str(first / "sweep_mismatch.json")]
        cli.main([a if a != "2" else "3" for a in sweep_main])
    assert "is not the same sweep" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # not a report at all
        cli.main(common + ["--filters", "ekf", "--out", str(second), "--merge", str(tmp_path)])


def test_cli_rejects_unknown_filter(tmp_path):
    with pytest.raises(SystemExit):
        montecarlo.main(["--runs", "1", "--filters", "KF9000", "--out", str(tmp_path)] + SHORT)


def test_oracle_row_is_the_grid_member_with_the_lowest_mean_position_rmse():
    family = "EKF, oracle-tuned Q"
    results = [{"filters": {runner.grid_name(family, m): {"position_rmse": abs(np.log10(m) - 3) + run}
                            for m in runner.ORACLE_GRID}} for run in range(3)]
    assert runner.select_oracle(results, (family, "EKF")) == {family: 1e3}
    assert all(r["filters"][family] is r["filters"][runner.grid_name(family, 1e3)] for r in results)
    assert runner.expand_filters((family, "EKF")) == tuple(runner.grid_name(family, m)
                                                           for m in runner.ORACLE_GRID) + ("EKF",)


def test_grid_member_runs_on_the_scaled_process_noise():
    config = ScenarioConfig()
    base = runner.filter_model_of("EKF", config)
    scaled = runner.filter_model_of(runner.grid_name("EKF, oracle-tuned Q", 1e4), config)
    np.testing.assert_allclose(scaled.process_noise(2.0), 1e4 * base.process_noise(2.0))
