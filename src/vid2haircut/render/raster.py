"""Fast compositing of screen-space strand Gaussians into pixel sums (custom autograd Function).

Compositing model (checked against the exact per-pixel sorted reference in
``tests/render_reference.py``):

* Silhouette: 1 - prod_i (1 - alpha_i) = 1 - exp(sum_i log(1 - alpha_i)) is order independent,
  so it is exact (float32 round-off only).
* Depth and direction: depth-binned front-to-back compositing. Sorting every (Gaussian, pixel)
  contribution by depth would cost more than the whole rest of the renderer on a CPU. Instead,
  per pixel, contributions fall into ``bins`` depth bins of ``depth_bin`` metres (default
  32 x 1 mm) counted from z_ref(p), the nearest Gaussian whose pixel window covers the pixel;
  log(1 - alpha) is summed per
  (pixel, bin), an exclusive cumulative sum over bins gives the transmittance in front of each
  bin, and a contribution's weight is that transmittance times its share of its bin's absorbed
  opacity (see :mod:`vid2haircut.render.kernels`). This equals exact front-to-back compositing
  whenever no two contributions at a pixel lie within the same millimetre bin; inside one bin
  the order is treated as unknown and the bin's opacity is shared in proportion to
  -log(1 - alpha). Hair more than bins * depth_bin behind the nearest contribution shares the
  last bin. The weights sum exactly to the silhouette. Gradients are exact for this function
  (the bin assignment, like a depth sort, is piecewise constant and carries no gradient).
  Depth = sum w z / sum w, direction = normalise(sum w (cos 2a, sin 2a)).
  Measured error against the exact reference on random tiny scenes (24 x 24 px, 6 wavy strands
  of 6 points crossing at mm depth spacing, 2 mm per pixel; inside the mask): depth mean
  0.015-0.07 mm (p95 <= 0.32 mm, max 1.6 mm), direction L1 mean 0.03-0.07 (p95 <= 0.29, on
  doubled-angle unit vectors), silhouette exact to 1e-15 (float64). For comparison, a soft
  z-buffer (w = alpha exp(-max(z - z_front, 0) / tau)) measured depth mean 1.2 mm and
  direction mean 0.22 on the same scenes for every tau from 0.03 to 3 mm, so it was dropped.
  Tests assert depth mean < 0.2 mm, p95 < 1 mm and direction mean < 0.1.
* Visibility: a segment is visible when its compositing weight (transmittance x alpha) reaches
  ``vis_weight`` (default 0.3) at some pixel, i.e. it is a substantial part of what the camera
  sees there.
* Head occluder: a contribution whose Gaussian depth is not in front of the head depth at that
  pixel has alpha 0 (it adds nothing to any channel; not differentiable w.r.t. the head).
"""

from __future__ import annotations

import torch
from torch import Tensor

from vid2haircut.render import kernels
from vid2haircut.render.gaussians import conics
from vid2haircut.render.kernels import KernelConsts, Layout, TileParams
from vid2haircut.render.types import Footprint, PixelSums


class _Composite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, mu, mv, quu, quv, qvv, z, c, s, layout, rows, cols, head, border, npix, consts):
        t = TileParams(mu, mv, quu, quv, qvv, z, c, s)
        sums, visible, saved = kernels.forward_kernel(t, layout, rows, cols, head, border, npix, consts)
        ctx.save_for_backward(*t, *layout, border, *saved)
        ctx.shape, ctx.npix, ctx.consts = (rows, cols), npix, consts
        if visible is None:
            visible = torch.zeros(mu.shape[0], dtype=torch.bool, device=mu.device)
        ctx.mark_non_differentiable(visible)
        return sums, visible

    @staticmethod
    def backward(ctx, grad, _g_vis):
        saved = ctx.saved_tensors
        t, layout, border = TileParams(*saved[:8]), Layout(*saved[8:12]), saved[12]
        g = kernels.backward_kernel(grad, t, layout, *ctx.shape, border, tuple(saved[13:]), ctx.npix, ctx.consts)
        return (*g, None, None, None, None, None, None, None)


def padding_mask(batch: int, height: int, width: int, pad: int, device) -> Tensor:
    """[B * (H + 2 pad) * (W + 2 pad)] bool mask, True on the padding."""
    border = torch.ones(batch, height + 2 * pad, width + 2 * pad, dtype=torch.bool, device=device)
    border[:, pad:-pad, pad:-pad] = False
    return border.reshape(-1)


def pad_head_depth(head_depth: Tensor, pad: int, dtype) -> Tensor:
    """[B, H, W] head depth (+inf where no head) -> flat padded [B * (H + 2 pad) * (W + 2 pad)]."""
    return torch.nn.functional.pad(head_depth.to(dtype), (pad,) * 4, value=float("inf")).reshape(-1)


def composite(
    means: Tensor,  # [G, 2]
    covs: Tensor,  # [G, 3]
    depths: Tensor,  # [G]
    dirs: Tensor,  # [G, 2]
    fp: Footprint,
    batch: int,
    height: int,
    width: int,
    consts: KernelConsts,
    head_depth: Tensor | None = None,  # [B, H, W]
) -> tuple[PixelSums, Tensor]:
    """Composite G Gaussians (flattened over frames) into per-pixel sums.

    Args:
        means, covs, depths, dirs: the flattened fields of :class:`Gaussians2D` ([G, ...]).
        fp: footprint from :func:`vid2haircut.render.footprint.build_footprint`.
        consts: kernel settings.
        head_depth: optional [B, H, W] camera z of the head (+inf where no head).

    Returns:
        (:class:`PixelSums` with [B, H, W] fields, visible [G] bool).
    """
    G = means.shape[0]
    dev = means.device
    dt = means.dtype
    qxx, qxy, qyy = conics(covs)
    hz = fp.horizontal
    tg = fp.tile_gauss
    swap = lambda a, b: torch.where(hz, a, b)[tg]  # noqa: E731  (u = x where horizontal)
    tiles = (swap(means[:, 0], means[:, 1]), swap(means[:, 1], means[:, 0]), swap(qxx, qyy), qxy[tg],
             swap(qyy, qxx), depths[tg], dirs[tg, 0], dirs[tg, 1])
    pad = fp.pad
    npix = batch * (height + 2 * pad) * (width + 2 * pad)
    border = padding_mask(batch, height, width, pad, dev)
    head = None if head_depth is None else pad_head_depth(head_depth, pad, dt)
    cols = fp.cols
    layout = Layout(fp.u.to(dt), fp.vstart.to(dt), fp.colbase, fp.vstride)
    sums, vis_tile = _Composite.apply(*tiles, layout, fp.rows, cols, head, border, npix, consts)
    sums = sums.reshape(batch, height + 2 * pad, width + 2 * pad, sums.shape[-1])[:, pad:-pad, pad:-pad]
    log_t = sums[..., 0]
    weight = -torch.expm1(log_t) + 0.0  # + 0.0 turns -0.0 into 0.0
    visible = torch.zeros(G, dtype=torch.bool, device=dev)
    if not consts.shading:
        zeros = torch.zeros_like(log_t)
        return PixelSums(log_t, weight, zeros, torch.stack([zeros, zeros], -1)), visible
    visible[tg[vis_tile]] = True
    return PixelSums(log_t, weight, sums[..., 1], sums[..., 2:4]), visible
