"""The campaigns' surface-station conditions: beacons on the rotating Moon replacing the centre station
(``ScenarioConfig.surface_stations``), what they see of the descent, and the runs that fuse them."""
import dataclasses
import json
import math

import numpy as np
import pytest

from gpf_nav import cli
from gpf_nav.experiments import runner, stress
from gpf_nav.experiments.surface import LANDING_SITE, SURFACE
from gpf_nav.filters import ExtendedKF
from gpf_nav.models.frames import MoonRotation
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate, undetermined_subspace
from gpf_nav.sim.surface_stations import scenario_stations

BASE = ScenarioConfig(epsilon=0.0)  # the stress campaign's base: exact dynamics


def _windows(name: str) -> list[tuple[float, float]]:
    """First and last time (s) each beacon of condition ``name`` sees run 0's descent."""
    scenario = generate(dataclasses.replace(BASE, **SURFACE[name][1]), 0)
    return [(scenario.times[np.isfinite(y[:, 0])][0], scenario.times[np.isfinite(y[:, 0])][-1])
            for _, y in scenario_stations(scenario, 0)]


@pytest.mark.parametrize("name, windows", [("surface-gaps", [(850, 1500)]),
                                           ("surface-two", [(32, 766), (2174, 2400)])])
def test_the_beacons_see_the_descent_when_the_docs_say(name, windows):
    assert np.allclose(_windows(name), windows, atol=6.0)


def test_the_landing_site_is_below_the_end_of_the_descent():
    scenario = generate(BASE, 0)
    r = MoonRotation(0.0).to_fixed(scenario.truth[-1, :3], t=scenario.times[-1])
    latitude, longitude = math.asin(r[2] / np.linalg.norm(r)), math.atan2(r[1], r[0])
    assert abs(latitude - LANDING_SITE[0]) < math.radians(0.05)
    assert abs(longitude - LANDING_SITE[1]) < math.radians(0.05)


def test_surface_stations_are_checked_and_replace_the_centre_symmetry():
    for bad in ((0.1, 0.2), (2.0, 0.0, 0.0), (0.1, math.nan, 0.0)):
        with pytest.raises(ValueError, match="surface_stations"):
            ScenarioConfig(surface_stations=bad)
    config = ScenarioConfig(surface_stations=LANDING_SITE)
    assert ScenarioConfig.from_dict(config.to_dict()) == config
    assert undetermined_subspace(config, generate(BASE, 0).truth[0]) is None
    assert undetermined_subspace(BASE, generate(BASE, 0).truth[0]).shape == (6, 0)


def test_a_run_fuses_each_beacon_and_predicts_while_none_sees_the_vehicle():
    """The run's estimate is the EKF's over the beacons' data: nothing before the uprange beacon rises
    (the estimate of a filter that only predicts), each beacon's update in turn after."""
    config = ScenarioConfig(epsilon=0.0, duration=200.0, surface_stations=SURFACE["surface-two"][1]["surface_stations"])
    scenario = generate(config, 4)
    stations = scenario_stations(scenario, 4)
    summary = runner.run_filter(ExtendedKF(filter_model(config)), scenario, stations=stations)
    by_hand, predicting = ExtendedKF(filter_model(config)), ExtendedKF(filter_model(config))
    for flt in (by_hand, predicting):
        flt.initialize(scenario.prior_mean, scenario.prior_cov)
    errors = []
    for k in range(len(scenario.times)):
        for flt in (by_hand, predicting):
            flt.predict(config.dt, scenario.specific_force[k])
        for sensor, y in stations:
            by_hand.update(y[k], sensor)
        if not any(np.isfinite(y[k]).any() for _, y in stations):
            assert np.array_equal(by_hand.mean, predicting.mean)
        errors.append(np.linalg.norm(by_hand.mean[:3] - scenario.truth[k + 1, :3]))
    assert np.array_equal(summary["series"]["position_error"], errors)
    assert 0 < np.isfinite(stations[0][1][:, 0]).sum() < len(scenario.times)  # the uprange beacon rose
    assert errors[-1] < 0.3 * errors[10]  # and its data pulled the estimate in


def test_an_ekf_tracks_the_uprange_beacon_honestly():
    """Known answer: over the uprange beacon's pass (exact dynamics) the EKF's errors are those of its
    covariance, time-averaged NEES near 6 over 4 runs, and the final error well inside the prior's."""
    config = ScenarioConfig(epsilon=0.0, duration=760.0, surface_stations=SURFACE["surface-two"][1]["surface_stations"])
    runs = [runner.run_task(runner.RunTask(0, run, 0, config, filters=("ekf",)))["filters"]["ekf"]
            for run in range(4)]
    assert 3.0 < np.mean([r["nees"] for r in runs]) < 9.0
    assert max(r["final_position_error"] for r in runs) < 100.0


def test_stress_runs_the_surface_conditions_only_when_named(tmp_path):
    tiny = ["--runs", "1", "--duration", "80", "--filters", "ekf", "--prior-scales", "", "--no-progress",
            "--no-plots", "--workers", "1"]
    assert cli.main(["stress", "--conditions", "surface-two", "--out", str(tmp_path)] + tiny) == 0
    report = json.loads((tmp_path / "stress.json").read_text())
    assert list(report["conditions"]) == ["surface-two"]
    assert report["conditions"]["surface-two"]["changes"]["surface_stations"] == pytest.approx(
        SURFACE["surface-two"][1]["surface_stations"])
    assert not set(SURFACE) & set(stress.CONDITIONS)
