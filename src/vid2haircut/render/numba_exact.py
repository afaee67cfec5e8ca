"""Exact front-to-back compositing with early termination (numba), ``compositing="exact"``.

The alternative to the depth-binned model of :mod:`.numba_kernels`. The Gaussians reach these
kernels numbered in depth order (:func:`vid2haircut.render.numba_backend.composite_fused` sorts
them, :mod:`.numba_records`), so each tile's instance list (:mod:`.numba_tiles`, Gaussian order inside a tile) is its
front-to-back order, and every pixel's contributions arrive sorted by their Gaussian's depth, as
in the per-pixel reference (tests/render_reference.py). Per tile, forward
(:func:`composite_exact_forward`): the windows are walked a few instances at a time
(:func:`.numba_lines.walk_lines`, without z_ref), then each element (pixel p, alpha) in that
order: w = alpha T(p), T(p) := T(p) (1 - alpha), the sums of w z, w cos2a, w sin2a at p, the
largest w of its instance (visibility). A pixel stops compositing once T(p) < ``t_min`` (its
later elements together weigh less than t_min: the silhouette is short by less than t_min, the
sum of w z by less than t_min times the largest depth), and a tile stops walking once all its
pixels have stopped (so a tile with a pixel that no window covers walks to its end). Before that,
the walk skips what only covers stopped pixels: the tile keeps bit masks of its live pixels per
row and per column, and an instance whose box of window lines and lanes holds no live pixel, or a
line of it whose lanes hold none, is not walked (:func:`.numba_lines.walk_lines`; the same
results, as the compositing skips such elements anyway; on the 4k-strand benchmark frame the
instances with elements fall from 132,445 to 81,730 and the elements listed from 2.52 M to 1.39 M).
The kernels read each instance's Gaussian rows through ``sorted_g``, prefetched a few instances
ahead (:data:`.numba_walk.PREFETCH`; a copy of the rows per instance in tile order, written by the
binning, cost more than it saved: binning 4.4 -> 2.9 ms, forward and backward +0.8 ms without it),
from one 64-byte record per Gaussian (:mod:`.numba_records`: its row, depth and window in one
cache line, filled in depth order, each window computed on the way with the rows it needs), and
only for instances whose box code (:func:`.numba_windows.box_code`, worked out at
binning) covers a live pixel.
The log transmittance log T(p) and the silhouette 1 - T(p) are outputs.

Backward (:func:`composite_exact_backward`), from the kept elements in the same order: with
q = d loss / d w = g_z z + g_c cos2a + g_s sin2a at the element's pixel, Q(p) = sum of w q over
the pixel (from the forward's float64 sums) and R = what the elements behind it add to it,
d loss / d alpha = T q - (R + g_logT) / (1 - alpha); then d loss / d power = that times
d alpha / d power (alpha, 0 where clamped), and the per-instance moments of
:func:`.numba_kernels.composite_backward` (reduced by :func:`.numba_kernels.reduce_gradients`).
The walk lists no lane of a pixel stopped before its chunk of instances (366k of the 1.39 M
elements it listed before on the 4k-strand frame), and the forward pass keeps only the elements it
composited (moved down in place over those whose pixel stopped within the chunk), so the backward
pass walks exactly those, without a test per element, and recomputes the same T sequence with the
same operations.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from vid2haircut.render.numba_kernels import N_ACC, _pixel_xy, walk_scratch
from vid2haircut.render.numba_lines import load_head, walk_lines
from vid2haircut.render.numba_math import lane_cast, lane_exp
from vid2haircut.render.numba_simd import prefetch_row
from vid2haircut.render.numba_walk import C_AMAX, C_AMIN, G_C, G_MX, G_MY, G_S, G_Z, PREFETCH, tile_box

_PAR = dict(cache=True, parallel=True, error_model="numpy")
CHUNK = 8
"""Instances walked before their elements are composited (and the tile's stop is checked)."""
T_MIN = 1e-4
"""Default transmittance below which a pixel stops compositing."""


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def alpha_and_slope(pw, hf, amin, amax):
    """In place: power -> alpha = min(exp(power), alpha_max) if > alpha_min else 0, times the head
    factor; head factor -> d alpha / d power (alpha; 0 where alpha is clamped to alpha_max).
    Branch free, vectorised by LLVM in the arrays' dtype."""
    if pw.shape[0] == 0:
        return
    lo, hi, zero = lane_cast(amin, pw[0]), lane_cast(amax, pw[0]), lane_cast(0.0, pw[0])
    for i in range(pw.shape[0]):
        al = min(lane_exp(pw[i]), hi)
        al = (al if al > lo else zero) * hf[i]
        pw[i] = al
        hf[i] = al if al < hi else zero


@njit(**_PAR)
def composite_exact_forward(gpar, zs, wint, wflt, head, has_head, consts, shade, tile_start, sorted_g, boxes,
                            work_start, work_tiles, width, height, tile, offsets, elems, e_range, out, sums,
                            t_end, vis_weight, visible, compress, t_min, order, tile_kept):
    """Forward compositing of all tiles, front to back.

    Args:
        gpar, zs, wint, wflt: the Gaussians' tables (:func:`.numba_tiles.bin_windows`; zs the
            depths, gpar's column 5), the Gaussians numbered front to back.
        head, has_head, consts, tile_start, sorted_g, boxes, work_start, work_tiles, width, height,
            tile, offsets, e_range, vis_weight, visible, compress: as for
            :func:`.numba_kernels.composite_forward` (``consts``' second-silhouette ratio unused;
            sorted_g gives the Gaussian whose visibility an instance sets).
        shade: composite depth and direction (else the log transmittance only).
        elems: (pixel int32, alpha, d alpha / d power (input dtype)) element arrays, filled with
            the composited elements only (e_range: each instance's; the instances a tile did not
            walk get empty ranges).
        out: (log T [B, H, W], silhouette 1 - T [B, H, W], sum w z [B, H, W], (sum w cos2a,
            sum w sin2a) [B, H, W, 2]) zeros in the input dtype, filled (the last two with ``shade``
            only); the silhouette computed here in float64 from T (in place of torch's -expm1(log T)
            on the rounded log T, and its autograd node: 0.3 ms less per 256 x 256 frame).
        sums: [B, H, W, 3] float64, the three sums unrounded (with ``shade``; the backward pass's
            Q), and t_end: [B, H, W] float64, T at the end, both filled in the tiles with instances
            (the only ones the backward pass reads).
        t_min: transmittance below which a pixel stops.
        order: [G] int64, the caller's index of each Gaussian (numbered here in depth order):
            ``visible`` is set at order[g], in the caller's order (after the tiles, in a pass of its
            own: the random read of order[g] per visible instance was 3% of the kernel's time).
        tile_kept: [NT] int64 zeros, filled with each tile's count of instances with elements (the
            backward pass gives only those a row of sums, :func:`composite_exact_backward`).
    """
    e_p, e_al, e_da = elems
    o_l, o_w, o_z, o_d = out
    L = tile
    amin, amax = consts[C_AMIN], consts[C_AMAX]
    vis = np.zeros(gpar.shape[0], np.bool_)  # visibility in depth order: no random read of ``order`` per instance
    for wk in prange(work_start.shape[0] - 1):
        scratch = walk_scratch(L, zs)
        hl, zref2, lane, pw, hf, vlo, vhi, km, pix = scratch
        for j in range(work_start[wk], work_start[wk + 1]):
            t = work_tiles[j]
            b, x0, x1, y0, y1 = tile_box(t, width, height, tile)
            load_head(head, has_head, b, x0, y0, width, height, L, hl)
            tw = x1 - x0 + 1
            npx = tw * (y1 - y0 + 1)
            T = np.ones(npx)
            acc = np.zeros((npx, 3))  # (pixel-major: one base address in the element loop, not three)
            live = npx
            th = y1 - y0 + 1
            lm = np.zeros((2, L), np.uint32)  # the live pixels' bits in both layouts (walk_lines)
            lm[0, :th] = np.uint32((1 << tw) - 1)
            lm[1, :tw] = np.uint32((1 << th) - 1)
            n = offsets[t]
            i0, i1 = tile_start[t], tile_start[t + 1]
            k = i0
            kept = 0
            while k < i1:
                if live == 0:  # every pixel has stopped: the rest of the tile is not walked
                    for kk in range(k, i1):
                        e_range[kk, 0] = n
                        e_range[kk, 1] = n
                    break
                kb = min(k + CHUNK, i1)
                m = walk_lines(k, kb, sorted_g, boxes, wint, wflt, gpar, zs, hl, consts, x0, x1, y0, y1, L, zref2,
                               False, lane, vlo, vhi, pw, hf, km, pix, elems, n, e_range, compress, lm)
                alpha_and_slope(e_al[n:n + m], e_da[n:n + m], amin, amax)
                o = np.uint64(n)  # the composited elements, moved down over the skipped ones
                for kk in range(k, kb):
                    e0, e1 = np.uint64(e_range[kk, 0]), np.uint64(e_range[kk, 1])
                    e_range[kk, 0] = o
                    if e1 == e0:  # (no row to read)
                        e_range[kk, 1] = o
                        continue
                    gk = sorted_g[kk]
                    z, c, s = gpar[gk, G_Z], gpar[gk, G_C], gpar[gk, G_S]
                    mw = 0.0
                    for e in range(e0, e1):
                        p = np.uint64(e_p[e])
                        tp = T[p]
                        if tp >= t_min:
                            a = e_al[e]
                            e_p[o] = e_p[e]
                            e_al[o] = a
                            e_da[o] = e_da[e]
                            o += np.uint64(1)
                            w = a * tp
                            tn = tp * (1.0 - a)
                            T[p] = tn
                            if tn < t_min:  # the pixel stops
                                live -= 1
                                yy = p // np.uint64(tw)
                                xx = p - yy * np.uint64(tw)
                                lm[0, yy] &= ~np.uint32(1 << xx)
                                lm[1, xx] &= ~np.uint32(1 << yy)
                            if shade:
                                acc[p, 0] += w * z
                                acc[p, 1] += w * c
                                acc[p, 2] += w * s
                                mw = max(mw, w)
                    e_range[kk, 1] = o
                    kept += np.int64(o > e_range[kk, 0])
                    if mw >= vis_weight:
                        vis[gk] = True
                n = np.int64(o)  # the next instances' elements follow the kept ones
                k = kb
            tile_kept[t] = kept
            p = 0
            for y in range(y0, y1 + 1):
                for x in range(x0, x1 + 1):
                    o_l[b, y, x] = np.log(T[p])
                    o_w[b, y, x] = 1.0 - T[p]
                    t_end[b, y, x] = T[p]
                    if shade:
                        o_z[b, y, x] = acc[p, 0]
                        o_d[b, y, x, 0] = acc[p, 1]
                        o_d[b, y, x, 1] = acc[p, 2]
                        sums[b, y, x, 0] = acc[p, 0]
                        sums[b, y, x, 1] = acc[p, 1]
                        sums[b, y, x, 2] = acc[p, 2]
                    p += 1
    for g in prange(vis.shape[0]):  # into the caller's order
        if vis[g]:
            visible[order[g]] = True


@njit(**_PAR)
def composite_exact_backward(gpar, shade, tile_start, sorted_g, work_start, work_tiles, width, height, tile, elems,
                             e_range, grad, sums, t_end, acc, acc_start, inst_csr, slot):
    """Backward compositing of all tiles from the elements kept by :func:`composite_exact_forward`
    (every one of them composited).

    Args:
        grad: the upstream gradients (log T, silhouette, sum w z, direction sums) in the table's
            dtype (summed in float64; the last two read with ``shade`` only); sums, t_end: the
            forward's; acc: [n, 8] filled (see :data:`.numba_kernels.N_ACC`), one row per instance
            with elements (n of them), tile t's from row acc_start[t] on (the forward's tile_kept,
            summed), in instance order; inst_csr: [n_instances] each instance's position in the
            Gaussian order (:func:`.numba_tiles.bin_windows`); slot: [n_instances] int32 -1,
            indexed by that position, where each instance with elements gets its row (the reduction,
            :func:`.numba_kernels.reduce_gradients`, then reads its slots in order: read by
            instance, they were one random read each, 1/5 of its time). Rows for the 2/3 of the
            instances without elements (4k strands at 256 x 256) would cost their writes here and
            their reads in the reduction. The rest as given to the forward kernel.
    """
    e_p, e_al, e_da = elems
    g_l, g_w, g_z, g_d = grad
    for wk in prange(work_start.shape[0] - 1):
        for j in range(work_start[wk], work_start[wk + 1]):
            t = work_tiles[j]
            b, x0, x1, y0, y1 = tile_box(t, width, height, tile)
            px, py = _pixel_xy(x0, x1, y0, y1)
            npx = px.shape[0]
            gl = np.zeros((4, npx))
            Q = np.zeros(npx)  # what the elements not yet visited add to sum w q
            for p in range(npx):
                y, x = int(py[p]), int(px[p])
                gl[0, p] = g_l[b, y, x] - g_w[b, y, x] * t_end[b, y, x]  # d loss / d log T
                if shade:
                    gl[1, p] = g_z[b, y, x]
                    gl[2, p] = g_d[b, y, x, 0]
                    gl[3, p] = g_d[b, y, x, 1]
                    Q[p] = gl[1, p] * sums[b, y, x, 0] + gl[2, p] * sums[b, y, x, 1] + gl[3, p] * sums[b, y, x, 2]
            T = np.ones(npx)
            k1 = tile_start[t + 1]
            r = acc_start[t]
            for k in range(tile_start[t], k1):
                kp = k + PREFETCH  # a later instance's Gaussian row, if it has elements (the table outgrows L2)
                if kp < k1 and e_range[kp, 1] > e_range[kp, 0]:
                    prefetch_row(gpar, sorted_g[kp])
                if e_range[k, 1] == e_range[k, 0]:  # no element (most instances): no row to read or write
                    continue
                gk = sorted_g[k]
                z, c, s = gpar[gk, G_Z], gpar[gk, G_C], gpar[gk, G_S]
                mx, my = gpar[gk, G_MX], gpar[gk, G_MY]
                s0 = s1 = s2 = s3 = s4 = sz = sc = ss = 0.0
                for e in range(np.uint64(e_range[k, 0]), np.uint64(e_range[k, 1])):
                    p = np.uint64(e_p[e])
                    tp = T[p]
                    a = e_al[e]
                    om = 1.0 - a
                    w = a * tp
                    T[p] = tp * om
                    q = gl[1, p] * z + gl[2, p] * c + gl[3, p] * s  # d loss / d w
                    Q[p] -= w * q  # now: what the elements behind this one add
                    gp = (tp * q - (Q[p] + gl[0, p]) / om) * e_da[e]
                    if shade:
                        sz += gl[1, p] * w
                        sc += gl[2, p] * w
                        ss += gl[3, p] * w
                    dx, dy = px[p] - mx, py[p] - my
                    s0 += gp * dx
                    s1 += gp * dy
                    s2 += gp * dx * dx
                    s3 += gp * dx * dy
                    s4 += gp * dy * dy
                acc[r, 0], acc[r, 1], acc[r, 2], acc[r, 3], acc[r, 4] = s0, s1, s2, s3, s4
                acc[r, 5], acc[r, 6], acc[r, 7] = sz, sc, ss
                slot[inst_csr[k]] = r
                r += 1


__all__ = ["composite_exact_forward", "composite_exact_backward", "alpha_and_slope", "T_MIN", "CHUNK", "N_ACC"]
