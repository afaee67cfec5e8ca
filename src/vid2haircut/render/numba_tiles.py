"""Screen-tile binning of Gaussian windows for the fused CPU compositor (numba).

Each frame is cut into square screen tiles of ``tile`` x ``tile`` pixels (tile id =
(frame * nty + ty) * ntx + tx). Every (Gaussian, tile) pair where the Gaussian's pixel window
(:class:`vid2haircut.render.footprint.Windows`) may touch the tile is an *instance*; instances are
listed tile by tile, and inside a tile by increasing Gaussian index, so that every later
summation has a fixed order. A (Gaussian, tile) pair that the head hides entirely (its depth is
not in front of the head at any pixel of the tile, :func:`tile_head_max`) is no instance: it
would add no element, and its z_ref could only matter at pixels where another window has a kept
element, which is in front of the head there and so nearer than it. Tiles are then dealt to the
worker threads (largest first, each to the least loaded worker); which thread composites a tile
never changes its result.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from vid2haircut.render.footprint import COLUMN_COST

# columns of the int64 window table ``wint`` [G, 4] and the float32 table ``wflt`` [G, 2]
W_HZ, W_ULO, W_NCOL, W_HGT = 0, 1, 2, 3
W_SLOPE, W_V0 = 0, 1


@njit(cache=True)
def vstart(slope, u, v0):
    """First window row of column ``u``: ceil(slope * u + v0), in float32 exactly as footprint.py does.

    The ceiling is taken as trunc(t) + (t > trunc(t)) (exact for finite |t| < 2^63; windows are
    built from finite values only): numba's ``math.ceil`` is a call into libm that LLVM does not
    inline, ~15 cycles per window start outside vectorised loops."""
    t = slope * np.float32(u)
    t = t + v0
    i = np.int64(t)
    return i + np.int64(t > np.float32(i))


@njit(inline="always")
def vstart32(slope, u, v0):
    """:func:`vstart` in int32 for an int32 ``u``: the same value wherever |slope * u + v0| <= 2^30; beyond,
    +-2^30 (rows far outside any image). Its conversions have AVX2 vector forms (float32 <-> int64
    conversions need AVX-512DQ), so that a loop over lanes of it vectorises on AVX2 CPUs too."""
    t = slope * np.float32(u)
    t = t + v0
    t = min(max(t, np.float32(-2.0**30)), np.float32(2.0**30))
    i = np.int32(t)
    return i + np.int32(t > np.float32(i))


# fields of an instance's box code (uint32, :func:`bin_windows`): its window inside its tile, tile
# relative, with tiles of at most 32 pixels a side
B_MISS = np.uint32(1 << 31)
"""Set in the code of an instance whose window (its columns in the tile, and their rows) misses the tile."""


@njit(cache=True, inline="always")
def box_code(lay, lo, hi, ua, ub, hmin):
    """The box code of an instance: layout ``lay`` (0: u = x, the window horizontal; 1: u = y), its
    lines lo..hi (rows of the window within the tile, along v), its lanes ua..ub (columns, along u)
    and ``hmin`` = min(window height, tile extent along v), each tile relative (< 32, ``hmin`` <= 32)."""
    return (np.uint32(lay) | (np.uint32(lo) << np.uint32(1)) | (np.uint32(hi) << np.uint32(6))
            | (np.uint32(ua) << np.uint32(11)) | (np.uint32(ub) << np.uint32(16)) | (np.uint32(hmin) << np.uint32(21)))


@njit(cache=True, inline="always")
def box_fields(c):
    """(lay, lo, hi, ua, ub, hmin) of box code ``c`` (:func:`box_code`; not :data:`B_MISS`)."""
    m = np.uint32(31)
    return (np.int64(c & np.uint32(1)), np.int64((c >> np.uint32(1)) & m), np.int64((c >> np.uint32(6)) & m),
            np.int64((c >> np.uint32(11)) & m), np.int64((c >> np.uint32(16)) & m),
            np.int64((c >> np.uint32(21)) & np.uint32(63)))


@njit(cache=True, inline="always")
def row_box(g, wint, wflt, x0, x1, y0, y1):
    """Box code (:func:`box_code`, or :data:`B_MISS`) of window g in the tile of pixels x0..x1,
    y0..y1, from its rows: what the window walk (:func:`vid2haircut.render.numba_lines.walk_lines`)
    takes to start an instance, listed by :func:`bin_windows` with ``with_boxes``."""
    hz = wint[g, W_HZ] != 0
    tu0, tu1, tv0, tv1 = (x0, x1, y0, y1) if hz else (y0, y1, x0, x1)
    ula = np.int64(wint[g, W_ULO])
    ua, ub = max(ula, tu0), min(ula + np.int64(wint[g, W_NCOL]) - 1, tu1)
    if ub < ua:
        return B_MISS
    sl, v0 = wflt[g, W_SLOPE], wflt[g, W_V0]
    va, vb = vstart(sl, ua, v0), vstart(sl, ub, v0)  # vstart is monotone in u
    h = np.int64(wint[g, W_HGT])
    lo = max(min(va, vb), tv0) - tv0
    hi = min(max(va, vb) + h - 1, tv1) - tv0
    if hi < lo:
        return B_MISS
    return box_code(0 if hz else 1, lo, hi, ua - tu0, ub - tu0, min(h, tv1 - tv0 + 1))


@njit(cache=True, parallel=True)
def tile_head_max(head, has_head, nframes, width, height, tile):
    """[NT] largest head depth over the pixels of each tile (+inf without a head; the dtype of
    ``head`` [B, H, W])."""
    ntx = (width + tile - 1) // tile
    nty = (height + tile - 1) // tile
    out = np.full(nframes * nty * ntx, np.inf, head.dtype)
    if not has_head:
        return out
    for t in prange(out.shape[0]):
        b = t // (ntx * nty)
        r = t - b * ntx * nty
        ty = r // ntx
        tx = r - ty * ntx
        m = head[b, ty * tile, tx * tile]
        for y in range(ty * tile, min(ty * tile + tile, height)):
            for x in range(tx * tile, min(tx * tile + tile, width)):
                m = max(m, head[b, y, x])
        out[t] = m
    return out


@njit(cache=True, inline="always")
def _tile_of(i, tile, shift):
    """floor(i / tile) for an int64 ``i``: an arithmetic shift when tile = 2^shift (``shift`` >= 0; the
    same value for negative i too), a division otherwise (``shift`` -1)."""
    return (i >> shift) if shift >= 0 else i // tile


@njit(cache=True)
def tile_shift(tile):
    """log2(tile) when ``tile`` is a power of two, else -1 (see :func:`_tile_of`)."""
    if tile <= 0 or tile & (tile - 1) != 0:
        return -1
    s = 0
    while (1 << s) < tile:
        s += 1
    return s


@njit(cache=True, inline="always")
def _tile_box(g, wint, wflt, width, height, tile, shift):
    """Tile range (x0, x1, y0, y1), inclusive, that window g may touch; empty (0, -1, 0, -1) when it
    touches no pixel (not drawn, non-finite line, or off the image). Selects rather than branches:
    whether a window is horizontal, drawn or on the image is unpredictable from one to the next.
    Pixel -> tile by shifts when the tile size is a power of two (``shift``, :func:`tile_shift`)
    instead of four 64-bit divisions: the binning of six 2000-strand frames at 224² 15.0-15.9 ->
    14.1-14.4 ms single-thread on an AMD Zen 3 (the same instances)."""
    ncol = wint[g, W_NCOL]
    sl, v0 = wflt[g, W_SLOPE], wflt[g, W_V0]
    ok = (ncol > 0) & math.isfinite(sl) & math.isfinite(v0)
    sl, v0 = (sl, v0) if ok else (np.float32(0.0), np.float32(0.0))
    hz = wint[g, W_HZ] != 0
    su = width if hz else height
    sv = height if hz else width
    ua = wint[g, W_ULO]
    ub = min(ua + ncol - 1, su - 1)
    va, vb = vstart(sl, ua, v0), vstart(sl, ub, v0)  # vstart is monotone in u
    vlo = max(min(va, vb), 0)
    vhi = min(max(va, vb) + wint[g, W_HGT] - 1, sv - 1)
    ok = ok & (ub >= ua) & (vhi >= vlo)
    u0, u1 = _tile_of(ua, tile, shift), _tile_of(ub, tile, shift)
    v0_, v1 = _tile_of(vlo, tile, shift), _tile_of(vhi, tile, shift)
    bx0, bx1, by0, by1 = (u0, u1, v0_, v1) if hz else (v0_, v1, u0, u1)
    return (bx0, bx1, by0, by1) if ok else (0, -1, 0, -1)


@njit(cache=True, parallel=True)
def bin_windows(wint, wflt, frame, nframes, width, height, tile, z, hmax, with_boxes):
    """List the instances of every tile.

    Args:
        wint: [G, 4] int64 (horizontal, u_lo, ncols, height) of each window (ncols 0: not drawn).
        wflt: [G, 2] float32 (slope, v0). frame: [G] int64 frame of each Gaussian.
        nframes, width, height: image stack size; tile: tile size in pixels.
        z: [G] camera depth of each Gaussian, hmax: [NT] largest head depth of each tile
            (:func:`tile_head_max`, same dtype): no instance where z >= hmax (hidden; a NaN
            depth is kept).

    Returns:
        gstart [G + 1] (instances of Gaussian g are gstart[g]:gstart[g + 1] in Gaussian order),
        inst_pos [n] (position of each of them in the tile order), tile_start [NT + 1] (instances
        of tile t are tile_start[t]:tile_start[t + 1] in tile order), sorted_g [n] (their Gaussian),
        boxes: with ``with_boxes``, [n] uint32 in tile order: each instance's window within its tile
        (:func:`box_code`, or :data:`B_MISS`; tiles of at most 32 pixels a side), else empty. The
        exact model takes them (its walk then reads no row of an instance that covers no live
        pixel; 1 ms more binning, 0.8 ms less tile bounds, ~1.5 ms less forward for 4k strands at
        256 x 256); the binned model, which walks every instance, works them out from the rows.
    """
    if tile > 32:
        raise ValueError("bin_windows: tiles of at most 32 pixels a side (box codes)")
    G = wint.shape[0]
    ntx = (width + tile - 1) // tile
    nty = (height + tile - 1) // tile
    box = np.empty((G, 4), np.int64)
    cnt = np.empty(G, np.int64)
    NT = nframes * nty * ntx
    shift = tile_shift(tile)
    for g in prange(G):
        bx0, bx1, by0, by1 = _tile_box(g, wint, wflt, width, height, tile, shift)
        box[g, 0], box[g, 1], box[g, 2], box[g, 3] = bx0, bx1, by0, by1
        zg, row0 = z[g], frame[g] * nty
        if bx1 - bx0 <= 1 and by1 - by0 <= 1:  # at most 2 x 2 tiles (most windows): no loop to mispredict
            x1 = bx0 + 1 <= bx1
            y1 = by0 + 1 <= by1
            any_ = bx0 <= bx1
            t00 = (row0 + by0) * ntx + bx0
            t00 = t00 if any_ else 0
            t01 = t00 + 1 if x1 else t00
            t10 = t00 + ntx if y1 else t00
            t11 = t10 + 1 if x1 else t10
            cnt[g] = (np.int64(any_ & (not zg >= hmax[t00])) + np.int64(x1 & (not zg >= hmax[t01]))
                      + np.int64(y1 & (not zg >= hmax[t10])) + np.int64(x1 & y1 & (not zg >= hmax[t11])))
        else:
            c = 0
            for ty in range(by0, by1 + 1):
                for tx in range(bx0, bx1 + 1):
                    c += not zg >= hmax[(row0 + ty) * ntx + tx]
            cnt[g] = c
    gstart = np.zeros(G + 1, np.int64)
    for g in range(G):
        gstart[g + 1] = gstart[g] + cnt[g]
    n = gstart[G]
    inst_tile = np.empty(n, np.int64)
    inst_code = np.empty(n if with_boxes else 0, np.uint32)
    for g in prange(G):
        j, j1 = gstart[g], gstart[g + 1]
        if j == j1:
            continue
        bx0, bx1, by0, by1 = box[g, 0], box[g, 1], box[g, 2], box[g, 3]
        zg, row0 = z[g], frame[g] * nty
        for ty in range(by0, by1 + 1):
            for tx in range(bx0, bx1 + 1):
                t = (row0 + ty) * ntx + tx
                if j < j1 and not zg >= hmax[t]:
                    inst_tile[j] = t
                    if with_boxes:
                        x0, y0 = tx * tile, ty * tile
                        inst_code[j] = row_box(g, wint, wflt, x0, min(x0 + tile, width) - 1, y0,
                                               min(y0 + tile, height) - 1)
                    j += 1
    # counting sort of the instances by tile, stable (Gaussian order inside a tile), in parallel over
    # CH chunks of instances: per-chunk tile counts, then each chunk's first slot in every tile
    CH = 64
    step = (n + CH - 1) // CH
    counts = np.zeros((CH + 1, NT), np.int64)
    for c in prange(CH):
        for j in range(c * step, min((c + 1) * step, n)):
            counts[c + 1, inst_tile[j]] += 1
    tile_start = np.zeros(NT + 1, np.int64)
    for t in range(NT):
        tot = 0
        for c in range(CH):
            tot += counts[c + 1, t]
        tile_start[t + 1] = tile_start[t] + tot
    for t in prange(NT):  # counts[c, t] := first slot of chunk c in tile t
        cur = tile_start[t]
        for c in range(CH):
            k = counts[c + 1, t]
            counts[c, t] = cur
            cur += k
    sorted_g = np.empty(n, np.int64)
    inst_pos = np.empty(n, np.int64)
    boxes = np.empty(n if with_boxes else 0, np.uint32)
    for c in prange(CH):
        cursor = counts[c].copy()
        g = np.searchsorted(gstart, c * step, side="right") - 1  # Gaussian of the chunk's first instance
        for j in range(c * step, min((c + 1) * step, n)):
            while gstart[g + 1] <= j:
                g += 1
            pos = cursor[inst_tile[j]]
            cursor[inst_tile[j]] += 1
            sorted_g[pos] = g
            if with_boxes:
                boxes[pos] = inst_code[j]
            inst_pos[j] = pos
    return gstart, inst_pos, tile_start, sorted_g, boxes


@njit(cache=True)
def assign_tiles(tile_start, nworkers):
    """Deal the non-empty tiles to ``nworkers`` workers, largest first (cost: instance count).

    Returns:
        work_start [nworkers + 1], work_tiles [n_nonempty]: worker w composites tiles
        work_tiles[work_start[w]:work_start[w + 1]].
    """
    NT = tile_start.shape[0] - 1
    cost = np.empty(NT, np.int64)
    for t in range(NT):
        cost[t] = tile_start[t + 1] - tile_start[t]
    order = np.argsort(-cost, kind="mergesort")
    load = np.zeros(nworkers, np.int64)
    owner = np.full(NT, -1, np.int64)
    for i in range(NT):
        t = order[i]
        if cost[t] == 0:
            break
        w = np.argmin(load)
        owner[t] = w
        load[w] += cost[t] + 8
    work_start = np.zeros(nworkers + 1, np.int64)
    for t in range(NT):
        if owner[t] >= 0:
            work_start[owner[t] + 1] += 1
    for w in range(nworkers):
        work_start[w + 1] += work_start[w]
    cursor = work_start[:nworkers].copy()
    work_tiles = np.empty(work_start[nworkers], np.int64)
    for t in range(NT):
        if owner[t] >= 0:
            work_tiles[cursor[owner[t]]] = t
            cursor[owner[t]] += 1
    return work_start, work_tiles


@njit(cache=True, parallel=True, error_model="numpy")
def gaussian_windows(means, covs, valid, height, width, power_min, cols, max_rows, wint, wflt):
    """The pixel windows of :func:`vid2haircut.render.footprint.gaussian_windows`, computed here in
    float32 in the same order of operations, straight into the window tables.

    Args:
        means: [G, 2], covs: [G, 3] (any float dtype; rounded to float32 first, as there), valid:
            [G] bool. height, width: image size. power_min: log(alpha_min / opacity) < 0.
        cols, max_rows: tile width and the largest tile height tried.
        wint: [G, 4] int64, wflt: [G, 2] float32, filled (columns ``W_*``).

    Returns:
        rows, the common tile height (every window's height is a multiple of it).

    torch's float32 square root is not always correctly rounded (numba's is), so a window edge
    can differ by a pixel in rare cases: the numba backend uses these windows with its own
    projection (:func:`vid2haircut.render.numba_ops.project_fused`), and torch's windows when
    it composites Gaussians projected by torch.
    """
    G = means.shape[0]
    f32 = np.float32
    c2 = f32(-2.0 * power_min)
    need = np.empty(G, np.int64)
    ntu = np.empty(G, np.int64)
    for g in prange(G):
        mx, my = f32(means[g, 0]), f32(means[g, 1])
        sxx, sxy, syy = f32(covs[g, 0]), f32(covs[g, 1]), f32(covs[g, 2])
        hz = sxx >= syy
        mu, mv = (mx, my) if hz else (my, mx)
        suu, svv = (sxx, syy) if hz else (syy, sxx)
        size_u, size_v = (f32(width), f32(height)) if hz else (f32(height), f32(width))
        eu = np.sqrt(c2 * suu)
        ev = np.sqrt(c2 * svv)
        u_lo = max(np.ceil(mu - eu), f32(0.0))
        u_hi = min(np.floor(mu + eu), size_u - f32(1.0))
        on_image = (mv + ev >= f32(0.0)) & (mv - ev <= size_v - f32(1.0))
        slope = sxy / suu
        det = max(suu * svv - sxy * sxy, f32(1e-12))
        half = np.sqrt(c2 * det / suu)
        ok = valid[g] & on_image & np.isfinite(mu) & np.isfinite(eu) & np.isfinite(ev) & np.isfinite(half)
        ncol = max(u_hi - u_lo + f32(1.0), f32(0.0)) if ok else f32(0.0)
        nt = np.int64(np.ceil(ncol / f32(cols)))
        ntu[g] = nt
        need[g] = np.int64(np.floor(f32(2.0) * half) + f32(1.0)) if nt > 0 else 1
        wint[g, W_HZ] = np.int64(hz)
        wint[g, W_ULO] = np.int64(u_lo) if ok else 0
        wint[g, W_NCOL] = nt * cols
        wflt[g, W_SLOPE] = slope
        wflt[g, W_V0] = mv - slope * mu - half
    # common tile height R minimising sum_g ntu_g * ceil(need_g / R) * (R + column cost), as in
    # vid2haircut.render.footprint._choose_rows
    hist = np.zeros(65)
    for g in range(G):
        if ntu[g] > 0:
            hist[min(need[g], 64)] += float(ntu[g])
    rows, best = 1, np.inf
    for R in range(1, max_rows + 1):
        cost = 0.0
        for n in range(65):
            cost += hist[n] * math.ceil(n / R) * (R + COLUMN_COST)
        if cost < best:
            rows, best = R, cost
    for g in prange(G):
        wint[g, W_HGT] = ((need[g] + rows - 1) // rows) * rows
    return rows
