"""Element kernels of the compositor: dense [tiles, cols, rows] math plus pixel scatters/gathers.

Plain tensor functions (no autograd inside), so they can run eagerly or through ``torch.compile``;
:mod:`vid2haircut.render.raster` wraps them in a custom autograd Function and documents the
compositing model. Per element (Gaussian i, pixel p):

    dy = v_p - mu_v,  power = A0 + dy (B0 + Cq dy)   (log opacity - m/2, column terms folded)
    alpha_i = min(exp(power), alpha_max) if power >= log alpha_min and z_i < head(p) else 0
    l_i = log(1 - alpha_i)
    bin_i = clamp(floor((z_i - z_ref(p)) / depth_bin), 0, bins - 1),  z_ref(p) = min z at p
    Lb(p, b) = sum_{i at p in bin b} l_i,  Lx(p, b) = sum_{b' < b} Lb(p, b')
    M(p, b) = exp(Lx) * F(Lb),  F(L) = expm1(L) / L,  w_i = M(p, bin_i) * (-l_i)

A single contribution in its bin gets w_i = T_i * alpha_i exactly (front-to-back compositing);
contributions sharing a bin share its absorbed opacity in proportion to -l_i. The weights sum to
1 - exp(sum l) = the silhouette at every pixel. Pixel sums (channels):
0: sum l, 1: sum w z, 2: sum w cos2a, 3: sum w sin2a.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor


class KernelConsts(NamedTuple):
    """Scalar settings of the element kernels."""

    log_opacity: float
    alpha_min: float
    alpha_max: float
    depth_bin: float  # metres
    bins: int
    vis_weight: float
    shading: bool  # False: silhouette channel only


class TileParams(NamedTuple):
    """Per-tile Gaussian parameters (differentiable), each [nt]."""

    mu: Tensor
    mv: Tensor
    quu: Tensor
    quv: Tensor
    qvv: Tensor
    z: Tensor
    c: Tensor
    s: Tensor


def _columns(t: TileParams, u: Tensor, vstart: Tensor, log_opacity: float):
    """Column terms -> (du, dyc, A0, B0) each [nt, cols] and Cq [nt]."""
    du = u - t.mu[:, None]
    dyc = vstart - t.mv[:, None]
    A0 = (-0.5 * t.quu[:, None]) * du * du + log_opacity
    B0 = -t.quv[:, None] * du
    return du, dyc, A0, B0, -0.5 * t.qvv


def _alpha(A0: Tensor, B0: Tensor, dyc: Tensor, Cq: Tensor, z: Tensor, pix: Tensor, head: Tensor | None,
           k: KernelConsts) -> tuple[Tensor, Tensor]:
    """-> (dy, alpha), each [nt, cols, rows]."""
    r = torch.arange(pix.shape[2], device=dyc.device, dtype=dyc.dtype)
    dy = dyc[:, :, None] + r
    power = A0[:, :, None] + dy * (B0[:, :, None] + Cq[:, None, None] * dy)
    if head is not None:
        power.masked_fill_(z[:, None, None] >= head[pix], float("-inf"))
    alpha = torch.exp(power).clamp_max_(k.alpha_max)
    return dy, torch.nn.functional.threshold(alpha, k.alpha_min, 0.0)


def _dalpha(alpha: Tensor, k: KernelConsts) -> Tensor:
    """d alpha / d power: alpha where it is neither clamped nor dropped, else 0."""
    return torch.where(alpha < k.alpha_max, alpha, torch.zeros((), dtype=alpha.dtype, device=alpha.device))


def _bin_factor(Lb: Tensor) -> tuple[Tensor, Tensor]:
    """F(L) = expm1(L) / L and F'(L), stable near L = 0 (L <= 0)."""
    small = Lb > -1e-4
    Ls = torch.where(small, torch.full_like(Lb, -1.0), Lb)
    em1 = torch.expm1(Ls)
    F = torch.where(small, 1.0 + Lb * (0.5 + Lb / 6.0), em1 / Ls)
    dF = torch.where(small, 0.5 + Lb / 3.0, (Ls * (em1 + 1.0) - em1) / (Ls * Ls))
    return F, dF


