"""The particle filters' standard normal draws: the filter's own generator for a small cloud, rows of streams
of their own for a large one, filled by a compiled loop (:mod:`gpf_nav.kernels.normals`).

Six normal draws per particle are a large part of a bootstrap filter's step (numpy's own loop takes ~10 ns a
draw here, the compiled one ~4 to 6). From :data:`ROW_STREAMS` particles each row of a draw comes from a
stream of its own (numpy's fastest bit generator, SFC64), and from :data:`~gpf_nav.kernels.PARALLEL`
particles the rows are filled by the calling thread and a pool of others at once (the compiled loop
releases the GIL; below that size handing rows to the pool costs more than it saves). The row streams are
children of a ``SeedSequence`` seeded by one integer the filter's generator draws at the first large draw:
the numbers depend on the filter's seed and on the shapes drawn, never on the number of threads, so a run
is still reproducible bit for bit, and each row is an exact standard normal draw independent of the others.
Below :data:`ROW_STREAMS` the draw is the generator's own ``standard_normal``, number for number.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from gpf_nav.kernels import PARALLEL
from gpf_nav.kernels.normals import fill_standard_normal

ROW_STREAMS = 4_096
"""Particles from which the rows of a draw come from streams of their own (filled on every core from
:data:`~gpf_nav.kernels.PARALLEL`)."""
_pool: ThreadPoolExecutor | None = None


class NormalDraws:
    """Standard normal draws ``(rows, count)`` for a filter with the generator ``rng``."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self._seeds: np.random.SeedSequence | None = None
        self._streams: list[np.random.Generator] = []

    def __call__(self, rows: int, count: int) -> np.ndarray:
        """``(rows, count)`` independent standard normals."""
        out = np.empty((rows, count))
        if count < ROW_STREAMS:
            fill_standard_normal(self.rng, out.reshape(-1))
            return out
        streams = self._row_streams(rows)
        workers = _workers() if count >= PARALLEL else 1
        groups = [range(first, rows, workers) for first in range(min(workers, rows))]

        def fill(group: range) -> None:
            for row in group:
                fill_standard_normal(streams[row], out[row])

        others = [_threads().submit(fill, group) for group in groups[1:]]
        fill(groups[0])  # (this thread's share)
        for done in others:
            done.result()
        return out

    def _row_streams(self, rows: int) -> list[np.random.Generator]:
        """The first ``rows`` row streams, spawned when first needed."""
        if self._seeds is None:
            self._seeds = np.random.SeedSequence(int(self.rng.integers(2 ** 63)))
        if len(self._streams) < rows:
            self._streams += [np.random.Generator(np.random.SFC64(child))
                              for child in self._seeds.spawn(rows - len(self._streams))]
        return self._streams


def _workers() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _threads() -> ThreadPoolExecutor:
    """The process's pool of draw threads (created at the first large draw)."""
    global _pool
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=max(_workers() - 1, 1), thread_name_prefix="gpf_nav_normals")
    return _pool


def _forget_pool() -> None:
    """In a forked child: the parent's pool threads were not copied, so a pool of its own is made when needed."""
    global _pool
    _pool = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)
