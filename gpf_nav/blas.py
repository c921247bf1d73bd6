"""Bound BLAS to one thread in processes that run a filter.

A filter step hands BLAS products of ``N``-long arrays (the process noise ``L z``, weighted
covariances). OpenBLAS threads them across every core; on a machine busy with other work its worker
threads wait for a core, and a step stalls for many times its own cost (``python -m
gpf_nav.experiments.blas_bench`` measures it). One thread per filter process avoids that stall; run several
processes for parallelism (as ``gpf-nav montecarlo`` does).

``gpf-nav`` and the ``estimator`` node call :func:`limit_blas_threads` at start-up; a program of your
own that runs the filters can do the same.
"""
from __future__ import annotations

import os

_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
_limits = None


def limit_blas_threads(threads: int = 1) -> bool:
    """Limit the BLAS libraries loaded in this process to ``threads`` threads, for its lifetime.

    Returns True when applied; False, changing nothing, when the user chose a thread count through
    ``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS`` or ``MKL_NUM_THREADS``, or when ``threadpoolctl`` is
    not installed (a pip install has it; a colcon build may not).
    """
    global _limits
    if any(os.environ.get(name) for name in _THREAD_VARIABLES):
        return False
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return False
    import numpy  # noqa: F401  threadpoolctl sees only the BLAS libraries already loaded:
    import scipy.linalg  # noqa: F401  numpy's and scipy's (each wheel ships its own OpenBLAS)

    _limits = threadpool_limits(limits=int(threads), user_api="blas")  # kept: the limit lasts while it lives
    return True
