"""Typed intermediate and final results of the strand renderer (PyTorch3D-style fragments).

Shapes use B = frames, N = strands, P = points per strand, S = N * (P - 1) segments,
H x W = image size, T = number of (Gaussian, pixel) contributions of one call.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor


class Gaussians2D(NamedTuple):
    """Screen-space Gaussians, one per strand segment (differentiable w.r.t. the points).

    Attributes:
        means: [B, S, 2] pixel coordinates (x = column, y = row) of the projected segment midpoints.
        covs: [B, S, 3] 2D covariance (xx, xy, yy) in px^2, dilation included.
        depths: [B, S] camera z of the segment midpoints (metres).
        dirs: [B, S, 2] undirected 2D direction as the doubled-angle unit vector (cos 2a, sin 2a),
            a = atan2(dy, dx) of the projected segment (image x right, y down).
        valid: [B, S] bool, False for segments behind the near plane (they are not drawn).
    """

    means: Tensor
    covs: Tensor
    depths: Tensor
    dirs: Tensor
    valid: Tensor


class Footprint(NamedTuple):
    """Which pixels each Gaussian touches: a list of fixed-size sheared tiles (no gradients).

    A Gaussian is walked along its "major" image axis u (x when cov_xx >= cov_yy, else y) one
    pixel column at a time; in each column the window holds ``rows`` consecutive pixels along the
    other axis v, starting at ``vstart`` (the window follows the Gaussian's slope). Columns are
    grouped ``cols`` at a time into tiles; a Gaussian that needs more than ``rows`` pixels per
    column gets several tiles stacked along v.

    Attributes:
        tile_gauss: [nt] int64 index of the Gaussian (flattened over B * S) of each tile; tiles
            are ordered along a Morton curve of the image (cache-friendly pixel access).
        u: [nt * cols] float pixel coordinate along u of each tile column (tile-major).
        vstart: [nt * cols] float v coordinate of the first window row of each column.
        colbase: [nt * cols] int64 index of each column's first window pixel in the padded
            (B, H + 2 pad, W + 2 pad) pixel buffer; off-image pixels land in the padding.
        vstride: [nt * cols] int64 index step of one pixel along v; row r of column k is pixel
            colbase[k] + r * vstride[k].
        horizontal: [G] bool, True where u = x for that Gaussian.
        rows: window height (pixels per column per tile).
        cols: tile width (columns per tile).
        pad: image padding in pixels on every side.
    """

    tile_gauss: Tensor
    u: Tensor
    vstart: Tensor
    colbase: Tensor
    vstride: Tensor
    horizontal: Tensor
    rows: int
    cols: int
    pad: int


class PixelSums(NamedTuple):
    """Per-pixel accumulators of one render, cropped to [B, H, W].

    Attributes:
        log_transmittance: sum over contributions of log(1 - alpha).
        weight: sum of compositing weights (equals 1 - exp(log_transmittance), the silhouette).
        depth: sum of w * z.
        dirs: [B, H, W, 2] sum of w * (cos 2a, sin 2a).
    """

    log_transmittance: Tensor
    weight: Tensor
    depth: Tensor
    dirs: Tensor


class StrandRender(NamedTuple):
    """Output of :func:`vid2haircut.render.render_strands`.

    Attributes:
        silhouette: [B, H, W] soft hair coverage 1 - prod(1 - alpha) in [0, 1].
        direction: [B, H, W, 2] undirected 2D strand direction as the doubled-angle unit vector
            (cos 2a, sin 2a), a in [0, pi) measured from image x towards image y (down);
            (0, 0) where no hair is drawn.
        depth: [B, H, W] composited camera z in metres, sum(w z) / sum(w); 0 where empty
            (silhouette == 0).
        depth_normalized: [B, H, W] depth min-max normalised to [0, 1] inside ``mask`` per frame,
            0 outside.
        mask: [B, H, W] bool, silhouette > 0.5.
        visibility: [B, N, P - 1] bool, True when the segment is part of the visible hair surface
            somewhere in the image (see :mod:`vid2haircut.render.raster`).
        gaussians: the screen-space Gaussians that were drawn.

    ``angle`` ([B, H, W], no gradient) is computed from ``direction`` when read: the fitting
    losses use ``direction``, and an atan2 over every pixel costs ~4.5 ms per Stage 2 render of 6
    frames at 224 x 224 (2 threads). Read it once per render (each read computes it anew).
    """

    silhouette: Tensor
    direction: Tensor
    depth: Tensor
    depth_normalized: Tensor
    mask: Tensor
    visibility: Tensor
    gaussians: Gaussians2D

    @property
    def angle(self) -> Tensor:
        """[B, H, W] a in [0, pi) of ``direction`` (0 where empty, i.e. where ``direction`` is
        (0, 0)); detached."""
        d = self.direction.detach()
        a = torch.remainder(0.5 * torch.atan2(d[..., 1], d[..., 0]), math.pi)
        drawn = (d[..., 0] != 0) | (d[..., 1] != 0)
        return torch.where(drawn & (a < math.pi - 1e-6), a, torch.zeros_like(a))
