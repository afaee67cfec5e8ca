"""Element kernels of the compositor: chunked dense math plus pixel scatters and gathers.

:mod:`vid2haircut.render.raster` wraps these in a custom autograd Function and documents the
compositing model. Inputs are per tile (one Gaussian, in its (u, v) axes): mean (mu_u, mu_v),
conic (q_uu, q_uv, q_vv), depth z, direction (c, s) = (cos 2a, sin 2a); per tile column: u and
the window start v0. Per element (Gaussian i, pixel p = (u, v0 + r), r = 0..rows-1):

    du = u - mu_u, dy = v0 + r - mu_v,
    power = log opacity - (q_uu du^2 + 2 q_uv du dy + q_vv dy^2) / 2 = P0 + r (P1 + r P2)
    alpha_i = min(exp(power), alpha_max) if alpha >= alpha_min and z_i < head(p) else 0
    l_i = log(1 - alpha_i)
    bin_i = clamp(floor((z_i - z_ref(p)) / depth_bin), 0, bins - 1)
    w_i = -M(p, bin_i) l_i            (M: :mod:`vid2haircut.render.bins`)

z_ref(p) is the smallest depth of any Gaussian whose window covers p. A contribution alone in its
bin gets w_i = T_i alpha_i exactly (front-to-back compositing); contributions sharing a bin share
its absorbed opacity in proportion to -l_i; the weights sum to the silhouette 1 - exp(sum l).
Pixel sums (channels): 0: sum l, 1: sum w z, 2: sum w cos2a, 3: sum w sin2a.

Performance notes (CPU): elements are stored row-major as [rows, columns] blocks so that every
broadcast runs along a long contiguous axis (broadcasting over a trailing axis of 4 is 10x
slower in eager PyTorch), and processed in chunks of about ``chunk`` elements so that the
temporaries stay in cache; only the per-element values the backward pass needs are stored.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from vid2haircut.render.bins import gradient_table, weight_table


class KernelConsts(NamedTuple):
    """Scalar settings of the element kernels."""

    log_opacity: float
    alpha_min: float
    alpha_max: float
    depth_bin: float  # metres
    bins: int
    vis_weight: float
    shading: bool  # False: silhouette channel only
    chunk: int = 262_144  # elements per chunk (CPU cache); use a huge value for one chunk on GPU


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


class Layout(NamedTuple):
    """Pixel layout of the tile columns (no gradients), each [nt * cols], tile-major.

    Element (column k, row r) is pixel colbase[k] + r * vstride[k] at (u[k], vstart[k] + r).
    """

    u: Tensor
    vstart: Tensor
    colbase: Tensor  # int64
    vstride: Tensor  # int64


_BIG = 1e12  # turns a positive depth gap (> 1e-12 m) into a step of 1 after clamping


def _chunks(nt: int, cols: int, rows: int, chunk: int):
    """[(first tile, end tile, first element)] covering all tiles."""
    step = max(1, chunk // (cols * rows))
    return [(a, min(nt, a + step), a * cols * rows) for a in range(0, nt, step)]


def _expand(x: Tensor, cols: int) -> Tensor:
    """[n] tile values -> [n * cols] column values (a new tensor, which the callers modify in place;
    reshaping an expanded view copies it, except when it is empty)."""
    return x.repeat_interleave(cols)


class Columns(NamedTuple):
    """Column terms, each [nt * cols]: power(r) = P0 + r (P1 + r Cq) at window row r."""

    du: Tensor
    dyc: Tensor
    B0: Tensor
    Cq: Tensor
    P0: Tensor
    P1: Tensor
    z: Tensor
    c: Tensor
    s: Tensor


def columns(t: TileParams, lay: Layout, cols: int, log_opacity: float) -> Columns:
    """Column terms of all tiles (whole-array operations, once per call)."""
    du = lay.u - _expand(t.mu, cols)
    dyc = lay.vstart - _expand(t.mv, cols)
    A0 = (du * du).mul_(_expand(t.quu, cols)).mul_(-0.5).add_(log_opacity)
    B0 = du * _expand(t.quv, cols).neg_()
    Cq = _expand(t.qvv, cols).mul_(-0.5)
    CqD = Cq * dyc
    P0 = (B0 + CqD).mul_(dyc).add_(A0)  # power at r = 0
    P1 = CqD.mul_(2.0).add_(B0)  # d power / d r at r = 0
    return Columns(du, dyc, B0, Cq, P0, P1, _expand(t.z, cols), _expand(t.c, cols), _expand(t.s, cols))


def _power(cc: Columns, ca: int, cb: int, r: Tensor) -> Tensor:
    """[rows, cb - ca] power of columns ca:cb."""
    p = r * cc.Cq[ca:cb]
    return p.add_(cc.P1[ca:cb]).mul_(r).add_(cc.P0[ca:cb])


def forward_kernel(t: TileParams, lay: Layout, rows: int, cols: int, head: Tensor | None, border: Tensor,
                   npix: int, k: KernelConsts):
    """Composite all contributions into pixel sums.

    Args:
        t: per-tile parameters, each [nt]. lay: column layout. rows, cols: tile shape.
        head: [npix] head depth (+inf: none) or None. border: [npix] bool, True on the padding.
        npix: padded pixel count.

    Returns:
        (sums [npix, 4] (or [npix, 1] without shading), visible_tile [nt] bool or None, saved).
    """
    nt = t.mu.shape[0]
    dev, dt = t.mu.device, t.mu.dtype
    T = nt * cols * rows
    r = torch.arange(rows, device=dev, dtype=dt)[:, None]
    ri = torch.arange(rows, device=dev)[:, None]
    pix = torch.empty(T, dtype=torch.int64, device=dev)
    alpha = torch.empty(T, dtype=dt, device=dev)
    la = torch.empty(T, dtype=dt, device=dev)
    cc = columns(t, lay, cols, k.log_opacity)
    zs = cc.z * (1.0 / k.depth_bin)
    logt = None if k.shading else torch.zeros(npix, dtype=dt, device=dev)
    zref = torch.full((npix,), float("inf"), dtype=dt, device=dev) if k.shading else None
    chunks = _chunks(nt, cols, rows, k.chunk)
    for a, b, e in chunks:  # pass 1: alpha, log(1 - alpha), z_ref
        n = (b - a) * cols
        ca, cb, eb = a * cols, b * cols, e + n * rows
        px = torch.mul(ri, lay.vstride[ca:cb], out=pix[e:eb].view(rows, n)).add_(lay.colbase[ca:cb]).view(-1)
        al = torch.exp(_power(cc, ca, cb, r), out=alpha[e:eb].view(rows, n)).clamp_max_(k.alpha_max)
        torch.nn.functional.threshold_(al, k.alpha_min, 0.0)
        if head is not None:
            gap = head.index_select(0, px).view(rows, n).sub_(cc.z[ca:cb])
            al.mul_(gap.mul_(_BIG).clamp_(0.0, 1.0))  # 0 where the head is in front
        torch.log1p(al.neg(), out=la[e:eb].view(rows, n))
        if k.shading:
            zref.scatter_reduce_(0, px, zs[ca:cb].expand(rows, n).reshape(-1), "amin")
        else:
            logt.scatter_add_(0, px, la[e:eb])
    if not k.shading:
        return logt[:, None], None, (*cc, pix, alpha)

    pb = torch.empty(T, dtype=torch.int64, device=dev)
    Lb = torch.zeros(npix * k.bins, dtype=dt, device=dev)
    for a, b, e in chunks:  # pass 2: depth bins (table [bins, npix]: bin planes stay cache friendly)
        n, ca = (b - a) * cols, a * cols
        eb = e + n * rows
        px = pix[e:eb]
        binf = zref.index_select(0, px).view(rows, n).neg_().add_(zs[ca:ca + n]).clamp_(0.0, k.bins - 1.0)
        pbc = torch.mul(binf.view(-1).to(torch.int64), npix, out=pb[e:eb]).add_(px)
        Lb.scatter_add_(0, pbc, la[e:eb])
    Lb = Lb.view(k.bins, npix)
    negM = weight_table(Lb, border).view(-1)

    Mel = torch.empty_like(alpha)
    sums = torch.zeros(4, npix, dtype=dt, device=dev)
    sums[0] = Lb.sum(0)
    visible = torch.empty(nt, dtype=torch.bool, device=dev)
    for a, b, e in chunks:  # pass 3: weights and shading channels
        n = (b - a) * cols
        eb = e + n * rows
        px = pix[e:eb]
        w = torch.index_select(negM, 0, pb[e:eb], out=Mel[e:eb]).mul(la[e:eb]).view(rows, n)
        ca = a * cols
        for ch, val in ((1, cc.z), (2, cc.c), (3, cc.s)):
            sums[ch].scatter_add_(0, px, (w * val[ca:ca + n]).view(-1))
        visible[a:b] = w.amax(0).view(b - a, cols).amax(1) >= k.vis_weight
    return sums.t(), visible, (*cc, pix, alpha, la, pb, Mel, Lb, negM.view(k.bins, npix))


def backward_kernel(grad: Tensor, t: TileParams, lay: Layout, rows: int, cols: int, border: Tensor,
                    saved: tuple, npix: int, k: KernelConsts) -> TileParams:
    """Gradients of the pixel sums w.r.t. the tile parameters.

    Args:
        grad: [npix, 4] (or [npix, 1]) upstream gradient of ``sums``; the other arguments as given
            to :func:`forward_kernel`; saved: its saved tensors.

    Returns:
        :class:`TileParams` of gradients, each [nt] (z, c, s None without shading).
    """
    nt = t.mu.shape[0]
    dev, dt = t.mu.device, t.mu.dtype
    chunks = _chunks(nt, cols, rows, k.chunk)
    grad = grad.t().contiguous()
    g_logt = grad[0]
    gz = gc = gs = None
    cc = Columns(*saved[:9])
    saved = saved[9:]
    if k.shading:
        pix, alpha, la, pb, Mel, Lb, negM = saved
        gz, gc, gs = (torch.empty(nt, dtype=dt, device=dev) for _ in range(3))
        q = torch.empty_like(alpha)
        G = torch.zeros(npix * k.bins, dtype=dt, device=dev)
        for a, b, e in chunks:  # pass A: d loss / d w per element, and its bin sums
            n = (b - a) * cols
            eb = e + n * rows
            px = pix[e:eb]
            w = (Mel[e:eb] * la[e:eb]).view(rows, n)
            qc = q[e:eb].view(rows, n)
            qc.zero_()
            ca = a * cols
            for val, out, gi in ((cc.z, gz, 1), (cc.c, gc, 2), (cc.s, gs, 3)):
                g = grad[gi].index_select(0, px).view(rows, n)
                qc.addcmul_(g, val[ca:ca + n])
                out[a:b] = (g.mul_(w)).sum(0).view(b - a, cols).sum(1)
            G.scatter_add_(0, pb[e:eb], qc.view(-1) * la[e:eb])
        H = gradient_table(Lb, negM, G.view(k.bins, npix), g_logt).view(-1)
    else:
        pix, alpha = saved

    r = torch.arange(rows, device=dev, dtype=dt)[:, None]
    r2 = r * r
    S0, S1, S2 = (torch.empty(nt * cols, dtype=dt, device=dev) for _ in range(3))
    for a, b, e in chunks:  # pass B: d loss / d power, as moments over the window rows
        n, ca = (b - a) * cols, a * cols
        eb = e + n * rows
        if k.shading:
            gla = H.index_select(0, pb[e:eb]).addcmul_(q[e:eb], Mel[e:eb])  # d w / d l = -M = Mel
        else:
            gla = g_logt.index_select(0, pix[e:eb])
        al = alpha[e:eb]
        # d l / d power = alpha / (alpha - 1) where alpha is neither clamped (step 0) nor dropped (alpha 0)
        step = (k.alpha_max - al).mul_(_BIG).clamp_(0.0, 1.0)
        gp = gla.mul_(al).div_(al - 1.0).mul_(step).view(rows, n)
        torch.sum(gp, 0, out=S0[ca:ca + n])
        torch.sum(gp * r, 0, out=S1[ca:ca + n])
        torch.sum(gp.mul_(r2), 0, out=S2[ca:ca + n])
    # power = A0 + dy (B0 + Cq dy), dy = dyc + r; A0 = -q_uu du^2 / 2 + log op, B0 = -q_uv du, Cq = -q_vv / 2
    gA0 = S0
    gB0 = cc.dyc * S0 + S1  # sum gp dy
    gCq = (cc.dyc * cc.dyc).mul_(S0).add_(cc.dyc * S1, alpha=2.0).add_(S2)  # sum gp dy^2
    gdyc = cc.B0 * gA0 + 2.0 * cc.Cq * gB0  # d power / d dy = B0 + 2 Cq dy
    gdu = (_expand(t.quu, cols) * cc.du * gA0).add_(_expand(t.quv, cols) * gB0).neg_()

    def tile_sum(x: Tensor) -> Tensor:
        return x.view(nt, cols).sum(1)

    return TileParams(-tile_sum(gdu), -tile_sum(gdyc), -0.5 * tile_sum(gA0 * cc.du * cc.du), -tile_sum(gB0 * cc.du),
                      -0.5 * tile_sum(gCq), gz, gc, gs)
