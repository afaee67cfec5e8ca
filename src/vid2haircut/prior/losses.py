"""Training losses and input augmentation of the hair prior.

The point loss decodes the predicted and the target coefficients of a random subset of scalp
texels with the strand codec and compares the strand points (the roots are shared, so only the
root-relative offsets matter); it counts only hair-bearing texels of the target. The optional
standoff term compares the same points' distances from the head surface: where a view leaves the
hairstyle open, the point term's best answer is a middle strand, and the middle of strands that wrap
round the head at different angles lies closer to the head than any of them (hair predicted too
flat); the standoff term asks for the targets' distance from the head whatever the direction.
Measured, it does not fill the fits' thin upper back and makes Stage 1 worse, so the bundled prior
is trained without it (``benchmarks/RESULTS.md``, "How full the hair is").
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import torch
import torch.nn.functional as F

from vid2haircut.prior.codec import StrandCodec

__all__ = ["LossWeights", "LossTerms", "prior_losses", "augment"]


class LossWeights(NamedTuple):
    """Weights of the loss terms.

    Attributes:
        points: weight of the decoded point error (in cm).
        coef: weight of the coefficient L2.
        mask: weight of the baldness BCE.
        n_texels: texels per view entering the point loss.
        standoff: weight of the error in distance from the head surface of the same points (in cm).
    """

    points: float = 1.0
    coef: float = 0.1
    mask: float = 1.0
    n_texels: int = 128
    standoff: float = 0.0


class LossTerms(NamedTuple):
    """Loss terms of one batch (scalar tensors).

    Attributes:
        total: weighted sum.
        points_cm: mean distance between decoded predicted and target strand points, cm.
        coef: mean squared coefficient error on the valid scalp texels.
        mask_bce: baldness BCE on the valid scalp texels.
        standoff_cm: mean difference in distance from the head surface of the decoded predicted and
            target points, cm (0 without ``roots`` and ``sdf``).
    """

    total: torch.Tensor
    points_cm: torch.Tensor
    coef: torch.Tensor
    mask_bce: torch.Tensor
    standoff_cm: torch.Tensor


def prior_losses(z: torch.Tensor, logits: torch.Tensor, z_t: torch.Tensor, mask_t: torch.Tensor,
                 valid_index: torch.Tensor, codec: StrandCodec, weights: LossWeights = LossWeights(),
                 generator: torch.Generator | None = None, roots: torch.Tensor | None = None,
                 sdf: Callable[[torch.Tensor], torch.Tensor] | None = None) -> LossTerms:
    """Loss of predicted maps against target maps.

    Args:
        z, z_t: (B,K,R,R) predicted / target coefficient maps.
        logits: (B,R,R) predicted baldness logits; mask_t: (B,R,R) target mask in {0,1}.
        valid_index: (Nv,) int64 row-major indices of the scalp texels.
        codec: the strand codec (decodes the point loss' texels).
        weights: loss weights and texel count.
        generator: draws the texel subset (on ``z``'s device).
        roots: (Nv,3) root points of the valid texels (in ``valid_index`` order) and ``sdf`` the
            head's signed distance ((...,3) -> (...,)): both needed for the standoff term.

    Returns:
        :class:`LossTerms`.
    """
    b = z.shape[0]
    zf, ztf = z.flatten(2)[..., valid_index], z_t.flatten(2)[..., valid_index]   # (B,K,Nv)
    mf, lf = mask_t.flatten(1)[:, valid_index], logits.flatten(1)[:, valid_index]  # (B,Nv)
    coef = (zf - ztf).square().mean()
    bce = F.binary_cross_entropy_with_logits(lf, mf)
    n = min(int(weights.n_texels), zf.shape[-1])
    pick = torch.randint(zf.shape[-1], (b, n), generator=generator, device=z.device)
    zs = torch.gather(zf, 2, pick[:, None].expand(-1, zf.shape[1], -1)).transpose(1, 2)   # (B,n,K)
    zts = torch.gather(ztf, 2, pick[:, None].expand(-1, zf.shape[1], -1)).transpose(1, 2)
    w = torch.gather(mf, 1, pick)                                                      # (B,n)
    off, off_t = codec.decode_offsets(zs), codec.decode_offsets(zts)                  # (B,n,P-1,3)
    dist = (off - off_t).norm(dim=-1).mean(-1)                                         # (B,n) m
    points = 100.0 * (dist * w).sum() / w.sum().clamp_min(1.0)
    total = weights.points * points + weights.coef * coef + weights.mask * bce
    standoff = torch.zeros((), dtype=points.dtype, device=points.device)
    if roots is not None and sdf is not None:
        root = roots[pick][:, :, None]                                                 # (B,n,1,3)
        gap = (sdf(root + off) - sdf(root + off_t)).abs().mean(-1)                     # (B,n) m
        standoff = 100.0 * (gap * w).sum() / w.sum().clamp_min(1.0)
        total = total + weights.standoff * standoff
    return LossTerms(total, points, coef, bce, standoff)


def augment(x: torch.Tensor, shift_px: int, depth_dropout: float, g: torch.Generator) -> torch.Tensor:
    """Random shifts (zero fill, up to ``shift_px``) and depth-channel dropout (probability
    ``depth_dropout``: channels 3-4 zeroed) of a (B,C,S,S) batch; draws from ``g``."""
    b, _, s, _ = x.shape
    if shift_px > 0:
        p = int(shift_px)
        padded = F.pad(x, (p, p, p, p))
        off = torch.randint(0, 2 * p + 1, (b, 2), generator=g, device=x.device).tolist()
        x = torch.stack([padded[i, :, oy:oy + s, ox:ox + s] for i, (oy, ox) in enumerate(off)])
    if depth_dropout > 0:
        drop = torch.rand(b, generator=g, device=x.device) < depth_dropout
        x = x.clone()
        x[drop, 3:5] = 0.0
    return x
