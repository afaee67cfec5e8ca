"""Fused CPU compositing kernels (numba): the compositing model of :mod:`.kernels` in a few loops.

Same contributions, same depth bins, same weights as the torch kernels (see
:mod:`vid2haircut.render.raster` for the model): a contribution of Gaussian g at pixel p of its
window has power = log opacity - (q_xx dx^2 + 2 q_xy dx dy + q_yy dy^2) / 2, alpha =
min(exp(power), alpha_max) kept when > alpha_min, times the head factor clamp((head(p) - z) 1e12,
0, 1); l = log(1 - alpha); bin = clamp(floor(zs - z_ref(p)), 0, bins - 1) with zs = z / depth_bin
in the input dtype and z_ref(p) the smallest zs of the windows covering p; w = -M(p, bin) l.

Work is split by screen tile (:mod:`.numba_tiles`): one thread composites a whole tile, with all
per-pixel tables private to it, so there are no atomics and no write races (but for the visibility
flags, which are only ever set to True), and every sum runs in a fixed order (instances of a tile by
Gaussian index, elements in window order, per-instance results reduced per Gaussian in instance
order): results do not depend on the number of threads.
Per tile, forward (:func:`composite_forward`):

 1. one walk of the windows, line by line (:func:`.numba_lines.walk_lines`): z_ref over every
    window pixel, and the elements (ellipse pixels not hidden by the head) with their power; then
    alpha, l and d l / d power in one vectorised loop (:func:`.numba_walk.alpha_and_l`; both in
    :func:`walk_tile`);
 2. bins and Lb(b, p) = sum of l per (bin, pixel);
 3. -M(b, p) = -exp(Lx) expm1(Lb) / Lb (:func:`vid2haircut.render.bins.weight_table`);
 4. w = -M l; per pixel sums of w z, w cos2a, w sin2a; the largest w of each instance, and the
    Gaussian marked visible when it reaches ``vis_weight``.

The elements (pixel, bin, d l / d power, l) stay in flat arrays at per-tile offsets (sized by the tile's
window element count, an upper bound; about 40% is used), and the backward pass
(:func:`composite_backward`) starts from them: A. Lb again (same order, same values) and
G(b, p) = sum of q l with q = dL/dw, in one loop over the elements
(:func:`.numba_walk.bin_and_grad_sums`: G needs no weights), then -M; B. dL/dLb
(:func:`vid2haircut.render.bins.gradient_table`); C. per element dL/dpower and per instance its
moments sum gp (dx, dy, dx^2, dx dy, dy^2) and dL/dz, dL/dc, dL/ds, turned into dL/d(mean, conic) by
:func:`reduce_gradients`. Per-element values have the input dtype, internal sums are float64;
outputs have the input dtype.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from vid2haircut.render.numba_lines import fold_zref, load_head, walk_lines
from vid2haircut.render.numba_simd import prefetch_row
from vid2haircut.render.numba_walk import (C_AMAX, C_AMIN, C_RATIO, G_C, G_MX, G_MY, G_QXX, G_QXY, G_QYY, G_S, G_Z, JIT,
                                           alpha_and_l, alpha_and_l2, bin_and_grad_sums, bin_sums, gradient_table,
                                           tile_box, weight_table)

GATHER_AHEAD = 16
"""How many rows ahead the gathers of scattered rows prefetch (:func:`reduce_gradients`: the
instances of Gaussian g + 16, 16 and 32 measured alike, 8 slower; :mod:`.numba_records`)."""
N_ACC = 8  # per-instance accumulators: sum gp dx, gp dy, gp dx^2, gp dx dy, gp dy^2, dL/dz, dL/dc, dL/ds
_PAR = dict(cache=True, parallel=True, error_model="numpy")


@njit(**JIT)
def _pixel_xy(x0, x1, y0, y1):
    """Pixel coordinates (x, y) [npx] of the tile's pixels, row-major."""
    tw = x1 - x0 + 1
    npx = tw * (y1 - y0 + 1)
    px, py = np.empty(npx), np.empty(npx)
    p = 0
    for y in range(y0, y1 + 1):  # rows and columns: no division per pixel
        for x in range(x0, x1 + 1):
            px[p] = x
            py[p] = y
            p += 1
    return px, py


