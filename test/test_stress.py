"""``gpf-nav stress``: end to end on tiny runs, the table's rows, and the per-run figures it reads."""
import json
import math

import numpy as np
import pytest

from gpf_nav import cli, registry
from gpf_nav.experiments import runner, stress
from gpf_nav.filters import ExtendedKF
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate

TINY = ["--runs", "2", "--duration", "40", "--particles", "40", "--no-progress"]  # 20 steps per run
FILTERS = tuple(map(registry.label, ("gpf", "gpf-single", "ekf-comp-gated", "ekf", "ekf-oracle")))


def test_stress_command_writes_every_condition_and_filter(tmp_path):
    assert cli.main(["stress", "--workers", "2", "--prior-scales", "1,5", "--out", str(tmp_path)] + TINY) == 0
    report = json.loads((tmp_path / "stress.json").read_text())
    names = ["large-prior", "range-only", "outliers", "range-bias", "prior-x1", "prior-x5"]
    assert list(report["conditions"]) == names
    assert report["settings"]["base_config"]["epsilon"] == 0.0 and report["meta"]["command"].startswith("gpf-nav stress")
    table = (tmp_path / "stress.md").read_text().splitlines()
    for entry in report["conditions"].values():
        assert list(entry["filters"]) == list(FILTERS)
        for name, row in entry["filters"].items():
            per_run = np.array([np.nan if v is None else v for v in row["per_run_position_rmse"]])
            assert row["runs"] == 2 and np.isfinite(per_run).all()
            assert row["position_rmse_mean"] == pytest.approx(per_run.mean())
            assert row["position_rmse_median"] == pytest.approx(np.median(per_run))
            assert row["worst_run"]["position_rmse"] == pytest.approx(per_run.max())
            assert math.isfinite(row["velocity_rmse_mean"]) and row["covariance_failures"] >= 0
            particle = registry.lookup(name).particles
            assert (row["first_ess_mean"] is not None) == particle
            if particle:
                assert 0.0 < row["first_ess_min"] <= row["first_ess_mean"] <= 1.0
        assert sum(line.startswith(f"| {entry['label']} |") for line in table) == 1  # opens its group
    rows = [line for line in table if line.startswith("| ") and any(f"| {f} |" in line for f in FILTERS)]
    assert len(rows) == len(names) * len(FILTERS)
    assert report["conditions"]["large-prior"]["oracle_multiplier"]["EKF, oracle-tuned Q"] in runner.ORACLE_GRID
    if pytest.importorskip("matplotlib"):
        assert (tmp_path / "stress.png").stat().st_size > 10_000


def test_stress_runs_are_the_public_scenario_runs():
    """Run r of a condition is run_task's run r of the changed scenario (exact dynamics): the figures can
    be reproduced run by run from the scenario options alone."""
    config = ScenarioConfig(duration=40.0, epsilon=0.0)
    report = stress.stress(config, stress.conditions(["range-only"], []), 2, 3, ("EKF",), 40, 10.0,
                           workers=1, progress=False)
    row = report["conditions"]["range-only"]["filters"]["EKF"]
    scenario_seed, filter_seed = runner.run_seeds(3, 1)
    scenario = generate(ScenarioConfig(duration=40.0, epsilon=0.0, case="range"), scenario_seed)
    assert np.isnan(scenario.measurements[:, 1:]).all()
    again = runner.run_filter(ExtendedKF(filter_model(scenario.config), seed=filter_seed), scenario)
    assert row["per_run_position_rmse"][1] == again["position_rmse"]


def test_run_filter_counts_the_published_covariances_a_consumer_cannot_factor():
    class SingularAfterThree(ExtendedKF):
        updates = 0

        def update(self, y, sensor=None):
            super().update(y, sensor)
            self.updates += 1

        @property
        def covariance(self):
            P = np.array(super().covariance)
            if self.updates > 3:
                P[0, :] = P[:, 0] = 0.0
            return P

    scenario = generate(ScenarioConfig(duration=40.0), 0)
    summary = runner.run_filter(SingularAfterThree(filter_model(scenario.config)), scenario)
    assert summary["covariance_failures"] == 20 - 3
    assert 0.0 < summary["final_position_error"] and math.isnan(summary["first_ess"])
    assert runner.run_filter(ExtendedKF(filter_model(scenario.config)), scenario)["covariance_failures"] == 0


def test_stress_refuses_an_unknown_condition_before_running(tmp_path):
    with pytest.raises(SystemExit) as stop:
        cli.main(["stress", "--conditions", "large-prior,solar-storm", "--out", str(tmp_path)] + TINY)
    assert stop.value.code == 2 and not (tmp_path / "stress.json").exists()


def test_tempering_comparison_runs_every_variant(capsys):
    from gpf_nav.experiments import tempering
    assert tempering.main(["--runs", "1", "--duration", "20", "--particles", "40", "--workers", "1"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| single") or line.startswith("| multiple")]
    assert len(rows) == 2 * len(tempering.VARIANTS)
    assert "nan" not in " ".join(rows)


def test_conditions_beyond_the_envelope_run_only_when_named(tmp_path):
    """A combined condition is not in the default campaign, is accepted by name, and its scenario carries
    every change it names (the mismatch of ``range-only-mismatch`` overrides ``--epsilon``)."""
    assert not set(stress.BEYOND) & set(stress.CONDITIONS)
    out = tmp_path / "beyond"
    assert cli.main(["stress", "--workers", "1", "--prior-scales", "", "--filters", "ekf",
                     "--conditions", "range-only-mismatch,dropouts", "--out", str(out)] + TINY) == 0
    report = json.loads((out / "stress.json").read_text())
    assert list(report["conditions"]) == ["range-only-mismatch", "dropouts"]
    assert report["conditions"]["range-only-mismatch"]["changes"] == {"case": "range", "epsilon": 0.09}
    assert report["conditions"]["dropouts"]["filters"]["EKF"]["runs"] == 2
    with pytest.raises(SystemExit):
        cli.main(["stress", "--conditions", "no-such-condition", "--out", str(out)] + TINY)


def test_honesty_command_reports_bound_share_verdicts_and_monitor(tmp_path):
    """``gpf-nav honesty`` on tiny runs (150 s: the verdicts start at 100 s): every condition and filter,
    and the report's verdicts where the scenario knows the answer (range only: three rotations; full
    case: none)."""
    args = ["honesty", "--runs", "1", "--duration", "150", "--particles", "40", "--no-progress", "--workers", "1",
            "--filters", "ekf,gpf-paper", "--conditions", "full,range-only,large-prior-partial", "--out", str(tmp_path)]
    assert cli.main(args) == 0
    report = json.loads((tmp_path / "honesty.json").read_text())
    assert report["schema"] == "gpf_nav.honesty/1" and list(report["conditions"]) == [
        "full", "range-only", "large-prior-partial"]
    for name, entry in report["conditions"].items():
        for row in entry["filters"].values():
            assert 0.0 <= row["above_bound_mean"] <= 1.0 and 0.0 <= row["consistency_fault_share"] <= 1.0
            assert row["named_share_mean"] == 1.0, (name, row)  # EKF and the paper's GPF: the right subspace
            assert row["undetermined_share_mean"] == (0.0 if name == "full" else 1.0)
    assert "| full case (control) | EKF |" in (tmp_path / "honesty.md").read_text()


def test_honesty_refuses_an_unknown_condition(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["honesty", "--conditions", "full,nope", "--out", str(tmp_path)])
    assert exc.value.code == 2 and "nope" in capsys.readouterr().err
