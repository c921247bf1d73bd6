"""Compiled inner loops of the particle filters and of the lunar model (numba, ``@njit(cache=True)``), and
the small-matrix arithmetic every filter runs at each step (the observability tracker,
:mod:`~gpf_nav.kernels.information`; the covariance floor's screen, :mod:`~gpf_nav.kernels.covariance`).

Plain functions over float64 arrays, particle index last (``(n, N)``), called from the numpy code paths
of :mod:`gpf_nav.filters`, :mod:`gpf_nav.models` and :mod:`gpf_nav.resampling`; random numbers come from
the filters' numpy ``Generator`` (drawn by the callers and passed in, or, for the normal draws, drawn here from
the generator by numpy's own algorithm, :mod:`~gpf_nav.kernels.normals`), so the streams stay those of the
numpy code (results equal to rounding, most of them bit for bit: ``test/test_kernels.py`` checks each kernel against
the numpy it replaced, ``test/numpy_reference.py``). Each kernel is compiled at its first call and cached
on disk (``__pycache__``, or numba's user cache where that is not writable): a fresh install pays the
compilation once. A user's own model's methods stay its numpy; the machinery around them (the
residual's angle wrapping, the flattened update's departures and tests) runs here for every model.

What makes them fast: loops over a block of :data:`CHUNK` particles that vectorise, one per function
(inlined together with a branchy loop, a loop stays scalar), rows indexed through views (an index
``start + t`` gets numba's negative-index check, which keeps loops scalar), no sum of floats or
short-circuit across particles; the lunar flow runs each sub-step over the whole block rather than
particle by particle. The products of a small matrix with the whole cloud (the GPF's proposal draw, the
moment map) stay BLAS calls, which a loop does not beat. The per-particle kernels run on every core from
:data:`PARALLEL` particles, with the serial loop's arithmetic (bit for bit); below it, on a machine
busy with other processes, the threads cost more than they save. The moments stay serial at every N:
threads do not make them faster.
"""

CHUNK = 256
"""Particles a kernel works on at a time (rows of this length stay in the first-level cache, and loops
over them vectorise)."""
PARALLEL = 50_000
"""Particles from which the per-particle kernels (the lunar flow and frames, the flattening's departures) use
every core."""
VECTOR_MATH = 4_096
"""Particles from which the kernels' transcendental functions (the lunar measurement's arctangents, the
weights' exponentials) are numpy's SIMD loops over the whole cloud, the numpy code's results bit for bit on
every machine; below it the C library's, one particle at a time, in a single pass: the rounding the
figures on record (N = 500, ``docs/results.md``) were computed with."""