@njit(cache=True, error_model="numpy", inline="always")
def walk_scratch(L, zs):
    """Per-worker scratch of :func:`walk_tile` for tiles of L x L pixels (lane dtype: that of ``zs``):
    (head depth and z_ref, each in two layouts [2 L L], lane terms [3, L], power and head factor
    [L], window rows, kept lanes and their pixels [L] int32)."""
    dt = zs.dtype
    i32 = np.int32
    return (np.empty(2 * L * L, dt), np.empty(2 * L * L, dt), np.empty((3, L), dt), np.empty(L, dt), np.empty(L, dt),
            np.empty(L, i32), np.empty(L, i32), np.empty(L, i32), np.empty(L, i32))


@njit(cache=True, error_model="numpy", inline="always")
def walk_tile(t, scratch, gpar, zs, wint, wflt, head, has_head, consts, with_zref, tile_start, sorted_g, boxes, width,
              height, tile, offsets, elems, e_range, compress):
    """Step 1 of :func:`composite_forward` for tile ``t``: walk its windows (z_ref into ``scratch[1]``
    when ``with_zref``), listing its elements at ``offsets[t]``, and turn their power into d l / d
    power and l (and the second silhouette's, when ``consts`` has one).

    Returns:
        (frame, x0, x1, y0, y1 (the tile's inclusive pixel bounds), first element slot, element count).
    """
    hl, zref2, lane, pw, hf, vlo, vhi, km, pix = scratch
    e_p, e_bin, e_al, e_la, e_dl2, e_la2 = elems
    b, x0, x1, y0, y1 = tile_box(t, width, height, tile)
    L = tile
    load_head(head, has_head, b, x0, y0, width, height, L, hl)
    off = offsets[t]
    n = walk_lines(tile_start[t], tile_start[t + 1], sorted_g, boxes, wint, wflt, gpar, zs, hl, consts, x0, x1, y0,
                   y1, L, zref2, with_zref, lane, vlo, vhi, pw, hf, km, pix, (e_p, e_al, e_la), off, e_range, compress,
                   None)
    if consts[C_RATIO] > 0.0:
        alpha_and_l2(e_al[off:off + n], e_la[off:off + n], consts[C_AMIN], consts[C_AMAX], consts[C_RATIO],
                     e_dl2[off:off + n], e_la2[off:off + n])
    else:
        alpha_and_l(e_al[off:off + n], e_la[off:off + n], consts[C_AMIN], consts[C_AMAX])
    return b, x0, x1, y0, y1, off, n


