"""Compiled inner loops of the particle filters and of the lunar model (numba, ``@njit(cache=True)``), and
the small-matrix arithmetic every filter runs at each step (the observability tracker,
:mod:`~gpf_nav.kernels.information`; the covariance floor's screen, :mod:`~gpf_nav.kernels.covariance`).

Plain functions over float64 arrays, particle index last (``(n, N)``), called from the numpy code paths
of :mod:`gpf_nav.filters`, :mod:`gpf_nav.models` and :mod:`gpf_nav.resampling`; random numbers are drawn
by the callers with numpy's ``Generator`` and passed in, so the streams stay those of the numpy code
(results equal to rounding, most of them bit for bit: ``test/test_kernels.py`` checks each kernel against
the numpy it replaced, ``test/numpy_reference.py``). Each kernel is compiled at its first call and cached
on disk (``__pycache__``, or numba's user cache where that is not writable): a fresh install pays the
compilation once. A user's own model's methods stay its numpy; the machinery around them (the
residual's angle wrapping, the flattened update's departures and tests) runs here for every model.

What made them fast, measured on a 2-core machine: loops over a block of :data:`CHUNK` particles that
vectorise, one per function (inlined together with a branchy loop, the frames' loop stayed scalar),
indexing rows through views (an index ``start + t`` gets numba's negative-index check, which kept loops
scalar), no sum of floats or short-circuit across particles; the lunar flow runs each sub-step over the
whole block (5 times faster than particle by particle). The products of a small matrix with the whole
cloud (the GPF's proposal draw, the moment map) stay BLAS calls: kernels written for them were 1.1 to 2
times slower. The per-particle kernels run on every core from :data:`PARALLEL` particles, with the
serial loop's arithmetic (bit for bit); below it they stay serial: next to two busy processes the
parallel flow was 4 times slower at N = 500 and 1.6 times at 10 000, and 1.7 times faster at 100 000.
The moments stay serial at every N (in parallel they were never faster, and up to 8 times slower).
"""

CHUNK = 256
"""Particles a kernel works on at a time (rows of this length stay in the first-level cache, and loops
over them vectorise)."""
PARALLEL = 50_000
"""Particles from which the per-particle kernels (the lunar flow and frames, the flattening's departures) use
every core."""
