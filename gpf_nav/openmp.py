"""Idle OpenMP threads asleep in processes that run a filter.

The compiled kernels' loops over a large cloud (from :data:`~gpf_nav.kernels.PARALLEL` particles) run on
numba's OpenMP threads, and a large cloud's normal draws on threads of their own
(:mod:`gpf_nav.filters.normal_draws`). After each parallel loop GNU OpenMP keeps its threads spinning for
a while by default, on the cores the draws want next: at 100,000 particles the draws of a bootstrap step
then take half as long again. ``OMP_WAIT_POLICY=PASSIVE`` puts idle OpenMP threads to sleep; waking them
costs microseconds, a parallel loop here milliseconds.

``gpf-nav`` and the ``estimator`` node call :func:`passive_openmp_waits` at start-up; a program of your
own that runs the filters can do the same, before it runs one.
"""
from __future__ import annotations

import os


def passive_openmp_waits() -> bool:
    """Set ``OMP_WAIT_POLICY=PASSIVE`` for this process.

    Returns True when applied; False, changing nothing, when the user chose a policy through
    ``OMP_WAIT_POLICY`` or numba's threads are already running (OpenMP read the policy when they started).
    """
    if os.environ.get("OMP_WAIT_POLICY"):
        return False
    from numba.np.ufunc import parallel

    if parallel._is_initialized:
        return False
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    return True