@njit(**_PAR)
def composite_forward(gpar, zs, wint, wflt, head, has_head, consts, nbins, tile_start, sorted_g, boxes,
                      work_start, work_tiles, width, height, tile, offsets, elems, e_range, out, vis_weight, visible,
                      compress):
    """Forward compositing of all tiles.

    Args:
        gpar: [G, 8] (mean x, mean y, q_xx, q_xy, q_yy, z, cos2a, sin2a) in the input dtype, the
            lane dtype of the walk and of alpha and l. zs: [G] z / depth_bin (same dtype). wint,
            wflt: window tables (:mod:`.numba_windows`). head: [B, H, W] head depth (same dtype;
            used when ``has_head``). consts: [4] (log opacity, alpha_min, alpha_max, the second
            silhouette's opacity over the first's: 0 for none).
        nbins: depth bins (1: silhouette only). tile_start, sorted_g, boxes: instances per tile
            (:func:`.numba_tiles.bin_windows`);
        work_start, work_tiles: tiles per worker (:func:`.numba_tiles.assign_tiles`).
        offsets: [NT] first element slot of each tile (bounds from :func:`.numba_walk.tile_bounds`).
        elems: (pixel int32, bin int32, d l / d power, l, d l2 / d power, l2 (input dtype))
            element arrays, filled (the last two: the second silhouette's, empty without one).
        e_range: [n_instances, 2] filled with the element range of each instance.
        out: (sum l [B, H, W], sum w z [B, H, W], (sum w cos2a, sum w sin2a) [B, H, W, 2], sum l2
            [B, H, W]) zeros in the input dtype, filled (separate arrays: each becomes one output
            of the autograd function, with no slicing in its graph); without shading the second
            and third, without a second silhouette the last, are not written (may be empty).
        vis_weight, visible: [G] bool, False on entry; set True for a Gaussian when the largest
            weight of one of its instances reaches ``vis_weight`` (with shading only). Only True
            is ever stored, by whichever thread composites the instance's tile: the same value
            for any thread count and order (the one shared write of these kernels).
        compress: the walk's compaction (:func:`.numba_lines.walk_lines`; only with ``tile`` 16).
    """
    e_p, e_bin, e_al, e_la, e_dl2, e_la2 = elems
    o_l, o_z, o_d, o_2 = out
    second = consts[C_RATIO] > 0.0
    L = tile
    for wk in prange(work_start.shape[0] - 1):
        scratch = walk_scratch(L, zs)
        for j in range(work_start[wk], work_start[wk + 1]):
            t = work_tiles[j]
            b, x0, x1, y0, y1, off, n = walk_tile(t, scratch, gpar, zs, wint, wflt, head, has_head, consts, nbins > 1,
                                                  tile_start, sorted_g, boxes, width, height, tile, offsets, elems,
                                                  e_range, compress)
            tw = x1 - x0 + 1
            npx = tw * (y1 - y0 + 1)
            i0, i1 = tile_start[t], tile_start[t + 1]
            zref = np.full(npx, np.inf, zs.dtype)
            if nbins > 1:
                fold_zref(scratch[1], zref, x1, x0, y1, y0, L)
            Lb, nb = bin_sums(e_p, e_bin, e_la, e_range, i0, i1, sorted_g, zs, zref, nbins, npx)
            acc = np.zeros((5, npx))
            for bb in range(nb):  # sum of l, in bin order
                for p in range(npx):
                    acc[0, p] += Lb[bb, p]
            if second:  # sum of l2, in element order
                for e in range(np.uint64(off), np.uint64(off + n)):
                    acc[4, np.uint64(e_p[e])] += e_la2[e]
            if nbins > 1:
                negM, Etab = weight_table(Lb, nb)
                for k in range(i0, i1):
                    g = sorted_g[k]
                    z, c, s = gpar[g, G_Z], gpar[g, G_C], gpar[g, G_S]
                    mw = 0.0
                    for e in range(np.uint64(e_range[k, 0]), np.uint64(e_range[k, 1])):
                        p = np.uint64(e_p[e])
                        w = negM[np.uint64(e_bin[e]), p] * e_la[e]
                        acc[1, p] += w * z
                        acc[2, p] += w * c
                        acc[3, p] += w * s
                        mw = max(mw, w)
                    if mw >= vis_weight:
                        visible[g] = True
            p = 0
            for y in range(y0, y1 + 1):  # row-major tile pixels: no division per pixel
                for x in range(x0, x1 + 1):
                    o_l[b, y, x] = acc[0, p]
                    if nbins > 1:
                        o_z[b, y, x] = acc[1, p]
                        o_d[b, y, x, 0] = acc[2, p]
                        o_d[b, y, x, 1] = acc[3, p]
                    if second:
                        o_2[b, y, x] = acc[4, p]
                    p += 1


@njit(**_PAR)
def composite_backward(gpar, consts, nbins, tile_start, sorted_g, work_start, work_tiles, width, height, tile,
                       elems, e_range, grad, acc):
    """Backward compositing of all tiles from the elements kept by :func:`composite_forward`.

    Args:
        grad: the upstream gradients of the four arrays of ``out`` of :func:`composite_forward`, in
            the table's dtype (summed in float64; those it did not write are not read); the other arguments as given to (and
            filled by) :func:`composite_forward`.
        acc: [n_instances, 8] filled with the instance sums (see ``N_ACC``; every entry is
            written, the array need not be zeroed).
    """
    e_p, e_bin, e_dl, e_la, e_dl2, e_la2 = elems
    g_l, g_z, g_d, g_2 = grad
    second = consts[C_RATIO] > 0.0
    for wk in prange(work_start.shape[0] - 1):
        for j in range(work_start[wk], work_start[wk + 1]):
            t = work_tiles[j]
            b, x0, x1, y0, y1 = tile_box(t, width, height, tile)
            px, py = _pixel_xy(x0, x1, y0, y1)
            npx = px.shape[0]
            i0, i1 = tile_start[t], tile_start[t + 1]
            gl = np.zeros((4, npx))
            g2 = np.zeros(npx if second else 0)
            shade = nbins > 1
            for p in range(npx):
                y, x = int(py[p]), int(px[p])
                gl[0, p] = g_l[b, y, x]
                if shade:
                    gl[1, p] = g_z[b, y, x]
                    gl[2, p] = g_d[b, y, x, 0]
                    gl[3, p] = g_d[b, y, x, 1]
            for p in range(g2.shape[0]):
                g2[p] = g_2[b, int(py[p]), int(px[p])]
            if shade:  # A: Lb and G(b, p) = sum of q l in one loop; B: dL/dLb
                Lb, Gt, nb = bin_and_grad_sums(e_p, e_bin, e_la, e_range, i0, i1, sorted_g, gpar, gl, nbins, npx)
                negM, Etab = weight_table(Lb, nb)
                H = gradient_table(Lb, nb, negM, Etab, Gt, gl[0])
            else:  # silhouette only: sum l is all there is
                negM, H = np.zeros((1, npx)), gl[0:1].copy()
            for k in range(i0, i1):  # C: d loss / d power and its moments, d loss / d (z, c, s), per instance
                g = sorted_g[k]
                z, c, s = gpar[g, G_Z], gpar[g, G_C], gpar[g, G_S]
                mx, my = gpar[g, G_MX], gpar[g, G_MY]
                s0 = s1 = s2 = s3 = s4 = sz = sc = ss = 0.0
                for e in range(np.uint64(e_range[k, 0]), np.uint64(e_range[k, 1])):
                    p, bn = np.uint64(e_p[e]), np.uint64(e_bin[e])
                    q = gl[1, p] * z + gl[2, p] * c + gl[3, p] * s  # d loss / d w
                    nm = negM[bn, p]
                    gp = (H[bn, p] + q * nm) * e_dl[e]  # d l / d power, 0 where alpha was clamped
                    if second:
                        gp += g2[p] * e_dl2[e]
                    if shade:
                        w = nm * e_la[e]
                        sz += gl[1, p] * w
                        sc += gl[2, p] * w
                        ss += gl[3, p] * w
                    dx, dy = px[p] - mx, py[p] - my
                    s0 += gp * dx
                    s1 += gp * dy
                    s2 += gp * dx * dx
                    s3 += gp * dx * dy
                    s4 += gp * dy * dy
                acc[k, 0], acc[k, 1], acc[k, 2], acc[k, 3], acc[k, 4] = s0, s1, s2, s3, s4
                acc[k, 5], acc[k, 6], acc[k, 7] = sz, sc, ss


