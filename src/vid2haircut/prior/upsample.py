"""Dense hair from a guide map (the HAAR scheme used by Im2Haircut / Vid2Haircut).

At any scalp UV the dense strand blends the *nearest* guide and the *bilinear* interpolation of
the four surrounding guides: ``strand = w(s) * nearest + (1 - w(s)) * bilinear`` with ``s`` the mean
cosine similarity of neighbouring guides' segment vectors and
``w(s) = 1 - 1.63 s^5`` for ``s <= 0.9``, ``0.4 - 0.4 s`` above (clamped to [0, 1]): similar
neighbours are interpolated smoothly, dissimilar ones (partings, clumps) keep the nearest guide.
The codec decode is affine in the coefficients with a shared mean, so blending coefficients and
decoding at the dense root equals blending the decoded root-relative strands.

Evaluating the nearest / bilinear interpolants at the exact (jittered) UV of each dense root is the
continuous form of "upsample the map, then pick texels"; the upsampled map only decides which
scalp texels carry hair (the mask test).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F

__all__ = ["blend_weight", "NeighbourSimilarity", "neighbour_similarity", "MapSamples", "sample_map",
           "systematic_texel_samples"]


def blend_weight(s: torch.Tensor) -> torch.Tensor:
    """HAAR nearest-vs-bilinear weight ``w(s)`` (weight of the nearest guide).

    Args:
        s: (...) mean cosine similarity in [-1, 1].

    Returns:
        (...) ``1 - 1.63 s^5`` where ``s <= 0.9``, else ``0.4 - 0.4 s``; clamped to [0, 1] (negative
        similarities would otherwise extrapolate past the nearest guide).
    """
    return torch.where(s <= 0.9, 1.0 - 1.63 * s ** 5, 0.4 - 0.4 * s).clamp(0.0, 1.0)


class NeighbourSimilarity(NamedTuple):
    """Cosine similarities of neighbouring guides on an (H,W) map.

    Attributes:
        horizontal: (H,W-1) mean segment cosine of texels [i,j] and [i,j+1].
        vertical: (H-1,W) mean segment cosine of texels [i,j] and [i+1,j].
        horizontal_weight: (H,W-1) 1 where both texels are hair-bearing guides, else 0.
        vertical_weight: (H-1,W) same for vertical pairs.
    """

    horizontal: torch.Tensor
    vertical: torch.Tensor
    horizontal_weight: torch.Tensor
    vertical_weight: torch.Tensor


def _segment_cosine(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """Mean over segments of the cosine between segment vectors: (...,S,3) x2 -> (...)."""
    dot = (a * b).sum(-1)
    return (dot / (a.norm(dim=-1) * b.norm(dim=-1)).clamp_min(eps)).mean(-1)


def neighbour_similarity(offsets: torch.Tensor, guide: torch.Tensor) -> NeighbourSimilarity:
    """Similarity of each guide with its right and lower neighbour.

    Args:
        offsets: (H,W,P-1,3) root-relative offsets of the decoded guide of every texel.
        guide: (H,W) bool, texels that hold a hair-bearing guide.

    Returns:
        :class:`NeighbourSimilarity`.
    """
    zero = offsets.new_zeros(*offsets.shape[:2], 1, 3)
    seg = torch.diff(torch.cat([zero, offsets], dim=-2), dim=-2)         # (H,W,P-1,3)
    g = guide.to(offsets.dtype)
    return NeighbourSimilarity(_segment_cosine(seg[:, :-1], seg[:, 1:]),
                               _segment_cosine(seg[:-1], seg[1:]),
                               g[:, :-1] * g[:, 1:], g[:-1] * g[1:])


class MapSamples(NamedTuple):
    """A map evaluated at M UV positions.

    Attributes:
        z_nearest: (M,K) coefficients of the texel containing each UV.
        z_bilinear: (M,K) bilinear interpolation of the coefficients (border-clamped).
        mask: (M,) bilinear interpolation of the baldness mask.
        similarity: (M,) mean cosine similarity over the (up to 4) hair-bearing guide pairs on the
            edges of the bilinear cell around each UV; 1 where the cell has none.
        weight: (M,) ``blend_weight(similarity)``.
    """

    z_nearest: torch.Tensor
    z_bilinear: torch.Tensor
    mask: torch.Tensor
    similarity: torch.Tensor
    weight: torch.Tensor

    def blended(self) -> torch.Tensor:
        """(M,K) ``w * z_nearest + (1 - w) * z_bilinear``."""
        w = self.weight[:, None]
        return w * self.z_nearest + (1.0 - w) * self.z_bilinear


def sample_map(z: torch.Tensor, mask: torch.Tensor, sim: NeighbourSimilarity,
               uv: torch.Tensor) -> MapSamples:
    """Evaluate nearest and bilinear interpolants of a map at UV positions.

    Args:
        z: (K,H,W) coefficient map.
        mask: (H,W) baldness mask in [0, 1].
        sim: neighbour similarities of the map's guides (H,W >= 2).
        uv: (M,2) UV in [0,1]^2 (u along columns / W, v along rows / H).

    Returns:
        :class:`MapSamples`; ``z_nearest`` and ``z_bilinear`` are differentiable w.r.t. ``z``.
    """
    k, h, w = z.shape
    uv = uv.to(z)
    grid = (2.0 * uv - 1.0)[None, None]                                 # (1,1,M,2) x=u, y=v
    zb = F.grid_sample(z[None], grid, mode="bilinear", padding_mode="border", align_corners=False)
    mb = F.grid_sample(mask.to(z)[None, None], grid, mode="bilinear", padding_mode="border",
                       align_corners=False)
    col = (uv[:, 0] * w).floor().long().clamp(0, w - 1)
    row = (uv[:, 1] * h).floor().long().clamp(0, h - 1)
    zn = z[:, row, col].T                                                # (M,K)
    # bilinear cell: corners (i0,j0) .. (i0+1,j0+1)
    j0 = (uv[:, 0] * w - 0.5).floor().long().clamp(0, w - 2)
    i0 = (uv[:, 1] * h - 0.5).floor().long().clamp(0, h - 2)
    sh, sv, wh, wv = (t.to(z) for t in sim)
    s_sum = (sh[i0, j0] * wh[i0, j0] + sh[i0 + 1, j0] * wh[i0 + 1, j0]
             + sv[i0, j0] * wv[i0, j0] + sv[i0, j0 + 1] * wv[i0, j0 + 1])
    w_sum = wh[i0, j0] + wh[i0 + 1, j0] + wv[i0, j0] + wv[i0, j0 + 1]
    s = torch.where(w_sum > 0, s_sum / w_sum.clamp_min(1e-12), torch.ones_like(s_sum))
    return MapSamples(zn, zb[0, :, 0].T, mb[0, 0, 0], s, blend_weight(s))


def systematic_texel_samples(keep: np.ndarray, weights: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Deterministic, low-variance sampling of ``n`` jittered UVs over the kept texels of a grid.

    Texels are drawn by systematic resampling with probability proportional to ``weights``
    (every texel gets ``floor`` or ``ceil`` of its expected count), then each sample is jittered
    uniformly inside its texel.

    Args:
        keep: (R,R) bool, texels that may carry a strand.
        weights: (R,R) non-negative sampling weights (e.g. surface area per texel).
        n: number of samples.
        seed: seed of ``np.random.default_rng``.

    Returns:
        (n,2) float32 UVs; (0,2) when no texel is kept or n == 0.
    """
    res = keep.shape[0]
    idx = np.flatnonzero(keep.ravel())
    if idx.size == 0 or n <= 0:
        return np.zeros((0, 2), np.float32)
    rng = np.random.default_rng(seed)
    wts = np.asarray(weights, np.float64).ravel()[idx]
    cdf = np.cumsum(wts)
    cdf /= cdf[-1]
    pos = (np.arange(n) + rng.random()) / n
    pick = idx[np.minimum(np.searchsorted(cdf, pos, side="right"), idx.size - 1)]
    row, col = np.divmod(pick, res)
    jitter = rng.random((n, 2))
    uv = np.stack([(col + jitter[:, 0]) / res, (row + jitter[:, 1]) / res], axis=-1)
    return uv.astype(np.float32)
