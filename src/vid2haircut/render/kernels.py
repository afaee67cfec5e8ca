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

    log_alpha_min: float
    alpha_max: float
    depth_bin: float  # metres
    bins: int
    vis_weight: float
    shading: bool  # False: silhouette channel only


def _alpha(A0: Tensor, B0: Tensor, dyc: Tensor, Cq: Tensor, z: Tensor, pix: Tensor, head: Tensor | None,
           k: KernelConsts) -> tuple[Tensor, Tensor, Tensor]:
    """-> (dy, alpha, d alpha / d power) each [nt, cols, rows]."""
    r = torch.arange(pix.shape[2], device=dyc.device, dtype=dyc.dtype)
    dy = dyc[:, :, None] + r
    power = A0[:, :, None] + dy * (B0[:, :, None] + Cq[:, None, None] * dy)
    keep = power >= k.log_alpha_min
    if head is not None:
        keep &= z[:, None, None] < head[pix]
    ex = torch.exp(power)
    zero = torch.zeros((), dtype=ex.dtype, device=ex.device)
    alpha = torch.where(keep, ex.clamp_max(k.alpha_max), zero)
    dalpha = torch.where(keep & (ex < k.alpha_max), ex, zero)
    return dy, alpha, dalpha


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


def forward_kernel(A0: Tensor, B0: Tensor, dyc: Tensor, Cq: Tensor, z: Tensor, c: Tensor, s: Tensor,
                   pix: Tensor, head: Tensor | None, ring: Tensor, npix: int, k: KernelConsts):
    """Composite all contributions into pixel sums.

    Args:
        A0, B0, dyc: [nt, cols] column terms. Cq, z, c, s: [nt] tile terms.
        pix: [nt, cols, rows] int64 pixel index. head: [npix] head depth (+inf: none) or None.
        ring: [npix] bool, True on the padding ring. npix: padded pixel count.

    Returns:
        (sums [npix, 4] (or [npix, 1] without shading), visible_tile [nt] bool or None, saved).
    """
    dy, alpha, dalpha = _alpha(A0, B0, dyc, Cq, z, pix, head, k)
    flat = pix.reshape(-1)
    la = torch.log1p(-alpha)
    if not k.shading:
        sums = torch.zeros(npix, 1, dtype=alpha.dtype, device=alpha.device)
        sums[:, 0].scatter_add_(0, flat, la.reshape(-1))
        return sums, None, (dy, alpha, dalpha)
    z3 = z[:, None, None]
    inf = torch.full((), float("inf"), dtype=alpha.dtype, device=alpha.device)
    zref = torch.full((npix,), float("inf"), dtype=alpha.dtype, device=alpha.device)
    zref.scatter_reduce_(0, flat, torch.where(alpha > 0, z3, inf).reshape(-1), "amin")
    binf = ((z3 - zref[pix]) * (1.0 / k.depth_bin)).clamp_(0.0, k.bins - 1.0)
    pb = pix * k.bins + binf.to(torch.int64)  # index into the [npix, bins] table
    Lb = torch.zeros(npix * k.bins, dtype=alpha.dtype, device=alpha.device)
    Lb.scatter_add_(0, pb.reshape(-1), la.reshape(-1))
    Lb = Lb.reshape(npix, k.bins)
    ELx, F, _ = _bin_tables(Lb)
    M = (ELx * F).masked_fill_(ring[:, None], 0.0)
    Mel = M.reshape(-1)[pb]
    w = Mel * (-la)
    vals = torch.stack([w * z3, w * c[:, None, None], w * s[:, None, None]], dim=-1)
    sums = torch.zeros(npix, 4, dtype=alpha.dtype, device=alpha.device)
    sums[:, 0] = Lb.sum(1)
    sums[:, 1:].index_add_(0, flat, vals.reshape(-1, 3))
    visible = (w >= k.vis_weight).flatten(1).any(1)
    return sums, visible, (dy, alpha, dalpha, la, Mel, pb, Lb)


def backward_kernel(grad: Tensor, B0: Tensor, Cq: Tensor, z: Tensor, c: Tensor, s: Tensor, pix: Tensor,
                    ring: Tensor, saved: tuple, npix: int, k: KernelConsts):
    """Gradients of the pixel sums w.r.t. the kernel inputs.

    Args:
        grad: [npix, 4] (or [npix, 1]) upstream gradient of ``sums``.

    Returns:
        (gA0, gB0, gdyc) each [nt, cols]; (gCq, gz, gc, gs) each [nt] (gz, gc, gs None without shading).
    """
    if not k.shading:
        dy, alpha, dalpha = saved
        gp = -grad[:, 0][pix] / (1.0 - alpha) * dalpha
        gz = gc = gs = None
    else:
        dy, alpha, dalpha, la, Mel, pb, Lb = saved
        g = grad[:, 1:][pix]  # [nt, cols, rows, 3]
        gZ, gC, gS = g.unbind(-1)
        w = Mel * (-la)
        z3 = z[:, None, None]
        q = gZ * z3 + gC * c[:, None, None] + gS * s[:, None, None]
        gz = (gZ * w).sum((1, 2))
        gc = (gC * w).sum((1, 2))
        gs = (gS * w).sum((1, 2))
        G = torch.zeros(npix * k.bins, dtype=w.dtype, device=w.device)
        G.scatter_add_(0, pb.reshape(-1), (q * (-la)).reshape(-1))
        G = G.reshape(npix, k.bins)
        ELx, F, dF = _bin_tables(Lb)
        GM = (G * ELx * F).masked_fill_(ring[:, None], 0.0)
        H = grad[:, :1] + (GM.sum(1, keepdim=True) - torch.cumsum(GM, 1))
        H = H + (G * ELx * dF).masked_fill_(ring[:, None], 0.0)
        gla = H.reshape(-1)[pb] - q * Mel
        gp = -gla / (1.0 - alpha) * dalpha
    gA0 = gp.sum(2)
    gpdy = gp * dy
    gB0 = gpdy.sum(2)
    gCq = (gpdy * dy).sum((1, 2))
    gdyc = B0 * gA0 + 2.0 * Cq[:, None] * gB0
    return gA0, gB0, gdyc, gCq, gz, gc, gs
