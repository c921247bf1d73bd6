"""Per-step time on the bearings-only user model (``bearings_only.py``): our EKF against filterpy's.

Both filters run the same 4-state model over the same bearings: ours through the model's methods
(``transition``, ``transition_jacobian``, ``measure_and_jacobian``, wrapped residual), filterpy's
``ExtendedKalmanFilter`` with the constant ``F`` and ``Q`` and the model's ``measure`` and
``measurement_jacobian`` as ``Hx`` and ``HJacobian``, with a wrapped residual. Blocks of steps of the
two alternate, so a busy machine slows both alike; a block is timed in CPU time of this process
(``time.process_time``: time spent descheduled on a shared machine is not counted). Reported: the
median block of each and the median ratio over pairs of adjacent blocks.

Run: ``python docs/examples/bench_user_model.py [--steps 2000] [--repeats 7]``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from bearings_only import PRIOR_COV, PRIOR_MEAN, BearingsOnlyModel, simulate
from gpf_nav.filters import ExtendedKF


def ours(ys: np.ndarray) -> float:
    """Seconds per predict + update of our EKF over ``ys``."""
    f = ExtendedKF(BearingsOnlyModel())
    f.initialize(PRIOR_MEAN, PRIOR_COV)
    start = time.process_time()
    for y in ys:
        f.predict(1.0)
        f.update(y)
    return (time.process_time() - start) / len(ys)


def filterpy(ys: np.ndarray) -> float:
    """Seconds per predict + update of filterpy's EKF over ``ys``."""
    from filterpy.kalman import ExtendedKalmanFilter
    model = BearingsOnlyModel()
    f = ExtendedKalmanFilter(dim_x=4, dim_z=1)
    f.x, f.P = PRIOR_MEAN[:, None].copy(), PRIOR_COV.copy()
    f.F, f.Q, f.R = model.transition_jacobian(PRIOR_MEAN[None], 1.0)[0], model.process_noise(1.0), \
        model.measurement_noise()

    def jacobian(x):
        return model.measurement_jacobian(x.T)[0]

    def measure(x):
        return model.measure(x.T)

    def residual(a, b):
        return (a - b + np.pi) % (2.0 * np.pi) - np.pi

    start = time.process_time()
    for y in ys:
        f.predict()
        f.update(y, jacobian, measure, residual=residual)
    return (time.process_time() - start) / len(ys)


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    ys = simulate(np.random.default_rng(0), steps=args.steps)[1]
    times: dict[str, list[float]] = {"gpf_nav EKF": [], "filterpy EKF": []}
    for _ in range(args.repeats):
        times["gpf_nav EKF"].append(ours(ys))
        times["filterpy EKF"].append(filterpy(ys))
    result = {name: 1e6 * float(np.median(t)) for name, t in times.items()}
    for name, us in result.items():
        print(f"{name:14s} {us:7.1f} us/step (median of {args.repeats} blocks of {args.steps} steps)")
    ratios = np.array(times["gpf_nav EKF"]) / np.array(times["filterpy EKF"])
    result["ratio"] = float(np.median(ratios))
    print(f"gpf_nav / filterpy, median over pairs of adjacent blocks: {result['ratio']:.2f} "
          f"(range {ratios.min():.2f}-{ratios.max():.2f})")
    return result


if __name__ == "__main__":
    main()
