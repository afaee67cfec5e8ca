"""The exact model's Gaussians in depth order, as one-cache-line records (numba).

The exact compositing kernels (:mod:`.numba_exact`) take the Gaussians numbered front to back:
:func:`depth_order` sorts their depths (a radix sort, one chunk per thread), and a parallel gather writes
each Gaussian's table row, depth and window into one 64-byte record (:func:`gaussian_records`) in
that order, so that an instance's rows are one cache line. :func:`gather_windows` computes the
windows of the numba projection on the way; :func:`gather_gaussians` copies windows computed
before (by torch, for Gaussians that torch projected).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from vid2haircut.render.allocator import aligned_empty
from vid2haircut.render.numba_kernels import GATHER_AHEAD
from vid2haircut.render.numba_simd import prefetch_row
from vid2haircut.render.numba_windows import W_HGT, W_HZ, W_NCOL, W_SLOPE, W_ULO, W_V0, window_of


DEPTH_CHUNK_MIN = 32768
""":func:`depth_order` splits the depths into one chunk per thread when each holds at least this many."""


@njit(cache=True, parallel=True)
def depth_order(z, threads=1):
    """[G] int64 permutation sorting the depths ``z`` (float32 or float64) in ascending order, ties
    in index order (stable); NaN last. A radix sort of the depths' float32 bits (positive floats
    order as their bit patterns; negative depths, which are never drawn, as 0.0) less the
    smallest: the depths of a frame span ~2^23 such steps (0.46-0.74 m: 23 bits), sorted in two
    passes of 12-bit digits whose count tables (32 KB) stay in the L1 cache (1.11 -> 0.85 ms for
    124,000 depths on the project's CPU, against two passes of 16-bit digits); at most 12 bits a
    pass, so a wider span takes three. float64 depths are ordered by their float32 rounding: two
    within one float32 step (3e-8 m at 0.5 m) keep index order.

    With ``threads`` > 1 the depths are cut into one contiguous chunk per thread (each of at least
    :data:`DEPTH_CHUNK_MIN`): every pass counts each chunk's digits in parallel, and chunk c's
    members of a digit go after those of the chunks before it, so the order stays stable and is
    the same for any thread count."""
    G = z.shape[0]
    C = max(1, min(threads, G // DEPTH_CHUNK_MIN))
    key = np.empty(G, np.uint32)
    nan = np.uint32(0xFFFFFFFF)  # (no float32 >= 0 has these bits)
    los, his = np.full(C, nan, np.uint32), np.zeros(C, np.uint32)
    for c in prange(C):  # the keys, and the smallest and largest of those that are not NaN
        lo, hi = nan, np.uint32(0)
        for i in range(c * G // C, (c + 1) * G // C):
            v = np.float32(z[i])
            if v != v:
                key[i] = nan
                continue
            k = np.uint32(0) if v < 0 else np.float32(v + np.float32(0.0)).view(np.uint32)  # + 0: -0.0 -> 0.0
            key[i] = k
            lo, hi = min(lo, k), max(hi, k)
        los[c], his[c] = lo, hi
    lo, hi = los.min(), his.max()
    if lo > hi:  # every depth NaN (or none)
        return np.arange(G)
    top = hi - lo + np.uint32(1)  # the keys less lo: 0 .. hi - lo, NaN top (made in the first count)
    nb = 0
    while nb < 32 and (top >> np.uint32(nb)) != 0:
        nb += 1
    order = np.arange(G)
    npass = (nb + 11) // 12  # (top >= 1: at least one pass)
    bits = (nb + npass - 1) // npass
    mask = np.uint32((1 << bits) - 1)
    R = 1 << bits
    tmp = np.empty(G, np.int64)
    cnt = np.empty((C, R), np.int64)
    for ps in range(npass):
        shift = np.uint32(ps * bits)
        for c in prange(C):
            row = cnt[c]
            row[:] = 0
            if ps == 0:  # (order is the identity)
                for i in range(c * G // C, (c + 1) * G // C):
                    k = top if key[i] == nan else key[i] - lo
                    key[i] = k
                    row[k & mask] += 1
            else:
                for i in range(c * G // C, (c + 1) * G // C):
                    row[(key[order[i]] >> shift) & mask] += 1
        at = 0
        for d in range(R):  # each (chunk, digit)'s first slot: digits in turn, the chunks in order within one
            for c in range(C):
                n = cnt[c, d]
                cnt[c, d] = at
                at += n
        for c in prange(C):
            row = cnt[c]
            for i in range(c * G // C, (c + 1) * G // C):
                j = order[i]
                d = (key[j] >> shift) & mask
                tmp[row[d]] = j
                row[d] += 1
        order, tmp = tmp, order
    return order


@njit(cache=True, inline="always")
def _copy_row(dst, b, src, a, n):
    """dst[b, :n] = src[a, :n]. Callers pass the width as a literal: LLVM turns a row loop of
    run-time length into a call of memcpy, whose per-call cost was ~5% of a whole exact
    forward+backward (perf, AMD Zen 3)."""
    for c in range(n):
        dst[b, c] = src[a, c]


def gaussian_records(G, dtype):
    """Views (gpar [G, 8] of ``dtype``, wint [G, 4] int32, wflt [G, 2] float32) of one table of
    records, one per Gaussian, each starting on a 64-byte cache line: the rows that the exact
    kernels read for an instance (:func:`composite_exact_forward`: the Gaussian, its depth
    gpar[:, 5] and its window) lie in one cache line for float32 tables (64-byte records; 128 for
    float64), instead of in four arrays (each instance's Gaussian is a random row of the table,
    which outgrows the L2 cache). The exact forward kernel alone: 27.0-27.5 -> 24.0-25.0 ms single
    threaded for 4k strands at 256 x 256 (AMD Zen 3), the same results."""
    item = np.dtype(dtype).itemsize
    rb = 64 if item == 4 else 128
    rec = aligned_empty((G, rb), np.uint8)
    w0 = 8 * item  # byte offsets: the Gaussian's 8 values, then (slope, v0), then the 4 window integers
    gpar = rec.view(dtype)[:, 0:8]
    wflt = rec.view(np.float32)[:, w0 // 4:w0 // 4 + 2]
    wint = rec.view(np.int32)[:, w0 // 4 + 2:w0 // 4 + 6]
    return gpar, wint, wflt


@njit(cache=True, inline="always")
def _gather_row(i, order, gpar, frame, gs, fr):
    """Record i's share of a gather into depth order: Gaussian j = order[i]'s table row into gs[i] and
    its frame into fr[i], after prefetching the table row and frame of Gaussian ia = order[i +
    GATHER_AHEAD] (read that many iterations later, scattered). Returns (j, ia): the caller reads
    j's other rows and prefetches ia's."""
    ia = np.int64(order[min(i + GATHER_AHEAD, order.shape[0] - 1)])
    prefetch_row(gpar, ia)
    prefetch_row(frame, ia)
    j = np.int64(order[i])
    _copy_row(gs, i, gpar, j, 8)
    fr[i] = frame[j]
    return j, ia


@njit(cache=True, parallel=True)
def gather_gaussians(order, gpar, wint, wflt, frame, gs, ws, fs):
    """The Gaussians' rows and windows in the order ``order`` (a [G] permutation,
    :func:`depth_order`), in one parallel pass, into the records of :func:`gaussian_records`
    (gs [G, 8], ws [G, 4] int32, fs [G, 2] float32: each record written whole at once); returns
    frame [G] in that order. Record i is that of Gaussian order[i]."""
    G = order.shape[0]
    fr = np.empty(G, frame.dtype)
    for i in prange(G):
        j, ia = _gather_row(i, order, gpar, frame, gs, fr)
        prefetch_row(wint, ia)
        prefetch_row(wflt, ia)
        for c in range(4):
            ws[i, c] = np.int32(wint[j, c])
        fs[i, 0], fs[i, 1] = wflt[j, 0], wflt[j, 1]
    return fr


@njit(cache=True, parallel=True, error_model="numpy")
def gather_windows(order, gpar, covs, valid, frame, height, width, power_min, cols, gs, ws, fs):
    """:func:`gather_gaussians` for the numba backend's own windows: the Gaussians' rows in the order
    ``order``, with their windows computed on the way (:func:`.numba_windows.window_of`) from their
    means (gpar[:, 0:2]), ``covs`` [G, 3] and ``valid`` [G] bool, straight into the records, in one
    pass: no window tables written, then read scattered.

    The windows are those of :func:`.numba_windows.gaussian_windows` but for their heights: each
    window has the rows it needs, not that count rounded up to the binned model's common tile
    height (:func:`.numba_windows.common_rows`, which the torch footprint's layout needs). The
    exact model walks windows line by line and takes any height; the rows the rounding adds lie
    outside the Gaussian's alpha_min contour and hold no element. Choosing that height would take
    a pass over all windows before their records could be written whole. 4k strands at 256 x 256:
    windows 1.1 + gather 0.9 ms -> 1.5 ms in the call (AMD Zen 4), the same render.
    height, width, power_min, cols: as for :func:`.numba_windows.gaussian_windows`. Returns frame [G]
    in that order."""
    G = order.shape[0]
    fr = np.empty(G, frame.dtype)
    f32 = np.float32
    c2 = f32(-2.0 * power_min)
    for i in prange(G):
        j, ia = _gather_row(i, order, gpar, frame, gs, fr)
        prefetch_row(covs, ia)
        hz, u_lo, nt, nd, slope, v0 = window_of(f32(gpar[j, 0]), f32(gpar[j, 1]), f32(covs[j, 0]), f32(covs[j, 1]),
                                                f32(covs[j, 2]), valid[j], height, width, c2, cols)
        ws[i, W_HZ] = np.int32(hz)
        ws[i, W_ULO] = np.int32(u_lo)
        ws[i, W_NCOL] = np.int32(nt * cols)
        ws[i, W_HGT] = np.int32(nd)
        fs[i, W_SLOPE] = slope
        fs[i, W_V0] = v0
    return fr


__all__ = ["depth_order", "gaussian_records", "gather_gaussians", "gather_windows"]
