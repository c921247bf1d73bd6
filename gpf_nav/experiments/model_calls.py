"""How much of a filter's step is spent inside its model: a timer of the calls into one model instance.

A filter's step is calls into the user's model (the drift, its Jacobian, the measurement and its residuals: what
any implementation of the same algorithm makes, at the model's own cost) and the filter's machinery around them
(projection, weights, resampling, moments, trackers, and the filter's own wrappers of the model, such as the
unmodelled-acceleration compensation). :class:`ModelCallTimer` wraps every public method of a model instance
while it is installed and sums the wall time of the outermost calls (a model method calling another counts
once), so ``gpf-nav bench --model-calls`` splits each filter's step in the two. Every wrapped call costs a
fraction of a microsecond more, so the steps it times are slower than the bench's plain figures by that much.
"""
from __future__ import annotations

import inspect
import time
from collections import defaultdict
from collections.abc import Callable


class ModelCallTimer:
    """The calls into ``model`` while installed (``with ModelCallTimer(model) as timer:``), outermost only.

    Attributes:
        seconds: wall time spent inside the model's methods so far, s.
        calls: the calls counted so far.
        blocks: per filter index, ``(seconds per step, calls per step)`` inside the model in each of its
            timed blocks (:meth:`start_block`, :meth:`end_block`).
    """

    def __init__(self, model):
        self.model = model
        self.seconds = 0.0
        self.calls = 0
        self.blocks: defaultdict[int, list[tuple[float, float]]] = defaultdict(list)
        self._depth = 0
        self._wrapped: list[str] = []
        self._block_start = (0.0, 0)

    def __enter__(self) -> ModelCallTimer:
        for name, _ in inspect.getmembers(type(self.model), callable):
            method = getattr(self.model, name)
            if not name.startswith("_") and inspect.ismethod(method):
                setattr(self.model, name, self._timed(method))  # (an instance attribute: shadows the class's)
                self._wrapped.append(name)
        return self

    def __exit__(self, *exc) -> None:
        for name in self._wrapped:
            delattr(self.model, name)
        self._wrapped = []

    def start_block(self) -> None:
        """A timed block of steps begins."""
        self._block_start = (self.seconds, self.calls)

    def end_block(self, index: int, steps: int) -> None:
        """The block of ``steps`` steps of the filter ``index`` that began at :meth:`start_block` ends."""
        seconds, calls = self._block_start
        self.blocks[index].append(((self.seconds - seconds) / steps, (self.calls - calls) / steps))

    def _timed(self, method: Callable) -> Callable:
        def timed(*args, **kwargs):
            if self._depth:  # (inside another of the model's methods: counted there)
                return method(*args, **kwargs)
            self._depth += 1
            start = time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start
                self.calls += 1
                self._depth -= 1
        return timed
