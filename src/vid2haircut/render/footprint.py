"""Pixel footprints of screen-space Gaussians: sheared fixed-size tiles (no gradients).

A Gaussian contributes to pixel p only where its power -m/2 (m the squared Mahalanobis distance)
is at least ``power_min`` (alpha >= alpha_min), i.e. inside the ellipse m <= c^2, c^2 = -2 power_min.
Strand Gaussians are long and thin and mostly not axis aligned, so a square window around the
centre would be mostly empty. Instead each Gaussian is walked along its major image axis u
(one pixel column at a time) and, per column, only a short run of ``rows`` pixels along the other
axis v is visited, starting where the ellipse begins in that column (the run follows the slope of
the ellipse). Runs of ``cols`` columns form one fixed-size tile, so every later step is a dense
[tiles, cols, rows] tensor operation with per-tile parameters broadcast instead of gathered.

The window provably contains the whole ellipse: in column u the ellipse spans
v in [v_c(u) - h, v_c(u) + h] with v_c(u) = mu_v + (s_uv / s_uu)(u - mu_u) and
h <= c sqrt(det / s_uu), which holds at most floor(2h) + 1 integers; columns with
|u - mu_u| > c sqrt(s_uu) lie outside. Pixels outside the image land in the padding, which is
cropped away after compositing.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from vid2haircut.render.types import Footprint


COLUMN_COST = 3.0
"""Cost of one tile column's own bookkeeping, in units of one pixel element (measured, CPU)."""


def _choose_rows(ncol_tiles: Tensor, need: Tensor, max_rows: int) -> int:
    """Tile height R in 1..max_rows minimising sum_g ncol_tiles_g * ceil(need_g / R) * (R + COLUMN_COST)."""
    if need.numel() == 0:
        return 1
    hist = torch.bincount(need.clamp(max=64), weights=ncol_tiles.to(torch.float64), minlength=65)
    n = torch.arange(65, device=need.device, dtype=torch.float64)[:, None]
    cand = torch.arange(1, max_rows + 1, device=need.device, dtype=torch.float64)
    cost = (hist[:, None] * torch.ceil(n / cand) * (cand + COLUMN_COST)).sum(0)
    return int(torch.argmin(cost).item()) + 1


def _morton_key(means: Tensor, frame: Tensor, width: int, height: int, cell: int = 16) -> Tensor:
    """[G] int64 sort key: frame, then the Z-order index of the Gaussian's 16 x 16 pixel cell."""
    cx = torch.nan_to_num(means[:, 0] / cell, nan=0.0).clamp(0, 1023).to(torch.int64)
    cy = torch.nan_to_num(means[:, 1] / cell, nan=0.0).clamp(0, 1023).to(torch.int64)
    key = torch.zeros_like(cx)
    for bit in range(10):
        key |= ((cx >> bit) & 1) << (2 * bit) | ((cy >> bit) & 1) << (2 * bit + 1)
    return frame * (1 << 20) + key


class Windows(NamedTuple):
    """Per-Gaussian pixel windows (no gradients), each [G]; see the module docstring.

    In column u (an integer, u = x where ``horizontal`` else y) the window holds the ``height``
    pixels v = vs(u) .. vs(u) + height - 1 along the other axis, vs(u) = ceil(slope * u + v0)
    evaluated in float32 exactly in this order; the columns are u_lo .. u_lo + ncols - 1.
    Gaussians with ncols = 0 are not drawn. Used by both compositing backends, so that they
    visit the same pixels.

    Attributes:
        horizontal: bool, u = x. u_lo: float32 first column (integer valued, >= 0).
        slope, v0: float32 window start line. ntu, ntv: int64 tiles along u (ncols = ntu * cols)
        and along v (height = ntv * rows). rows, cols: tile shape.
    """

    horizontal: Tensor
    u_lo: Tensor
    slope: Tensor
    v0: Tensor
    ntu: Tensor
    ntv: Tensor
    rows: int
    cols: int


