"""Window walk of the fused CPU compositor (numba): a screen tile's windows visited line by line.

A Gaussian's window runs along its major image axis u (x when ``horizontal``, else y;
:mod:`.footprint`). Inside a tile of L x L pixels (L = 16) it is visited one *line* at a time:
one pixel position v along the minor axis and all L pixels of the tile along u, evaluated as one
vector of L lanes (lane i is u = u0 + i): the window test, z_ref and the power are computed for
every lane, and the lanes inside the ellipse that the head does not hide are then appended to
the tile's element list. Where the CPU has AVX-512 or AVX2 a line is one call of
:func:`vid2haircut.render.numba_simd.line16` (explicit 16-lane vector code with compress or
permute instructions; :func:`~vid2haircut.render.numba_simd.line8`, 8 lanes, when the window's
lanes in the tile all lie in one half, about half the lines); elsewhere numba loops over the lanes and appends them with a branch-free
loop from the first to the last kept one (the same elements). A thin strand Gaussian crosses a tile
in a few lines (its minor extent), so the walk costs a few vector operations per line instead
of a loop of data-dependent length per pixel column, whose mispredicted exits were most of the
earlier per-column walk's time (measured, one thread, 4k strands at 256 x 256, z_ref and the
candidates: 64 ms per column, 31 ms by lines with compress stores, 41 ms with the loop, on an
Intel Xeon; on a 2-core AMD EPYC (Zen 4) the whole walk took 33 ms single-thread with the lane
loops and register compression, 19 ms with :func:`line16` and 16.5 ms without libm's ceil in
the window starts).

Because u is x for some Gaussians and y for others, z_ref and the head depth are kept per tile in
two layouts, row-major (lay 0: [v = y][u = x]) and transposed (lay 1: [v = x][u = y]), of
L x L pixels each; a Gaussian reads and writes the layout of its axis, and the two z_ref layouts
are combined after the walk. Element pixels are stored row-major with the tile's own width, as
the rest of the compositor (:mod:`.numba_kernels`) expects. Lane math runs in the dtype of the
Gaussian table (float32 or float64).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from vid2haircut.render.numba_math import lane_cast
from vid2haircut.render.numba_simd import line8, line16, prefetch_row
from vid2haircut.render.numba_windows import B_MISS, W_HGT, W_SLOPE, W_V0, box_fields, row_box, vstart32
from vid2haircut.render.numba_walk import PREFETCH

_INL = dict(cache=True, error_model="numpy", inline="always")
BIG = 1e12  # turns a positive depth gap (> 1e-12 m) into a head factor of 1 after clamping
FAR = 1 << 20  # window row bounds of lanes outside the window (no line lies between them)
# columns of the Gaussian table ``gpar`` [G, 8] (lane dtype)
G_MX, G_MY, G_QXX, G_QXY, G_QYY, G_Z, G_C, G_S = range(8)
# rows of the per-instance lane scratch ``lane`` [3, L]: u - mean u, q_uu du^2, 2 q_uv du
L_DU, L_QA, L_QB = range(3)


@njit(**_INL)
def _setup(g, lay, ua, ub, wint, wflt, gpar, x0, y0, L, lane, vlo, vhi):
    """Instance of Gaussian g in the tile, in layout ``lay`` with lanes ua..ub (tile relative; from
    its box code, :func:`.numba_windows.box_fields`): fills the lane arrays (``lane``, and vlo / vhi
    [L] int32: the window rows of each lane, tile relative; FAR / -FAR outside the window) and
    returns (mean v - tile v0, q_vv)."""
    if lay == 0:
        tu0, tv0 = x0, y0
        mu, mv, qu, qv = gpar[g, G_MX], gpar[g, G_MY], gpar[g, G_QXX], gpar[g, G_QYY]
    else:
        tu0, tv0 = y0, x0
        mu, mv, qu, qv = gpar[g, G_MY], gpar[g, G_MX], gpar[g, G_QYY], gpar[g, G_QXX]
    qxy = gpar[g, G_QXY]
    h = wint[g, W_HGT]
    sl, v0 = wflt[g, W_SLOPE], wflt[g, W_V0]
    mvr = mv - lane_cast(tv0, mv)
    # the lanes in int32 (vstart32; sums wrap as the int32 stores of the int64 sums did): the same window
    # rows wherever they lie within +-2^30, in a loop that LLVM vectorises without AVX-512DQ's
    # float <-> int64 conversions
    u0, ua32, ub32 = np.int32(tu0), np.int32(tu0 + ua), np.int32(tu0 + ub)
    tv032, hm1 = np.int32(tv0), np.int32(h - 1)
    for i in range(L):
        u = np.int32(u0 + np.int32(i))
        vs = np.int32(vstart32(sl, u, v0) - tv032)
        ok = (u >= ua32) & (u <= ub32)
        vlo[i] = vs if ok else np.int32(FAR)
        vhi[i] = np.int32(vs + hm1) if ok else np.int32(-FAR)
        d = lane_cast(u, mu) - mu
        lane[L_DU, i] = d
        lane[L_QA, i] = qu * d * d
        lane[L_QB, i] = (qxy + qxy) * d
    return mvr, qv


@njit(**_INL)
def load_head(head, has_head, b, x0, y0, width, height, L, hl):
    """hl [2 L L] (lane dtype): the tile's head depth in both layouts (+inf off the image or
    without a head)."""
    for a in range(L):
        for c in range(L):
            y, x = y0 + a, x0 + c
            v = head[b, y, x] if has_head and y < height and x < width else np.inf
            hl[np.uint64(a * L + c)] = v
            hl[np.uint64(L * L + c * L + a)] = v


@njit(**_INL)
def walk_lines(i0, i1, sorted_g, boxes, wint, wflt, gpar, zs, hl, consts, x0, x1, y0, y1, L, zref2, with_zref,
               lane, vlo, vhi, pw, hf, km, pix, elems, off, e_range, compress, live):
    """Walk the windows of instances i0:i1 line by line: z_ref over the whole windows into both
    layouts of ``zref2`` [2 L L] (when ``with_zref``; filled with +inf first), and the candidate
    elements into ``elems`` = (e_p, e_al, e_la)[off:off + n] (pixel, power, head factor), instance
    k's at e_range[k, 0]:e_range[k, 1]; returns n. ``boxes``: the instances' box codes
    (:func:`vid2haircut.render.numba_tiles.bin_windows`: each window's lines and lanes in its tile,
    worked out at binning), so that an instance whose window misses the tile, or (``live``) covers
    no live pixel, costs no read of its Gaussian's rows; or None: worked out here from the rows
    (:func:`vid2haircut.render.numba_windows.row_box`; the binned model walks every instance).

    Candidates are the window pixels inside the ellipse power > log(alpha_min) - 1e-3 that the
    head does not hide; alpha > alpha_min is then tested exactly by
    :func:`vid2haircut.render.numba_walk.alpha_and_l` (the few candidates that fail it stay, with
    alpha = l = 0: they add nothing). The element slots must hold the tile's window elements
    (:func:`vid2haircut.render.numba_walk.tile_bounds`) and 16 more: with ``compress`` a line's
    stores write up to 16 slots (the kept lanes, then zeros that the next line overwrites).
    ``lane`` [3, L], vlo / vhi / km / pix [L] int32, pw / hf [L] (lane dtype) are scratch (L = 16).
    ``compress``: evaluate each line with :func:`vid2haircut.render.numba_simd.line16` (explicit
    16-lane vector code packing the kept lanes with AVX-512 compress or AVX2 permutes; pass
    ``numba_simd.USE_LINE16``) instead of the loop over the lanes; the same elements either way.
    ``live``: None (the binned model's walk), or (the exact model's, :mod:`.numba_exact`) [2, L]
    uint32 bit masks of the tile's pixels still compositing in both layouts (live[0, y] bit x,
    live[1, x] bit y; tile relative): an instance whose window box (its lines by its lanes
    ua..ub) holds no live pixel is not walked (an empty range), nor is a line whose lanes hold
    none, and the lanes of stopped pixels are not kept (26% of the 1.39 M elements listed on the
    4k-strand frame before). The rows of instance k's Gaussian sorted_g[k] are read from ``wint``,
    ``wflt``, ``gpar`` and ``zs`` when it is walked, those of instance k + PREFETCH prefetched (also
    past ``i1``: the exact model walks a tile a few instances at a time).
    """
    tw = x1 - x0 + 1
    cut = lane_cast(math.log(consts[1]) - 1e-3, zs[0])  # power > cut: inside the ellipse
    logop = lane_cast(consts[0], zs[0])
    half, zero, one, big = (lane_cast(0.5, zs[0]), lane_cast(0.0, zs[0]), lane_cast(1.0, zs[0]),
                            lane_cast(BIG, zs[0]))
    if with_zref:
        for p in range(2 * L * L):
            zref2[p] = np.inf
    e_p, e_al, e_la = elems
    packed = live is not None
    n = off
    for k in range(i0, i1):
        e_range[k, 0] = n
        e_range[k, 1] = n
        if k + PREFETCH < sorted_g.shape[0]:  # a later instance's Gaussian's rows, fetched while this one is walked
            gn = sorted_g[k + PREFETCH]
            prefetch_row(gpar, gn)
            prefetch_row(wint, gn)
            prefetch_row(wflt, gn)
            prefetch_row(zs, gn)
        c = boxes[k] if boxes is not None else row_box(sorted_g[k], wint, wflt, x0, x1, y0, y1)
        if c == B_MISS:  # the window misses the tile
            continue
        lay, lo, hi, ua, ub, _h = box_fields(c)
        lanes0 = 0 if ub < 8 else (8 if ua >= 8 else -1)  # the lanes a line needs: 0-7, 8-15 or both (-1)
        umask = np.uint32(((1 << (ub + 1)) - 1) ^ ((1 << ua) - 1))  # bits ua..ub
        if packed:  # no live pixel in the window's box (its lines by its lanes): not walked
            hit = np.uint32(0)
            for r in range(lo, hi + 1):
                hit |= live[lay, r]
            if not hit & umask:
                continue
        g = sorted_g[k]
        mvr, qv = _setup(g, lay, ua, ub, wint, wflt, gpar, x0, y0, L, lane, vlo, vhi)
        z, zg = gpar[g, G_Z], zs[g]
        keep_any = qv > zero  # else degenerate: z_ref only
        # pixel index in the tile of lane i of line r: r * sr + i * si
        sr, si = (tw, 1) if lay == 0 else (1, tw)
        for r in range(lo, hi + 1):
            on = np.uint32(0xFFFFFFFF)  # the lanes that may be kept
            if packed:
                on = live[lay, r]
                if not on & umask:  # no live pixel in the line's lanes
                    continue
            rr = np.int32(r)
            dv = lane_cast(r, mvr) - mvr
            base = np.uint64((lay * L + r) * L)
            pr = r * sr
            if compress:  # AVX-512 / AVX2: the line as explicit vector code, the same result as the loops
                if lanes0 >= 0:  # the window's lanes all in one half: 8 lanes (line16's work halved)
                    n += line8(lane[L_QA], lane[L_QB], vlo, vhi, hl, zref2, with_zref, zg, base, rr, dv, qv, logop,
                               half, cut, z, big, keep_any, np.int32(pr), np.int32(si), e_al, e_la, e_p,
                               np.uint64(n), on, np.uint64(lanes0))
                else:
                    n += line16(lane[L_QA], lane[L_QB], vlo, vhi, hl, zref2, with_zref, zg, base, rr, dv, qv, logop,
                                half, cut, z, big, keep_any, np.int32(pr), np.int32(si), e_al, e_la, e_p, np.uint64(n),
                                on)
                continue
            if with_zref:
                for i in range(L):
                    ii = np.uint64(i)
                    zr = zref2[base + ii]
                    zref2[base + ii] = zg if (rr >= vlo[ii]) & (rr <= vhi[ii]) & (zg < zr) else zr
            ifirst, ilast = np.int32(L), np.int32(-1)
            for i in range(L):
                ii = np.uint64(i)
                p = logop - half * (lane[L_QA, ii] + dv * (lane[L_QB, ii] + qv * dv))
                f = min(max((hl[base + ii] - z) * big, zero), one)  # head factor: 0 where the head is in front
                kept = ((rr >= vlo[ii]) & (rr <= vhi[ii]) & (p > cut) & keep_any & (f > zero)
                        & ((on >> np.uint32(i)) & np.uint32(1) != 0))
                pw[ii] = p
                hf[ii] = f
                km[ii] = np.int32(kept)
                pix[ii] = np.int32(pr + i * si)
                ifirst = min(ifirst, np.int32(i)) if kept else ifirst
                ilast = max(ilast, np.int32(i)) if kept else ilast
            for i in range(ifirst, ilast + 1):  # branch free over the lanes from the first to the last kept one
                ii = np.uint64(i)
                nu = np.uint64(n)
                e_p[nu] = pix[ii]
                e_al[nu] = pw[ii]
                e_la[nu] = hf[ii]
                n += km[ii]
        e_range[k, 1] = n
    return n - off


@njit(**_INL)
def fold_zref(zref2, zref, x1, x0, y1, y0, L):
    """zref [npx] (row-major, the tile's width) := the smaller of the two layouts of ``zref2``."""
    tw = x1 - x0 + 1
    for a in range(y1 - y0 + 1):
        for c in range(tw):
            zref[np.uint64(a * tw + c)] = min(zref2[np.uint64(a * L + c)], zref2[np.uint64(L * L + c * L + a)])