@njit(**_PAR)
def reduce_gradients(gstart, inst_pos, gpar, acc, grads, dest=None, slot=None):
    """grads [G, 8]: d loss / d (mean x, mean y, q_xx, q_xy, q_yy, z, cos2a, sin2a), summing the
    instance accumulators ``acc`` of each Gaussian in instance order (0 for undrawn Gaussians);
    computed in float64, stored in the dtype of ``grads``. ``dest``: None (Gaussian g's row is
    grads[g]) or a [G] permutation (its row is grads[dest[g]]: the exact model's Gaussians, numbered
    in depth order, written back in the caller's order without a separate permutation pass).
    ``slot``: None (the accumulators of the instance at position j of the Gaussian order are
    acc[inst_pos[j]]) or [n_instances] int32 in the Gaussian order, their row of ``acc`` (-1: none, a
    zero row; :func:`.numba_exact.composite_exact_backward`).
    The rows of Gaussian g + GATHER_AHEAD are prefetched (:func:`.numba_simd.prefetch_row`): in the exact
    model a tile lists its instances in depth order, so those of one Gaussian lie scattered over
    ``acc`` (3.3 -> 1.75 ms for the 218,000 instances of 4k strands at 256 x 256; AMD Zen 3)."""
    G = gstart.shape[0] - 1
    for gg in prange(G):
        g = np.int64(gg)
        ga = min(g + GATHER_AHEAD, G - 1)
        for j in range(gstart[ga], gstart[ga + 1]):
            ka = inst_pos[j] if slot is None else np.int64(slot[j])
            if ka >= 0:
                prefetch_row(acc, ka)
        r = g if dest is None else np.int64(dest[g])
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
        for j in range(gstart[g], gstart[g + 1]):
            k = inst_pos[j] if slot is None else np.int64(slot[j])
            if slot is not None and k < 0:
                continue
            s0 += acc[k, 0]
            s1 += acc[k, 1]
            s2 += acc[k, 2]
            s3 += acc[k, 3]
            s4 += acc[k, 4]
            s5 += acc[k, 5]
            s6 += acc[k, 6]
            s7 += acc[k, 7]
        if gstart[g] == gstart[g + 1]:
            for c in range(8):
                grads[r, c] = 0.0
            continue
        # power = log op - (q_xx dx^2 + 2 q_xy dx dy + q_yy dy^2) / 2 with dx = x - mean x
        grads[r, 0] = gpar[g, G_QXX] * s0 + gpar[g, G_QXY] * s1
        grads[r, 1] = gpar[g, G_QXY] * s0 + gpar[g, G_QYY] * s1
        grads[r, 2] = -0.5 * s2
        grads[r, 3] = -s3
        grads[r, 4] = -0.5 * s4
        grads[r, 5], grads[r, 6], grads[r, 7] = s5, s6, s7