def _bin_tables(Lb: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """[npix, bins] bin sums -> (exp(Lx), F(Lb), F'(Lb))."""
    ELx = torch.exp(torch.cumsum(Lb, 1) - Lb)
    F, dF = _bin_factor(Lb)
    return ELx, F, dF


def forward_kernel(t: TileParams, u: Tensor, vstart: Tensor, pix: Tensor, head: Tensor | None, border: Tensor,
                   npix: int, k: KernelConsts):
    """Composite all contributions into pixel sums.

    Args:
        t: per-tile parameters, each [nt]. u, vstart: [nt, cols] column coordinates.
        pix: [nt, cols, rows] int64 pixel index. head: [npix] head depth (+inf: none) or None.
        border: [npix] bool, True on the image padding. npix: padded pixel count.

    Returns:
        (sums [npix, 4] (or [npix, 1] without shading), visible_tile [nt] bool or None, saved).
    """
    z, c, s = t.z, t.c, t.s
    du, dyc, A0, B0, Cq = _columns(t, u, vstart, k.log_opacity)
    dy, alpha = _alpha(A0, B0, dyc, Cq, z, pix, head, k)
    flat = pix.reshape(-1)
    nla = torch.log1p(alpha.neg()).neg_()  # -log(1 - alpha) >= 0
    if not k.shading:
        sums = torch.zeros(npix, 1, dtype=alpha.dtype, device=alpha.device)
        sums[:, 0].scatter_add_(0, flat, nla.reshape(-1)).neg_()
        return sums, None, (du, dy, alpha)
    z3 = z[:, None, None]
    # z_ref(p): nearest Gaussian whose window covers p (a lower bound of every contributing z)
    zs = z * (1.0 / k.depth_bin)
    zref = torch.full((npix,), float("inf"), dtype=alpha.dtype, device=alpha.device)
    zref.scatter_reduce_(0, flat, zs[:, None, None].expand_as(alpha).reshape(-1), "amin")
    binf = (zs[:, None, None] - zref[pix]).clamp_(0.0, k.bins - 1.0)
    pb = pix * k.bins + binf.to(torch.int64)  # index into the [npix, bins] table
    Lb = torch.zeros(npix * k.bins, dtype=alpha.dtype, device=alpha.device)
    Lb.scatter_add_(0, pb.reshape(-1), nla.reshape(-1))
    Lb = Lb.reshape(npix, k.bins).neg_()
    ELx, F, _ = _bin_tables(Lb)
    M = (ELx * F).masked_fill_(border[:, None], 0.0)
    Mel = M.reshape(-1)[pb]
    w = Mel * nla
    sums = torch.zeros(4, npix, dtype=alpha.dtype, device=alpha.device)
    sums[0] = Lb.sum(1)
    sums[1].scatter_add_(0, flat, (w * z3).reshape(-1))
    sums[2].scatter_add_(0, flat, (w * c[:, None, None]).reshape(-1))
    sums[3].scatter_add_(0, flat, (w * s[:, None, None]).reshape(-1))
    visible = (w >= k.vis_weight).flatten(1).any(1)
    return sums.t(), visible, (du, dy, alpha, nla, Mel, pb, Lb)


def backward_kernel(grad: Tensor, t: TileParams, pix: Tensor, border: Tensor, saved: tuple, npix: int,
                    k: KernelConsts) -> TileParams:
    """Gradients of the pixel sums w.r.t. the tile parameters.

    Args:
        grad: [npix, 4] (or [npix, 1]) upstream gradient of ``sums``; t, pix, border, npix, k as
            given to :func:`forward_kernel`; saved: its saved tensors.

    Returns:
        :class:`TileParams` of gradients, each [nt] (z, c, s None without shading).
    """
    z, c, s = t.z, t.c, t.s
    if not k.shading:
        du, dy, alpha = saved
        gla = grad[:, 0][pix]
        gz = gc = gs = None
    else:
        du, dy, alpha, nla, Mel, pb, Lb = saved
        grad = grad.t()
        gZ, gC, gS = grad[1][pix], grad[2][pix], grad[3][pix]
        w = Mel * nla
        q = gZ * z[:, None, None] + gC * c[:, None, None] + gS * s[:, None, None]
        gz = (gZ * w).sum((1, 2))
        gc = (gC * w).sum((1, 2))
        gs = (gS * w).sum((1, 2))
        G = torch.zeros(npix * k.bins, dtype=w.dtype, device=w.device)
        G.scatter_add_(0, pb.reshape(-1), (q * nla).reshape(-1))
        G = G.reshape(npix, k.bins)
        ELx, F, dF = _bin_tables(Lb)
        GM = (G * ELx * F).masked_fill_(border[:, None], 0.0)
        H = grad[0][:, None] + (GM.sum(1, keepdim=True) - torch.cumsum(GM, 1))
        H = H + (G * ELx * dF).masked_fill_(border[:, None], 0.0)
        gla = H.reshape(-1)[pb] - q * Mel
    gp = gla * (_dalpha(alpha, k) / (alpha - 1.0))
    # power = A0 + dy (B0 + Cq dy); A0 = -q_uu du^2 / 2 + log op, B0 = -q_uv du, Cq = -q_vv / 2
    gA0 = gp.sum(2)
    gpdy = gp * dy
    gB0 = gpdy.sum(2)
    gCq = (gpdy * dy).sum((1, 2))
    B0 = -t.quv[:, None] * du
    gdyc = B0 * gA0 + 2.0 * (-0.5 * t.qvv)[:, None] * gB0
    gdu = -(t.quu[:, None] * du * gA0 + t.quv[:, None] * gB0)
    return TileParams(-gdu.sum(1), -gdyc.sum(1), -0.5 * (gA0 * du * du).sum(1), -(gB0 * du).sum(1), -0.5 * gCq,
                      gz, gc, gs)
