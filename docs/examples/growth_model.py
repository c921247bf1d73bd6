"""A discrete-time user model: the univariate nonstationary growth model (Kitagawa 1996; Gordon,
Salmond & Smith 1993), written on :class:`gpf_nav.models.StateSpaceModel`.

    x_k = x_{k-1} / 2 + 25 x_{k-1} / (1 + x_{k-1}^2) + 8 cos(1.2 k) + w_k,   w_k ~ N(0, 10)
    y_k = x_k^2 / 20 + v_k,                                                  v_k ~ N(0, 1)

Discrete time on the filters' continuous clock: drive the filter with ``predict(1.0)`` so that its time
``t`` counts steps; ``transition(x, dt, t)`` maps step ``k - 1 = t`` to step ``k = t + 1`` (it is
time-varying through ``cos(1.2 k)``) and ignores ``dt``. ``drift`` is the per-step increment.

Run it: ``python docs/examples/growth_model.py``.
"""
from __future__ import annotations

import numpy as np

from gpf_nav.models import StateSpaceModel

PROCESS_VARIANCE = 10.0
MEASUREMENT_VARIANCE = 1.0


class GrowthModel(StateSpaceModel):
    """The growth model: state ``(x,)``, measurement ``(x^2 / 20,)``; one step per unit of filter time."""

    state_dim = 1
    measurement_dim = 1
    angular = np.array([False])

    @staticmethod
    def _step(x: np.ndarray, t: float) -> np.ndarray:
        return 0.5 * x + 25.0 * x / (1.0 + x * x) + 8.0 * np.cos(1.2 * (t + 1.0))

    def transition(self, x, dt, t=0.0, u=None):
        return self._step(x, t)

    def drift(self, x, t=0.0, u=None):
        return self._step(x, t) - x

    def transition_jacobian(self, x, dt, t=0.0, u=None):
        x2 = x * x
        return (0.5 + 25.0 * (1.0 - x2) / (1.0 + x2) ** 2)[:, :, None]

    def process_noise(self, dt):
        return np.array([[PROCESS_VARIANCE]])

    def measure(self, x):
        return x * x / 20.0

    def measurement_jacobian(self, x):
        return (x / 10.0)[:, :, None]

    def measurement_noise(self):
        return np.array([[MEASUREMENT_VARIANCE]])


def simulate(steps: int, x0: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Truth ``(steps + 1,)`` from ``x0`` and measurements ``(steps, 1)``."""
    model = GrowthModel()
    x = np.empty(steps + 1)
    x[0] = x0
    for k in range(steps):
        x[k + 1] = model.transition(x[k:k + 1, None], 1.0, float(k))[0, 0] \
            + rng.normal(0.0, np.sqrt(PROCESS_VARIANCE))
    y = x[1:, None] ** 2 / 20.0 + rng.normal(0.0, np.sqrt(MEASUREMENT_VARIANCE), (steps, 1))
    return x, y


def main() -> None:
    from gpf_nav.filters import BootstrapPF
    truth, ys = simulate(50, 0.1, np.random.default_rng(1))
    f = BootstrapPF(GrowthModel(), n_particles=2000, seed=0)
    f.initialize(np.array([0.1]), np.array([[2.0]]))
    errors = []
    for k, y in enumerate(ys):
        f.predict(1.0)
        f.update(y)
        errors.append(f.mean[0] - truth[k + 1])
    print(f"growth model, bootstrap PF N=2000, 50 steps: RMSE {np.sqrt(np.mean(np.square(errors))):.2f}")


if __name__ == "__main__":
    main()
