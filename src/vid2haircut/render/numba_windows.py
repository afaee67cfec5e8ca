"""Pixel windows of the fused CPU compositor (numba): the window tables, and a window within a tile.

A Gaussian's window (:class:`vid2haircut.render.footprint.Windows`) runs along its major image
axis u (x when horizontal, else y): columns u_lo .. u_lo + ncols - 1, each holding ``height``
rows from ceil(slope * u + v0) (:func:`vstart`). :func:`gaussian_windows` computes them into two
tables per Gaussian (``wint`` integers, ``wflt`` the line), in float32 as footprint.py does.
Within one screen tile (:mod:`.numba_tiles`), a window's lines and lanes are packed into a 32-bit
box code (:func:`box_code`, :func:`row_box`): the window walk (:mod:`.numba_lines`) starts an
instance from it, and the exact model's binning lists one per instance.
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


# fields of an instance's box code (uint32, :func:`.numba_tiles.bin_windows`): its window inside its tile, tile
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
    takes to start an instance, listed by :func:`.numba_tiles.bin_windows` for the exact model."""
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


@njit(cache=True, inline="always", error_model="numpy")
def window_of(mx, my, sxx, sxy, syy, valid, height, width, c2, cols):
    """The window of one Gaussian (mean mx, my, covariance sxx, sxy, syy, all float32; ``valid``;
    c2 = -2 power_min in float32; ``cols`` the tile width), in float32 in the order of operations of
    :func:`vid2haircut.render.footprint.gaussian_windows`.

    Returns:
        (horizontal, u_lo, column tiles ntu, rows needed, slope, v0): the window's ``wint`` row is
        (horizontal, u_lo, ntu * cols, its height, :func:`common_rows`), its ``wflt`` row (slope, v0).
    """
    f32 = np.float32
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
    ok = valid & on_image & np.isfinite(mu) & np.isfinite(eu) & np.isfinite(ev) & np.isfinite(half)
    ncol = max(u_hi - u_lo + f32(1.0), f32(0.0)) if ok else f32(0.0)
    nt = np.int64(np.ceil(ncol / f32(cols)))
    need = np.int64(np.floor(f32(2.0) * half) + f32(1.0)) if nt > 0 else 1
    return hz, np.int64(u_lo) if ok else 0, nt, need, slope, mv - slope * mu - half


@njit(cache=True, error_model="numpy")
def common_rows(need, ntu, max_rows):
    """The common tile height R in 1..max_rows minimising sum_g ntu_g * ceil(need_g / R) * (R + column
    cost) over the windows (``need``, ``ntu`` [G] from :func:`window_of`), as
    :func:`vid2haircut.render.footprint._choose_rows` does; a window's height is then
    ceil(need_g / R) * R."""
    hist = np.zeros(65)
    for g in range(need.shape[0]):
        if ntu[g] > 0:
            hist[min(need[g], 64)] += float(ntu[g])
    rows, best = 1, np.inf
    for R in range(1, max_rows + 1):
        cost = 0.0
        for n in range(65):
            cost += hist[n] * math.ceil(n / R) * (R + COLUMN_COST)
        if cost < best:
            rows, best = R, cost
    return rows


@njit(cache=True, parallel=True, error_model="numpy")
def gaussian_windows(means, covs, valid, height, width, power_min, cols, max_rows, wint, wflt):
    """The pixel windows of :func:`vid2haircut.render.footprint.gaussian_windows`, computed here in
    float32 in the same order of operations (:func:`window_of`), straight into the window tables.

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
        hz, u_lo, nt, nd, slope, v0 = window_of(f32(means[g, 0]), f32(means[g, 1]), f32(covs[g, 0]), f32(covs[g, 1]),
                                                f32(covs[g, 2]), valid[g], height, width, c2, cols)
        ntu[g] = nt
        need[g] = nd
        wint[g, W_HZ] = np.int64(hz)
        wint[g, W_ULO] = u_lo
        wint[g, W_NCOL] = nt * cols
        wflt[g, W_SLOPE] = slope
        wflt[g, W_V0] = v0
    rows = common_rows(need, ntu, max_rows)
    for g in prange(G):
        wint[g, W_HGT] = ((need[g] + rows - 1) // rows) * rows
    return rows
