"""Per-pixel depth-bin tables of the compositor ([bins, npix], independent of the Gaussian count).

With Lb(p, b) the sum of log(1 - alpha) of the contributions of pixel p in depth bin b and
Lx(p, b) = sum_{b' < b} Lb(p, b') the log transmittance in front of the bin:

    M(p, b) = exp(Lx) F(Lb),  F(L) = expm1(L) / L  (F(0) = 1),

and a contribution i of bin b gets the compositing weight w_i = -M(p, b) log(1 - alpha_i).
"""

from __future__ import annotations

import torch
from torch import Tensor

def weight_table(Lb: Tensor, border: Tensor) -> Tensor:
    """-M(b, p), [bins, npix]; 0 on the image padding (``border`` [npix] bool)."""
    Lc = Lb.clamp_max(-1e-7)  # F(L) = expm1(L) / L; F(-1e-7) = 1 to float32 precision
    F = torch.expm1(Lc).div_(Lc)
    c = torch.cumsum(Lb, 0).sub_(Lb).exp_()  # exp(Lx), transmittance in front of the bin
    return c.mul_(F).neg_().masked_fill_(border[None], 0.0)


def gradient_table(Lb: Tensor, negM: Tensor, G: Tensor, g_logt: Tensor) -> Tensor:
    """d loss / d Lb(b, p), [bins, npix].

    Args:
        Lb: [bins, npix] bin sums of log(1 - alpha). negM: [bins, npix] from :func:`weight_table`.
        G: [bins, npix] sum over the bin's contributions of (d loss / d w_i) log(1 - alpha_i)
            (= -(d loss / d M), since w_i = -M l_i).
        g_logt: [npix] d loss / d (sum of all log(1 - alpha)) at the pixel (silhouette channel).

    d M / d Lx = M and d M / d Lb = M R(Lb) with R = F'/F = e^L / expm1(L) - 1/L
    (series 1/2 + L/12 near 0).
    """
    GM = G * negM  # d loss / d Lx(b, p) = (d loss / d M) M; Lx(b, p) sums the bins before b
    behind = GM.sum(0, keepdim=True) - torch.cumsum(GM, 0)
    Lc = Lb.clamp_max(-1e-2)
    R = torch.where(Lb > -1e-2, Lb * (1.0 / 12.0) + 0.5, torch.exp(Lc).div_(torch.expm1(Lc)).sub_(Lc.reciprocal()))
    return behind.add_(GM.mul_(R)).add_(g_logt[None])
