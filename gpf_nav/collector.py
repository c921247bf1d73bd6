"""Python's cyclic garbage collector in a real-time node: the start-up's objects kept out of its scans.

CPython runs a full collection when the objects that survived the younger generations reach a quarter of
those in the oldest, and a full collection scans every container object of the process. After its warm-up
the estimator holds about 150 000 (numpy's, numba's and rclpy's modules, the compiled kernels, the
parameters): one full collection took 64 ms, inside a measurement update (it was the largest latency of
``gpf-nav bench --node`` at 50 Hz). :func:`freeze_start_up` collects once and moves every object alive to
the collector's permanent generation (:func:`gc.freeze`): later full collections scan only what the run
has made since, and come seldom. :func:`thaw` moves them back, for a node that drops its filter (lifecycle
``cleanup``: what it dropped must be collectable again).
"""
from __future__ import annotations

import gc


def freeze_start_up() -> int:
    """Collect, then keep every object alive now out of later collections; returns how many were frozen."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


def thaw() -> None:
    """Return the frozen objects to the collector (:func:`freeze_start_up` undone)."""
    gc.unfreeze()
