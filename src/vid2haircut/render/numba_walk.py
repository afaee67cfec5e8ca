"""Per-tile building blocks of the fused CPU compositor (numba): element values, depth bins, bin tables.

See :mod:`vid2haircut.render.numba_kernels` for the model and the pass structure, and
:mod:`vid2haircut.render.numba_lines` for the window walk that lists a tile's elements. They are
kept in flat arrays at the tile's offset, instance by instance (instance k's at
e_range[k, 0]:e_range[k, 1]): pixel (index inside the tile), depth bin, d l / d power and
l = log(1 - alpha).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from vid2haircut.render.numba_math import lane_cast, lane_exp, lane_log1m, vexp
from vid2haircut.render.numba_simd import prefetch_row
from vid2haircut.render.numba_windows import B_MISS, W_HGT, W_HZ, W_NCOL, W_ULO, box_fields

JIT = dict(cache=True, error_model="numpy")
# columns of the Gaussian table ``gpar`` [G, 8] (input dtype)
G_MX, G_MY, G_QXX, G_QXY, G_QYY, G_Z, G_C, G_S = range(8)
# entries of ``consts``: log opacity, alpha_min, alpha_max, second silhouette's opacity ratio (0: none)
C_LOGOP, C_AMIN, C_AMAX, C_RATIO = range(4)
PREFETCH = 8
"""Instances ahead whose Gaussian rows the loops that first read them in a tile prefetch (the window
walk, :func:`tile_bounds`, :func:`bin_and_grad_sums`; :func:`.numba_simd.prefetch_row`): a tile's
instances lie scattered in the [G, 8] table, which outgrows the L2 cache, and the hint lets their
rows arrive while earlier instances are processed (2 ms less per 4k-strand forward+backward at 2
threads on the Zen 3, the same results, at 4 instances ahead; 8 since the exact model reads the
Gaussians' rows through ``sorted_g`` too: the same times for the binned model, 0.5 ms less
forward for the exact one)."""


@njit(**JIT)
def tile_box(t, width, height, tile):
    """Frame and inclusive pixel bounds (x0, x1, y0, y1) of tile ``t``."""
    ntx = (width + tile - 1) // tile
    nty = (height + tile - 1) // tile
    b = t // (ntx * nty)
    r = t - b * ntx * nty
    ty = r // ntx
    tx = r - ty * ntx
    x0, y0 = tx * tile, ty * tile
    return b, x0, min(x0 + tile, width) - 1, y0, min(y0 + tile, height) - 1


@njit(cache=True, parallel=True, error_model="numpy")
def tile_bounds(tile_start, sorted_g, wint, boxes, width, height, tile):
    """[NT] upper bound of each tile's element count (its window elements: the window's columns
    in the tile times its height, at most the tile's). ``boxes``: the instances' box codes
    (:func:`.numba_tiles.bin_windows`), read in order, no Gaussian rows; or None: from the rows
    of ``wint``, prefetched."""
    NT = tile_start.shape[0] - 1
    bounds = np.zeros(NT, np.int64)
    for t in prange(NT):
        cap = 0
        if boxes is not None:
            for k in range(tile_start[t], tile_start[t + 1]):
                c = boxes[k]
                if c != B_MISS:
                    lay, lo, hi, ua, ub, hmin = box_fields(c)
                    cap += (ub - ua + 1) * hmin
        else:
            b, x0, x1, y0, y1 = tile_box(t, width, height, tile)
            for k in range(tile_start[t], tile_start[t + 1]):
                if k + PREFETCH < tile_start[t + 1]:
                    prefetch_row(wint, sorted_g[k + PREFETCH])
                g = sorted_g[k]
                hz = wint[g, W_HZ] != 0
                tu0, tu1, tv0, tv1 = (x0, x1, y0, y1) if hz else (y0, y1, x0, x1)
                ua = max(wint[g, W_ULO], tu0)
                ub = min(wint[g, W_ULO] + wint[g, W_NCOL] - 1, tu1)
                if ub >= ua:
                    cap += (ub - ua + 1) * min(wint[g, W_HGT], tv1 - tv0 + 1)
        bounds[t] = cap
    return bounds


@njit(inline="always")
def _dl_and_l(e, h, lo, hi, zero, one):
    """(d l / d power, l) of one element: alpha = min(e, alpha_max) if > alpha_min else 0, times
    the head factor h, l = log(1 - alpha), d l / d power = alpha / (alpha - 1) (0 where alpha is
    clamped to alpha_max); e = exp(power) times the opacity ratio."""
    al = min(e, hi)
    al = (al if al > lo else zero) * h
    return (al / (al - one) if al < hi else zero), lane_log1m(al)


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def alpha_and_l(pw, hf, amin, amax):
    """In place: with alpha = min(exp(power), alpha_max) if > alpha_min else 0, times the head
    factor, and l = log(1 - alpha): power -> d l / d power = alpha / (alpha - 1) (0 where alpha is
    clamped to alpha_max: the backward pass needs nothing else of alpha), head factor -> l.
    A branch-free loop that LLVM vectorises, in the dtype of the arrays (float32 or float64);
    multiply-adds may be fused (``contract``: the series of exp and log in half the instructions,
    and no less accurate)."""
    if pw.shape[0] == 0:
        return
    lo, hi, zero, one = lane_cast(amin, pw[0]), lane_cast(amax, pw[0]), lane_cast(0.0, pw[0]), lane_cast(1.0, pw[0])
    for i in range(pw.shape[0]):
        pw[i], hf[i] = _dl_and_l(lane_exp(pw[i]), hf[i], lo, hi, zero, one)


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def alpha_and_l2(pw, hf, amin, amax, ratio, dl2, la2):
    """:func:`alpha_and_l`, and the same for a second, translucent silhouette whose opacity is
    ``ratio`` (< 1) times the first's: alpha2 = min(ratio exp(power), alpha_max) if > alpha_min
    else 0, times the head factor, into dl2 (d l2 / d power) and la2 (l2 = log(1 - alpha2)).
    Every contribution of the translucent render is one of the opaque render's, so one window
    walk serves both (:func:`vid2haircut.render.render_strands`, ``silhouette_opacity``)."""
    if pw.shape[0] == 0:
        return
    lo, hi, zero, one = lane_cast(amin, pw[0]), lane_cast(amax, pw[0]), lane_cast(0.0, pw[0]), lane_cast(1.0, pw[0])
    r = lane_cast(ratio, pw[0])
    for i in range(pw.shape[0]):
        e, h = lane_exp(pw[i]), hf[i]
        dl2[i], la2[i] = _dl_and_l(e * r, h, lo, hi, zero, one)
        pw[i], hf[i] = _dl_and_l(e, h, lo, hi, zero, one)


@njit(**JIT)
def bin_sums(e_p, e_bin, e_la, e_range, i0, i1, sorted_g, zs, zref, nbins, npx):
    """(Lb [nbins, npx], nb): sum of l per bin and pixel of the elements of instances i0:i1, and
    the number of bins in use (1 + the largest bin of an element; rows from nb on are 0).

    The bins (clamp(floor(zs - z_ref), 0, nbins - 1), in the dtype of ``zs``) are computed and
    stored in ``e_bin`` (the backward pass reads them: :func:`bin_and_grad_sums`).
    """
    Lb = np.zeros((nbins, npx))
    top = nbins - 1.0
    nb = 0
    for k in range(i0, i1):
        zk = zs[sorted_g[k]]
        for e in range(np.uint64(e_range[k, 0]), np.uint64(e_range[k, 1])):
            p = np.uint64(e_p[e])
            d = zk - zref[p]  # in the dtype of zs
            bn = int(min(d, top)) if d > 0.0 else 0  # clamp(floor(d), 0, top); 0 for NaN
            e_bin[e] = bn
            Lb[np.uint64(bn), p] += e_la[e]
            nb = max(nb, bn + 1)
    return Lb, nb


@njit(**JIT)
def bin_and_grad_sums(e_p, e_bin, e_la, e_range, i0, i1, sorted_g, gpar, gl, nbins, npx):
    """(Lb, Gt [nbins, npx], nb) of the backward pass from the stored bins: Lb as :func:`bin_sums`,
    and Gt = sum of (d loss / d w) l per bin and pixel, d loss / d w = gl[1] z + gl[2] cos2a +
    gl[3] sin2a at the element's pixel (``gl`` [4, npx], the upstream gradients of the tile):
    one loop over the elements for both tables, each summed in element order."""
    Lb, Gt = np.zeros((nbins, npx)), np.zeros((nbins, npx))
    nb = 0
    for k in range(i0, i1):
        if k + PREFETCH < i1:
            prefetch_row(gpar, sorted_g[k + PREFETCH])
        g = sorted_g[k]
        z, c, s = gpar[g, G_Z], gpar[g, G_C], gpar[g, G_S]
        for e in range(np.uint64(e_range[k, 0]), np.uint64(e_range[k, 1])):
            bn, p = np.uint64(e_bin[e]), np.uint64(e_p[e])
            la = e_la[e]
            Lb[bn, p] += la
            Gt[bn, p] += (gl[1, p] * z + gl[2, p] * c + gl[3, p] * s) * la
            nb = max(nb, e_bin[e] + 1)
    return Lb, Gt, nb


@njit(cache=True, inline="always")
def _expm1(L):
    """expm1(L) for L <= 0, branch free (Taylor series of degree 7 above -0.01)."""
    t = L * (1.0 + L * (0.5 + L * (1.0 / 6.0 + L * (1.0 / 24.0 + L * (1.0 / 120.0 + L * (1.0 / 720.0
                                                                                    + L * (1.0 / 5040.0)))))))
    return t if L > -0.01 else vexp(L) - 1.0


@njit(**JIT)
def weight_table(Lb, nb):
    """-M(b, p) = -exp(Lx) expm1(Lb) / Lb and E = expm1(Lb), each [nbins, npx] (vectorised over
    pixels; rows from ``nb`` on are not filled)."""
    nbins, npx = Lb.shape
    negM, Etab = np.empty((nbins, npx)), np.empty((nbins, npx))
    T = np.ones(npx)  # exp(Lx): transmittance in front of the bin
    for bb in range(nb):
        Lrow, Mrow, Erow = Lb[bb], negM[bb], Etab[bb]
        for p in range(npx):  # E first, in a loop of its own: fewer live constants (AVX2 has 16 registers)
            Erow[p] = _expm1(min(Lrow[p], -1e-7))
        for p in range(npx):
            L = Lrow[p]
            Lc = min(L, -1e-7)
            E = Erow[p]
            Mrow[p] = -(T[p] * (E / Lc))
            T[p] *= 1.0 + (E if Lc == L else L)  # expm1(L) = L to 5e-8 relative when |L| < 1e-7
    return negM, Etab


@njit(**JIT)
def gradient_table(Lb, nb, negM, Etab, Gt, g_logt):
    """H(b, p) = d loss / d Lb, [nbins, npx] (rows below ``nb``), given Gt = sum of (d loss / d w) l
    per bin and pixel and g_logt [npx] = d loss / d (sum l) (see
    :func:`vid2haircut.render.bins.gradient_table`)."""
    nbins, npx = Lb.shape
    H = np.empty((nbins, npx))
    behind = np.zeros(npx)  # d loss / d Lx from the bins behind
    for bb in range(nb - 1, -1, -1):
        _gradient_row(Lb[bb], Gt[bb], negM[bb], Etab[bb], H[bb], behind, g_logt)
    return H


@njit(cache=True, error_model="numpy", inline="never")
def _gradient_row(Lrow, Grow, Mrow, Erow, Hrow, behind, g_logt):
    """One bin row of :func:`gradient_table` (vectorised over pixels). A function of its own: inlined
    under the loop that runs over the rows backwards, LLVM left this loop scalar (measured with AVX2;
    a tile's table took 14 us instead of 9)."""
    for p in range(Lrow.shape[0]):
        L = Lrow[p]
        GM = Grow[p] * Mrow[p]
        Ls = min(L, -1e-2)
        R = L * (1.0 / 12.0) + 0.5 if L > -1e-2 else (Erow[p] + 1.0) / Erow[p] - 1.0 / Ls
        Hrow[p] = behind[p] + GM * R + g_logt[p]
        behind[p] += GM
