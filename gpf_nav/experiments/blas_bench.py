"""BLAS threads under load: what a length-N vector product and a particle-filter step cost when
OpenBLAS may use every core of a machine that is busy with other work.

OpenBLAS threads a product once it is long enough; on a loaded machine its worker threads wait for a
core, and a 5 us dot product of N = 20 000 weights can take milliseconds. The filters therefore sum
length-N products with ``np.einsum`` (no BLAS), and ``gpf-nav`` and the nodes bound BLAS to one
thread (:func:`gpf_nav.blas.limit_blas_threads`). This bench times, with ``--load`` busy processes
running beside it: ``np.dot(w, w)`` against ``np.einsum`` at N = 20 000, and a bootstrap-PF and a GPF
step on the lunar model at N = 20 000, each with BLAS unbounded and bounded to one thread.

Run: ``python -m gpf_nav.experiments.blas_bench [--load 2] [--particles 20000]`` (leave
``OPENBLAS_NUM_THREADS`` unset to see the default).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from gpf_nav import registry
from gpf_nav.sim.scenario import ScenarioConfig, filter_model, generate


def _median_seconds(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def _filter_step(name: str, n: int, repeats: int) -> float:
    """Median seconds per step of registry filter ``name`` with ``n`` particles."""
    config = replace(ScenarioConfig(), duration=60.0)
    scenario = generate(config, 0)
    f = registry.make(name, filter_model(config), n, seed=0)
    f.initialize(scenario.prior_mean, scenario.prior_cov)
    ys = iter(np.tile(scenario.measurements, (repeats // len(scenario.measurements) + 2, 1)))

    def step():
        f.predict(config.dt)
        f.update(next(ys))
        return f.mean

    step()
    return _median_seconds(step, repeats)


def run(n: int, repeats: int) -> dict[str, float]:
    """Median seconds of each case, BLAS unbounded (``default``) and bounded to one thread (``1``)."""
    w = np.random.default_rng(0).random(n)
    w /= w.sum()
    results = {}
    for threads in (None, 1):
        label = "default" if threads is None else "1"
        with threadpool_limits(limits=threads, user_api="blas"):
            results[f"np.dot(w, w), BLAS {label}"] = _median_seconds(lambda: np.dot(w, w), repeats * 20)
            results[f"BootstrapPF step, BLAS {label}"] = _filter_step("spf", n, repeats)
            results[f"GPF step, BLAS {label}"] = _filter_step("gpf-single", n, repeats)
    results["np.einsum('i,i->', w, w)"] = _median_seconds(lambda: np.einsum("i,i->", w, w), repeats * 20)
    return results


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--load", type=int, default=2, help="busy background processes to start")
    parser.add_argument("--particles", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args(argv)
    blas = [(i["internal_api"], i["num_threads"]) for i in threadpool_info() if i["user_api"] == "blas"]
    print(f"BLAS {blas}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
          f"{os.cpu_count()} CPUs, {args.load} busy background processes, N = {args.particles}")
    load = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.load)]
    try:
        results = run(args.particles, args.repeats)
    finally:
        for process in load:
            process.kill()
            process.wait()
    for name, seconds in results.items():
        print(f"{name:36s} {seconds * 1e6:10.1f} us")
    return results


if __name__ == "__main__":
    main()