@torch.no_grad()
def gaussian_windows(
    means: Tensor,  # [G, 2]
    covs: Tensor,  # [G, 3]
    valid: Tensor,  # [G]
    height: int,
    width: int,
    power_min: float,
    cols: int = 4,
    max_rows: int = 8,
) -> Windows:
    """Window of the pixels each Gaussian can touch (arguments as in :func:`build_footprint`)."""
    if power_min >= 0:
        raise ValueError(f"power_min must be negative (alpha_min < opacity), got {power_min}")
    means = means.detach().to(torch.float32)
    covs = covs.detach().to(torch.float32)
    c2 = -2.0 * power_min
    sxx, sxy, syy = covs.unbind(-1)
    hz = sxx >= syy
    mu = torch.where(hz, means[:, 0], means[:, 1])
    mv = torch.where(hz, means[:, 1], means[:, 0])
    suu = torch.where(hz, sxx, syy)
    svv = torch.where(hz, syy, sxx)
    size_u = torch.where(hz, width, height).to(torch.float32)
    size_v = torch.where(hz, height, width).to(torch.float32)

    eu = torch.sqrt(c2 * suu)
    ev = torch.sqrt(c2 * svv)
    u_lo = torch.ceil(mu - eu).clamp_min(0.0)
    u_hi = torch.minimum(torch.floor(mu + eu), size_u - 1.0)
    on_image = (mv + ev >= 0) & (mv - ev <= size_v - 1.0)
    ok = valid & on_image & torch.isfinite(mu) & torch.isfinite(eu) & torch.isfinite(ev)
    ncol = torch.where(ok, (u_hi - u_lo + 1.0).clamp_min(0.0), torch.zeros_like(u_lo))
    slope = sxy / suu
    det = (suu * svv - sxy * sxy).clamp_min(1e-12)
    half = torch.sqrt(c2 * det / suu)
    need = torch.floor(2.0 * half) + 1.0

    ntu = torch.ceil(ncol / cols).to(torch.int64)
    need_i = torch.where(ntu > 0, need, torch.ones_like(need)).to(torch.int64)
    rows = _choose_rows(ntu[ntu > 0], need_i[ntu > 0], max_rows)
    ntv = (need_i + rows - 1) // rows
    # first window row of column u: ceil(v_c(u) - half), v_c(u) = mv + slope (u - mu)
    v0 = mv - slope * mu - half
    return Windows(hz, u_lo, slope, v0, ntu, ntv, rows, cols)


@torch.no_grad()
def build_footprint(
    means: Tensor,  # [G, 2]
    covs: Tensor,  # [G, 3]
    valid: Tensor,  # [G]
    frame: Tensor,  # [G] int64
    height: int,
    width: int,
    power_min: float,
    cols: int = 4,
    max_rows: int = 8,
) -> Footprint:
    """Tile layout of the pixels each Gaussian can touch.

    Args:
        means: [G, 2] pixel centres (x, y). covs: [G, 3] covariances (xx, xy, yy), px^2.
        valid: [G] bool; invalid Gaussians get no tile.
        frame: [G] frame index of each Gaussian (selects the image in the padded buffer).
        height, width: image size.
        power_min: log(alpha_min / opacity) < 0; the ellipse drawn is -m/2 >= power_min.
        cols: tile width in columns; max_rows: largest tile height tried.

    Returns:
        :class:`Footprint`; pixel indices address a flat buffer of B * (height + 2 pad) * (width + 2 pad).
    """
    dev = means.device
    win = gaussian_windows(means, covs, valid, height, width, power_min, cols, max_rows)
    hz, rows, ntu, ntv = win.horizontal, win.rows, win.ntu, win.ntv
    ntile = ntu * ntv

    # Visit the Gaussians in a spatially coherent order (Morton order of 16-pixel cells) so that
    # consecutive tiles touch nearby pixels: the per-pixel gathers and scatters then hit the cache.
    order = torch.argsort(_morton_key(means.detach().to(torch.float32), frame, width, height))
    ntile_o = ntile[order]
    tile_gauss = torch.repeat_interleave(order, ntile_o)
    start = torch.cumsum(ntile_o, 0) - ntile_o
    local = torch.arange(tile_gauss.shape[0], device=dev) - torch.repeat_interleave(start, ntile_o)
    g = tile_gauss
    nt = g.shape[0]

    def take(x: Tensor) -> Tensor:  # per Gaussian -> per tile
        return x.index_select(0, g)

    def ex(x: Tensor) -> Tensor:  # per tile -> per column (flat [nt * cols], tile-major)
        return x[:, None].expand(nt, cols).reshape(-1)

    ntv_t = take(ntv)
    cu = local // ntv_t
    cv = local - cu * ntv_t
    slope_t = take(win.slope)
    pad = max(rows, cols) + 1
    col = (torch.arange(nt * cols, device=dev) % cols).to(torch.float32)
    u = ex(take(win.u_lo) + (cu * cols).to(torch.float32)).add_(col)  # [nt * cols]
    v0 = take(win.v0)
    vstart = torch.ceil(ex(slope_t).mul_(u).add_(ex(v0))).add_(ex((cv * rows).to(torch.float32)))
    # Windows that start more than ``pad`` off the image lie wholly off it; clamping them keeps
    # every index inside the padded buffer without per-pixel bounds checks.
    size_v_t = torch.where(take(hz), height, width).to(torch.float32)
    vstart = torch.minimum(vstart.clamp_min_(-float(pad)), ex(size_v_t + float(pad - rows)))
    hz_t = take(hz)
    stride_row = width + 2 * pad
    stride_u = torch.where(hz_t, 1, stride_row)
    stride_v = ex(torch.where(hz_t, stride_row, 1))
    base = take(frame) * ((height + 2 * pad) * stride_row) + pad * (stride_row + 1)  # pixel (0, 0)
    colbase = ex(base).add_(u.to(torch.int64).mul_(ex(stride_u))).add_(vstart.to(torch.int64).mul_(stride_v))
    return Footprint(tile_gauss, u, vstart, colbase, stride_v, hz, rows, cols, pad)
