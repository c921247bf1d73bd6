"""Compiled inner loops of the particle filters and of the lunar model (numba, ``@njit(cache=True)``), and
the small-matrix arithmetic every filter runs at each step (the observability tracker,
:mod:`~gpf_nav.kernels.information`; the covariance floor's screen, :mod:`~gpf_nav.kernels.covariance`).

Plain functions over float64 arrays, particle index last (``(n, N)``), called from the numpy code paths
of :mod:`gpf_nav.filters`, :mod:`gpf_nav.models` and :mod:`gpf_nav.resampling`; random numbers are drawn
by the callers with numpy's ``Generator`` and passed in, so the streams stay those of the numpy code
(results equal to rounding: ``test/test_kernels.py`` checks each kernel against the numpy it replaced,
``test/numpy_reference.py``). Each kernel is compiled at its first call and cached on disk
(``__pycache__``, or numba's user cache where that is not writable): a fresh install pays the compilation
once. A user's own model never goes through a kernel.

The filters' products of a small matrix with the whole cloud (the GPF's proposal draw, the moment map)
stay BLAS calls: kernels written for them were 1.1 to 2 times slower at N = 10 000 and 100 000. The
kernels that are arithmetic per particle (the lunar flow, its orbit frames and the acceleration pushed
through them) run their particles on every core from :data:`PARALLEL` particles, with the arithmetic of
the serial loop (bit for bit). Below it they stay serial: on the 2-core machine they were measured on,
next to two busy processes, the parallel flow was 4 times slower at N = 500 and 1.6 times at 10 000,
and 1.7 times faster at 100 000. The moments stay serial at every N (parallel moments were never faster
there, and up to 8 times slower).
"""

CHUNK = 256
"""Particles a kernel works on at a time (rows of this length stay in the first-level cache, and loops
over them vectorise)."""
PARALLEL = 50_000
"""Particles from which the per-particle kernels (:mod:`gpf_nav.kernels.orbit`) use every core."""
