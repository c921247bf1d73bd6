"""Heap tuning for processes that run a particle filter: keep freed memory instead of returning it.

A filter step allocates and frees a few arrays of ``N x n`` floats (megabytes at N = 10,000). With
glibc's default, adaptive policy such blocks are given back to the kernel at every ``free`` (``mmap``
or a heap trim) and taken again at the next step, so each step pays hundreds of page faults. Taking every
block from the heap (no ``mmap``: glibc maps blocks beyond 32 MiB, a 9 x 1,000,000 cloud is 72 MB) and
raising the trim threshold to 1 GiB keeps them there: the process keeps up to that much freed memory,
and a step stops faulting, for a slightly larger peak resident memory. Fixing the ``mmap`` threshold at
glibc's largest, 32 MiB, is not enough: a large cloud's blocks are beyond it.

The ``gpf-nav`` command and the ``estimator`` node call :func:`retain_freed_memory` at start-up; a
program of your own that runs the filters can do the same. It changes nothing but speed and resident memory.
"""
from __future__ import annotations

import ctypes
import sys

M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
TRIM_THRESHOLD = 1024 * 1024 * 1024
"""Freed memory at the top of the heap is returned to the kernel only beyond this size."""
retained = False
"""Whether :func:`retain_freed_memory` has been applied in this process."""


def retain_freed_memory() -> bool:
    """Take every block from the heap and set glibc's trim threshold (see the module docstring) for this
    process.

    Returns True when applied; False, changing nothing, on a C library without ``mallopt``
    (macOS, Windows, musl) or when glibc refuses a value.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    global retained
    retained = bool(mallopt(M_MMAP_MAX, 0)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    return retained
