"""A user's own sensor in a few lines: a slant range to a surface beacon, fused with the lunar model.

Run it: ``python docs/examples/own_sensor.py``. ``docs/filters.md`` walks through it; the tests run it.
"""
from __future__ import annotations

import numpy as np

from gpf_nav.sensors import Sensor


class BeaconRange(Sensor):
    """Distance, m, from a beacon at ``beacon`` ``(3,)`` (world frame) to the vehicle's position."""

    dim = 1
    angular = np.zeros(1, bool)
    measured_state_index = (0, 1, 2)

    def __init__(self, beacon, noise_std: float, name: str = "beacon"):
        self.beacon, self.name = np.asarray(beacon, dtype=float), name
        self._R = np.array([[noise_std ** 2]])

    def measure(self, x, t=0.0):  # (N, n) -> (N, 1)
        return np.linalg.norm(x[:, :3] - self.beacon, axis=1, keepdims=True)

    def jacobian(self, x, t=0.0):  # (N, n) -> (N, 1, n)
        d = x[:, :3] - self.beacon
        H = np.zeros((x.shape[0], 1, x.shape[1]))
        H[:, 0, :3] = d / np.linalg.norm(d, axis=1, keepdims=True)
        return H

    def noise(self, t=0.0):
        return self._R


def run(filter_name: str = "gpf", steps: int = 60, seed: int = 1) -> tuple[float, float]:
    """Fly the paper's descent with the model's range/azimuth/elevation and a beacon range every step;
    return the final position error, m, with the beacon and without it."""
    from gpf_nav import registry
    from gpf_nav.sim.scenario import MOON_RADIUS, ScenarioConfig, filter_model, generate

    config = ScenarioConfig(duration=steps * 2.0, case="partial")
    scenario = generate(config, seed)
    beacon = BeaconRange([MOON_RADIUS, 0.0, 0.0], noise_std=5.0)
    rng = np.random.default_rng(seed)
    errors = []
    for use_beacon in (True, False):
        flt = registry.make(filter_name, filter_model(config), 300, seed)
        flt.initialize(scenario.prior_mean, scenario.prior_cov)
        for k in range(steps):
            flt.predict(config.dt, scenario.specific_force[k])
            flt.update(scenario.measurements[k])  # the model's own sensor
            if use_beacon:
                truth = scenario.truth[k + 1][None]
                flt.update(beacon.measure(truth)[0] + 5.0 * rng.standard_normal(1), beacon)
        errors.append(float(np.linalg.norm(flt.mean[:3] - scenario.truth[steps, :3])))
    return errors[0], errors[1]


if __name__ == "__main__":
    with_beacon, without = run()
    print(f"final position error: {with_beacon:.0f} m with the beacon, {without:.0f} m without")
