"""Normalisation of a particle filter's log-weights (log-sum-exp) in three passes without temporaries, and the
Gaussian log-likelihood they are incremented by.

The numpy code it replaces (NaN to ``-inf``, the peak, ``exp(logw - peak)``, their sum, then
``logw - total`` and its ``exp``) makes eight passes over the weights and four temporaries; at a few
hundred particles its calls cost more than the arithmetic. Here the sum is numpy's pairwise summation
(:func:`_pairwise`, the order of ``np.add.reduce`` on a contiguous array: blocks of 128 summed in eight
interleaved partial sums, halved above that), each term computed where it is added, so the total is
numpy's bit for bit; ``math.exp`` and ``math.log`` are the C library's, as numpy's are where it has no
SIMD version of its own for float64 (x86-64 without AVX-512: ``test_kernels`` checks it where it runs).
From :data:`~gpf_nav.kernels.VECTOR_MATH` weights the exponentials are numpy's own over the whole cloud
(its SIMD loops, several times faster than the C library's one at a time) between passes of the kernel:
the numpy code's results bit for bit on every machine.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from gpf_nav.kernels import VECTOR_MATH

_BLOCK = 128
"""numpy's pairwise-summation block (``PW_BLOCKSIZE``)."""
_DEPTH = 64
"""Deepest stack of halved spans (the halves of 2^63 terms are 56 deep)."""


@njit(cache=True, error_model="numpy")
def _block_sum(logw: np.ndarray, peak: float, start: int, count: int) -> float:
    """Sum of ``exp(logw - peak)`` over ``logw[start:start + count]``, ``count`` at most :data:`_BLOCK`, in
    numpy's order: eight interleaved partial sums from eight terms on, a plain sum from ``-0.0`` below."""
    if count < 8:
        total = -0.0
        for i in range(start, start + count):
            total += math.exp(logw[i] - peak)
        return total
    r0, r1 = math.exp(logw[start] - peak), math.exp(logw[start + 1] - peak)
    r2, r3 = math.exp(logw[start + 2] - peak), math.exp(logw[start + 3] - peak)
    r4, r5 = math.exp(logw[start + 4] - peak), math.exp(logw[start + 5] - peak)
    r6, r7 = math.exp(logw[start + 6] - peak), math.exp(logw[start + 7] - peak)
    body = count - count % 8
    for i in range(start + 8, start + body, 8):
        r0 += math.exp(logw[i] - peak)
        r1 += math.exp(logw[i + 1] - peak)
        r2 += math.exp(logw[i + 2] - peak)
        r3 += math.exp(logw[i + 3] - peak)
        r4 += math.exp(logw[i + 4] - peak)
        r5 += math.exp(logw[i + 5] - peak)
        r6 += math.exp(logw[i + 6] - peak)
        r7 += math.exp(logw[i + 7] - peak)
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(start + body, start + count):
        total += math.exp(logw[i] - peak)
    return total


@njit(cache=True, error_model="numpy")
def _pairwise(logw: np.ndarray, peak: float) -> float:
    """Sum of ``exp(logw - peak)`` in numpy's pairwise order: a span longer than :data:`_BLOCK` is the sum
    of its two halves (the first rounded down to a multiple of eight), each summed the same way. Written
    with an explicit stack of the spans being summed (numba cannot load a cached recursive function)."""
    if logw.size <= _BLOCK:
        return _block_sum(logw, peak, 0, logw.size)
    start, count = np.zeros(_DEPTH, np.int64), np.zeros(_DEPTH, np.int64)
    stage, left = np.zeros(_DEPTH, np.int64), np.zeros(_DEPTH)  # stage: 0 new, 1 left half, 2 right half
    count[0], depth, value, returned = logw.size, 1, 0.0, False
    while depth:
        d = depth - 1
        if returned:  # a half of span d was summed into value
            if stage[d] == 2:
                value, depth = left[d] + value, depth - 1
                continue
            left[d], returned = value, False
        half = count[d] // 2
        half -= half % 8
        stage[d] += 1
        first, size = (start[d], half) if stage[d] == 1 else (start[d] + half, count[d] - half)
        if size <= _BLOCK:
            value, returned = _block_sum(logw, peak, first, size), True
        else:
            start[depth], count[depth], stage[depth], depth = first, size, 0, depth + 1
    return value


@njit(cache=True, error_model="numpy")
def _peak(logw: np.ndarray) -> float:
    """The largest of the log-weights ``logw`` ``(N,)``, NaN entries set to ``-inf`` in place."""
    peak = -math.inf
    for i in range(logw.size):
        value = logw[i]
        if value != value:
            logw[i] = value = -math.inf
        peak = value if value > peak else peak
    return peak


@njit(cache=True, error_model="numpy")
def _normalise_scalar(logw: np.ndarray, normalised: np.ndarray, weights: np.ndarray) -> float:
    peak = _peak(logw)
    if not -math.inf < peak < math.inf:
        return math.nan
    total = peak + math.log(_pairwise(logw, peak))
    for i in range(logw.size):
        normalised[i] = value = logw[i] - total
        weights[i] = math.exp(value)
    return total


def normalise(logw: np.ndarray, normalised: np.ndarray, weights: np.ndarray) -> float:
    """Normalise the log-weights ``logw`` ``(N,)`` (C-contiguous): NaN entries set to ``-inf`` in place,
    ``normalised = logw - total`` and ``weights = exp(normalised)`` written (both ``(N,)``), and the
    log-sum-exp ``total`` returned; NaN, writing neither, when the peak is not finite (every weight zero,
    or an infinite one). From :data:`~gpf_nav.kernels.VECTOR_MATH` weights with numpy's exponential."""
    if logw.size < VECTOR_MATH:
        return _normalise_scalar(logw, normalised, weights)
    peak = _peak(logw)
    if not -math.inf < peak < math.inf:
        return math.nan
    np.subtract(logw, peak, out=normalised)
    total = float(peak + np.log(np.exp(normalised, out=weights).sum()))
    np.subtract(logw, total, out=normalised)
    np.exp(normalised, out=weights)
    return total


@njit(cache=True, error_model="numpy")
def whitened_log_likelihood(e: np.ndarray, w: np.ndarray, constant: float, out: np.ndarray) -> None:
    """``constant - |w * e_n|^2 / 2`` into ``out`` ``(N,)`` for the residuals ``e`` ``(k, N)`` (``k >= 1``) and
    the diagonal whitener ``w`` ``(k,)``: the numpy code's ``e * w[:, None]`` squared and summed over ``k`` in
    order, as ``np.einsum("kn,kn->n")`` sums them from two particles on (one particle's column it sums in
    another order), bit for bit, without the ``(k, N)`` temporary. Row by row, so the loops vectorise."""
    first, scale = e[0], w[0]
    for j in range(out.size):
        a = first[j] * scale
        out[j] = a * a
    for c in range(1, e.shape[0]):
        row, scale = e[c], w[c]
        for j in range(out.size):
            a = row[j] * scale
            out[j] += a * a
    for j in range(out.size):
        out[j] = constant - 0.5 * out[j]
