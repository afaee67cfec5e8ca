"""Per-tile building blocks of the fused CPU compositor (numba): window walk, depth bins, bin tables.

See :mod:`vid2haircut.render.numba_kernels` for the model and the pass structure. A tile's
elements (contributions with alpha > 0) are kept in flat arrays at the tile's offset, instance
by instance (instance k's at e_range[k, 0]:e_range[k, 1]): pixel (index inside the tile), depth
bin, alpha and l = log(1 - alpha).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from vid2haircut.render.numba_math import vexp, vlog
from vid2haircut.render.numba_tiles import W_HGT, W_HZ, W_NCOL, W_SLOPE, W_ULO, W_V0, vstart

JIT = dict(cache=True, error_model="numpy")
BIG = 1e12  # turns a positive depth gap (> 1e-12 m) into a head factor of 1 after clamping
# columns of the float64 Gaussian table ``gpar`` [G, 8]
G_MX, G_MY, G_QXX, G_QXY, G_QYY, G_Z, G_C, G_S = range(8)
# entries of ``consts``: log opacity, alpha_min, alpha_max
C_LOGOP, C_AMIN, C_AMAX = range(3)


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


@njit(**JIT)
def _window_cols(g, wint, x0, x1, y0, y1):
    """Whether u = x, the columns ua..ub of window g inside the tile and the tile's v range."""
    hz = wint[g, W_HZ] != 0
    tu0, tu1, tv0, tv1 = (x0, x1, y0, y1) if hz else (y0, y1, x0, x1)
    ua = max(wint[g, W_ULO], tu0)
    ub = min(wint[g, W_ULO] + wint[g, W_NCOL] - 1, tu1)
    return hz, ua, ub, tv0, tv1


@njit(cache=True, parallel=True, error_model="numpy")
def tile_bounds(tile_start, sorted_g, wint, width, height, tile):
    """[NT] upper bound of each tile's element count (its window elements)."""
    NT = tile_start.shape[0] - 1
    bounds = np.zeros(NT, np.int64)
    for t in prange(NT):
        b, x0, x1, y0, y1 = tile_box(t, width, height, tile)
        cap = 0
        for k in range(tile_start[t], tile_start[t + 1]):
            g = sorted_g[k]
            hz, ua, ub, tv0, tv1 = _window_cols(g, wint, x0, x1, y0, y1)
            if ub >= ua:
                cap += (ub - ua + 1) * min(wint[g, W_HGT], tv1 - tv0 + 1)
        bounds[t] = cap
    return bounds


@njit(**JIT)
def walk(i0, i1, sorted_g, wint, wflt, gpar, zs, hloc, has_head, consts, x0, x1, y0, y1, zref, with_zref,
         e_p, e_al, e_la, off, e_range):
    """Walk the windows of instances i0:i1: z_ref over the whole windows (when ``with_zref``), and
    the elements with alpha > 0 into e_*[off:off + n], instance k's at e_range[k, 0]:e_range[k, 1];
    returns n.

    Elements are kept in the rows of each column inside the ellipse power > log(alpha_min) - 1e-3
    (roots of the quadratic) that the head does not hide; alpha > alpha_min is then tested
    exactly (the few elements that fail it stay, with alpha = l = 0: they add nothing). The
    element slots must hold the window elements (:func:`tile_bounds`): every window row is
    written once before the slot pointer decides whether it stays.
    """
    tw = x1 - x0 + 1
    log_op, amin, amax = consts[C_LOGOP], consts[C_AMIN], consts[C_AMAX]
    c2 = 2.0 * (log_op - (math.log(amin) - 1e-3))  # power > cut  <=>  quadratic form < c2
    n = off
    for k in range(i0, i1):
        e_range[k, 0] = n
        e_range[k, 1] = n
        g = sorted_g[k]
        hz, ua, ub, tv0, tv1 = _window_cols(g, wint, x0, x1, y0, y1)
        h, sl, v0, zg = wint[g, W_HGT], wflt[g, W_SLOPE], wflt[g, W_V0], zs[g]
        z, qxy = gpar[g, G_Z], gpar[g, G_QXY]
        if hz:  # u = x, v = y; pixel index in the tile = u * su + v * sv + off_p
            mu, mv, qu, qv, su, sv = gpar[g, G_MX], gpar[g, G_MY], gpar[g, G_QXX], gpar[g, G_QYY], 1, tw
        else:
            mu, mv, qu, qv, su, sv = gpar[g, G_MY], gpar[g, G_MX], gpar[g, G_QYY], gpar[g, G_QXX], tw, 1
        ok = qv > 0.0  # else degenerate: z_ref only
        iqv = 1.0 / qv if ok else 0.0
        slope_c = qxy * iqv
        off_p = -(y0 * tw + x0)
        for u in range(ua, ub + 1):
            vs = vstart(sl, u, v0)
            va, vb = max(vs, tv0), min(vs + h - 1, tv1)
            if vb < va:
                continue
            pu = u * su + off_p
            du = u - mu
            disc = (qxy * du) ** 2 - qv * (qu * du * du - c2)
            lo, hi = vb + 1, vb  # ellipse rows of the column (empty unless disc > 0)
            if disc > 0.0 and ok:
                r = math.sqrt(disc) * iqv
                cen = mv - slope_c * du
                lo = int(math.ceil(max(cen - r, va)))
                hi = int(math.floor(min(cen + r, vb)))
            qa = qu * du * du
            qb = 2.0 * qxy * du
            # branch free over the window rows (only the ellipse rows without z_ref): every row
            # updates z_ref and is written as a candidate at slot n, which only advances for
            # ellipse rows the head does not hide (unsigned indices: no wraparound code)
            for v in range(va if with_zref else lo, (vb if with_zref else hi) + 1):
                i = np.uint64(pu + v * sv)
                if with_zref:
                    zref[i] = min(zref[i], zg)
                hf = 1.0  # head factor: 0 where the head is in front
                if has_head:
                    hf = min(max((hloc[i] - z) * BIG, 0.0), 1.0)
                dv = v - mv
                nu = np.uint64(n)
                # candidate: power in e_al, head factor in e_la (alpha and l follow in one vector loop)
                e_p[nu], e_al[nu], e_la[nu] = pu + v * sv, log_op - 0.5 * (qa + qb * dv + qv * dv * dv), hf
                n += 1 if (v >= lo and v <= hi and hf > 0.0) else 0
        e_range[k, 1] = n
    _alpha_and_l(e_al[off:n], e_la[off:n], amin, amax)
    return n - off


