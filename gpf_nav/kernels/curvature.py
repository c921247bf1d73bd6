"""The flattened update's inner loops (:mod:`gpf_nav.filters.flattening`): the departures of the
measured rows from their linearisation at the cloud's mean, and the tests of their size, in noise
standard deviations, each in one pass without temporaries."""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from gpf_nav.kernels import CHUNK, PARALLEL


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def _departure_block(residual, x, mean, jacobian, out, column, start, linear):
    """:func:`departure` of the particles ``start`` to ``start + CHUNK``, row by row over the block, the
    linear part summed over the state's components in turn through ``linear`` ``(CHUNK,)`` (a loop
    that vectorises; indexing views, not ``start + t``, lets it)."""
    size = min(linear.size, x.shape[1] - start)
    for c in range(jacobian.shape[0]):
        for t in range(size):
            linear[t] = 0.0
        for a in range(x.shape[0]):
            slope, centre, row = jacobian[c, a], mean[a], x[a, start:start + size]
            for t in range(size):
                linear[t] += (row[t] - centre) * slope
        departures, residuals = out[start:start + size, column + c], residual[start:start + size, c]
        for t in range(size):
            departures[t] = residuals[t] - linear[t]


@njit(cache=True, error_model="numpy")
def _departure_serial(residual, x, mean, jacobian, out, column):
    linear = np.empty(CHUNK)
    for start in range(0, x.shape[1], CHUNK):
        _departure_block(residual, x, mean, jacobian, out, column, start, linear)


@njit(cache=True, error_model="numpy", parallel=True)
def _departure_parallel(residual, x, mean, jacobian, out, column):
    for block in prange((x.shape[1] + CHUNK - 1) // CHUNK):
        _departure_block(residual, x, mean, jacobian, out, column, block * CHUNK, np.empty(CHUNK))


def departure(residual: np.ndarray, x: np.ndarray, mean: np.ndarray, jacobian: np.ndarray, out: np.ndarray,
              column: int) -> None:
    """Write into the columns ``column`` to ``column + m`` of ``out`` ``(N, K)`` the ``residual`` ``(N, m)``
    of the particles ``x`` ``(n, N)`` (C-contiguous) minus its linear part ``(x - mean) @ jacobian.T``
    (``mean`` ``(n,)``, ``jacobian`` ``(m, n)`` C-contiguous). Each linear part is a chain of fused
    multiply-adds over the components in turn, the order of the BLAS product it replaces (equal to it bit
    for bit where that product is such a chain, as with OpenBLAS on x86-64 with FMA; to rounding
    elsewhere). On every core from :data:`~gpf_nav.kernels.PARALLEL` particles."""
    kernel = _departure_parallel if x.shape[1] >= PARALLEL else _departure_serial
    kernel(residual, x, mean, jacobian, out, column)


@njit(cache=True, error_model="numpy")
def largest_scaled(nu: np.ndarray, previous: np.ndarray, scale: np.ndarray) -> float:
    """``max |(nu - previous) / scale|`` over ``nu`` ``(N, K)`` (``previous`` ``(N, K)``, or ``(0, 0)``:
    none) with ``scale`` ``(K,)``, each term the numpy code's; NaN when any term is NaN (numpy's
    ``max``). A running maximum per column, so the loop vectorises (the divisions bound it)."""
    largest = np.zeros(nu.shape[1])
    change = previous.size > 0
    nan = False
    for j in range(nu.shape[0]):
        for k in range(nu.shape[1]):
            value = abs(((nu[j, k] - previous[j, k]) if change else nu[j, k]) / scale[k])
            largest[k] = value if value > largest[k] else largest[k]
            nan |= value != value
    if nan:
        return math.nan
    result = 0.0
    for k in range(largest.size):  # (not largest.max(): compiling numpy's reduction takes a second)
        result = largest[k] if largest[k] > result else result
    return result


@njit(cache=True, error_model="numpy")
def scaled_by_particle(nu: np.ndarray, scale: np.ndarray, out: np.ndarray) -> bool:
    """Write into ``out`` ``(N,)`` each particle's ``max |nu / scale|`` over ``nu`` ``(N, K)`` with ``scale``
    ``(K,)`` (each term :func:`largest_scaled`'s); True when any term is NaN (``out`` then undefined)."""
    nan = False
    for j in range(nu.shape[0]):
        largest = 0.0
        for k in range(nu.shape[1]):
            value = abs(nu[j, k] / scale[k])
            largest = value if value > largest else largest
            nan |= value != value
        out[j] = largest
    return nan


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def _quadratic_block(x, mean, upper, out, column, start, offsets, totals):
    """:func:`quadratic_departure` of the particles ``start`` to ``start + CHUNK``: the offsets from the
    mean into the first ``n`` rows of ``offsets`` ``(n + 1, CHUNK)``, then, pair of components by pair,
    their product into its last row and that product into every row's sum, ``totals`` ``(R, CHUNK)``."""
    size = min(totals.shape[1], x.shape[1] - start)
    n, rows = x.shape[0], upper.shape[0]
    for a in range(n):
        values, centre, offset = x[a, start:start + size], mean[a], offsets[a]
        for t in range(size):
            offset[t] = values[t] - centre
    for c in range(rows):
        total = totals[c]
        for t in range(size):
            total[t] = 0.0
    product = offsets[n]
    for a in range(n):
        first = offsets[a]
        for b in range(a, n):
            second = offsets[b]
            for t in range(size):
                product[t] = first[t] * second[t]
            for c in range(rows):
                coefficient, total = upper[c, a, b], totals[c]
                for t in range(size):
                    total[t] += coefficient * product[t]
    for c in range(rows):
        departures, total = out[start:start + size, column + c], totals[c]
        for t in range(size):
            departures[t] = total[t]


@njit(cache=True, error_model="numpy")
def _quadratic_serial(x, mean, upper, out, column):
    offsets, totals = np.empty((x.shape[0] + 1, CHUNK)), np.empty((upper.shape[0], CHUNK))
    for start in range(0, x.shape[1], CHUNK):
        _quadratic_block(x, mean, upper, out, column, start, offsets, totals)


@njit(cache=True, error_model="numpy", parallel=True)
def _quadratic_parallel(x, mean, upper, out, column):
    for block in prange((x.shape[1] + CHUNK - 1) // CHUNK):
        _quadratic_block(x, mean, upper, out, column, block * CHUNK, np.empty((x.shape[0] + 1, CHUNK)),
                         np.empty((upper.shape[0], CHUNK)))


def quadratic_departure(x: np.ndarray, mean: np.ndarray, hessians: np.ndarray, out: np.ndarray,
                        column: int) -> None:
    """Write into the columns ``column`` to ``column + R`` of ``out`` ``(N, K)`` the second-order departures
    ``d^T T_c d / 2`` of the particles ``x`` ``(n, N)`` (C-contiguous), ``d = x - mean``, for each symmetric
    ``T_c`` of ``hessians`` ``(R, n, n)``: a sum over the ``n (n + 1) / 2`` pairs of components, each pair's
    product formed once for every row. On every core from :data:`~gpf_nav.kernels.PARALLEL` particles."""
    upper = np.triu(hessians, 1) + 0.5 * np.diagonal(hessians, axis1=1, axis2=2)[:, :, None] * np.eye(mean.size)
    kernel = _quadratic_parallel if x.shape[1] >= PARALLEL else _quadratic_serial
    kernel(x, mean, np.ascontiguousarray(upper), out, column)
