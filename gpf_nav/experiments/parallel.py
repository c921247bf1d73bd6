"""Map independent tasks over local processes or a Dask distributed cluster, results in task order.

* ``workers == 1`` and no scheduler: in this process (no pool; handy for debugging and profiling).
* ``workers > 1``: a :class:`concurrent.futures.ProcessPoolExecutor` (``spawn`` start method, one BLAS
  thread per worker so the processes do not oversubscribe the cores).
* ``scheduler="ADDRESS"``: an existing Dask distributed scheduler (``tcp://host:8786``); the workers
  must be able to import ``gpf_nav`` (install the package on them). The client is closed afterwards,
  the cluster is left running.

Each task must be self-contained and seeded by its own content (see :mod:`gpf_nav.experiments.runner`);
results are returned in input order, so the output is identical for any worker count or engine.
A tqdm progress bar on stderr counts finished tasks.
"""
from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed

from gpf_nav.arguments import positive_int

_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def add_campaign_arguments(parser: argparse.ArgumentParser, runs: int, runs_help: str) -> None:
    """The options every campaign shares: ``--runs`` (default ``runs``, described by ``runs_help``),
    ``--seed`` and where the runs go (``--workers``, ``--scheduler``: :func:`map_tasks`)."""
    parser.add_argument("--runs", type=positive_int, default=runs, help=f"{runs_help} (default {runs})")
    parser.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    parser.add_argument("--workers", type=positive_int, default=None,
                        help="local worker processes (default: all local cores)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="run on this Dask distributed scheduler (e.g. tcp://host:8786) instead "
                             "of local processes; the workers must have gpf_nav installed")


def default_workers() -> int:
    """Number of local cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def _single_threaded_children():
    """Set the BLAS/OpenMP thread variables to 1 (unless set) while child processes are started."""
    saved = {name: os.environ.get(name) for name in _THREAD_VARIABLES}
    for name in _THREAD_VARIABLES:
        os.environ.setdefault(name, "1")
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _progress(total: int, enabled: bool, description: str):
    from tqdm import tqdm

    return tqdm(total=total, disable=not enabled, desc=description, unit="run", dynamic_ncols=True)


def map_tasks(function: Callable, tasks: Sequence, workers: int | None = None, scheduler: str | None = None,
              progress: bool = True, description: str = "runs") -> list:
    """``[function(t) for t in tasks]``, computed in parallel; the list is in the order of ``tasks``.

    Args:
        function: a module-level (picklable) function of one task.
        tasks: the tasks (picklable).
        workers: local processes (default: all local cores); ignored with ``scheduler``.
        scheduler: address of a Dask distributed scheduler, or None for local processes.
        progress: show a tqdm progress bar on stderr.
        description: label of the progress bar.
    """
    tasks = list(tasks)
    if scheduler:
        return _map_dask(function, tasks, scheduler, progress, description)
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers must be positive, got {workers}")
    results: list = [None] * len(tasks)
    with _progress(len(tasks), progress, description) as bar:
        if workers == 1 or len(tasks) <= 1:
            for i, task in enumerate(tasks):
                results[i] = function(task)
                bar.update()
            return results
        context = multiprocessing.get_context("spawn")
        with _single_threaded_children(), ProcessPoolExecutor(min(workers, len(tasks)),
                                                              mp_context=context) as pool:
            futures = {pool.submit(function, task): i for i, task in enumerate(tasks)}
            try:
                for future in as_completed(futures):
                    results[futures[future]] = future.result()
                    bar.update()
            except BaseException:
                for future in futures:
                    future.cancel()
                raise
    return results


def _map_dask(function: Callable, tasks: list, scheduler: str, progress: bool, description: str) -> list:
    from dask.distributed import Client
    from dask.distributed import as_completed as dask_as_completed

    results: list = [None] * len(tasks)
    with Client(scheduler) as client, _progress(len(tasks), progress, description) as bar:
        futures = client.map(function, tasks, pure=False)
        index = {future.key: i for i, future in enumerate(futures)}
        for future in dask_as_completed(futures):
            results[index[future.key]] = future.result()
            bar.update()
    return results