@njit(**JIT)
def _alpha_and_l(pw, hf, amin, amax):
    """In place: power -> alpha = min(exp(power), alpha_max) if > alpha_min else 0, times the head
    factor; head factor -> l = log(1 - alpha). A branch-free loop that LLVM vectorises."""
    for i in range(pw.shape[0]):
        al = min(vexp(pw[i]), amax)
        al = (al if al > amin else 0.0) * hf[i]
        pw[i] = al
        hf[i] = vlog(1.0 - al)


@njit(**JIT)
def bin_sums(e_p, e_bin, e_la, e_range, i0, i1, sorted_g, zs, zref, nbins, npx, assign):
    """(Lb [nbins, npx], nb): sum of l per bin and pixel of the elements of instances i0:i1, and
    the number of bins in use (1 + the largest bin of an element; rows from nb on are 0).

    With ``assign`` the bins are computed first (clamp(floor(zs - z_ref), 0, nbins - 1), in the
    dtype of ``zs``) and stored in ``e_bin``; otherwise the stored bins are used.
    """
    Lb = np.zeros((nbins, npx))
    top = nbins - 1.0
    nb = 0
    for k in range(i0, i1):
        if assign:
            zk = zs[sorted_g[k]]
            for e in range(np.uint64(e_range[k, 0]), np.uint64(e_range[k, 1])):
                p = np.uint64(e_p[e])
                bn = int(min(max(zk - zref[p], 0.0), top))  # zk - z_ref in the dtype of zs
                e_bin[e] = bn
                Lb[np.uint64(bn), p] += e_la[e]
                nb = max(nb, bn + 1)
        else:
            for e in range(np.uint64(e_range[k, 0]), np.uint64(e_range[k, 1])):
                bn = e_bin[e]
                Lb[np.uint64(bn), np.uint64(e_p[e])] += e_la[e]
                nb = max(nb, bn + 1)
    return Lb, nb


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
        for p in range(npx):
            L = Lrow[p]
            Lc = min(L, -1e-7)
            E = _expm1(Lc)
            Mrow[p] = -(T[p] * (E / Lc))
            Erow[p] = E
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
        Lrow, Grow, Mrow, Erow, Hrow = Lb[bb], Gt[bb], negM[bb], Etab[bb], H[bb]
        for p in range(npx):
            L = Lrow[p]
            GM = Grow[p] * Mrow[p]
            Ls = min(L, -1e-2)
            R = L * (1.0 / 12.0) + 0.5 if L > -1e-2 else (Erow[p] + 1.0) / Erow[p] - 1.0 / Ls
            Hrow[p] = behind[p] + GM * R + g_logt[p]
            behind[p] += GM
    return H
