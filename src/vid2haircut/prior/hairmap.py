"""Hair map: codec coefficients on the scalp UV (one guide strand per texel) plus a baldness mask.

Layout: ``HairMap.z`` is **channel-first** ``(K,H,W)`` (``(...,K,H,W)`` where batches are allowed),
the layout of convolutional networks and ``F.interpolate``; ``HairMap.mask`` is ``(H,W)`` in [0,1]
(1 = hair). Texel ``[row, col]`` has its guide root at ``head.scalp_uv_to_root`` of the texel centre
``((col+0.5)/W, (row+0.5)/H)`` (see :mod:`vid2haircut.prior.scalp`); maps are square (H = W).

Example::

    hm = encode_strands(strands, head, codec, res=32)
    guides = decode_guides(hm, head, codec)            # guides.points (N,100,3)
    dense = decode_dense(hm, head, codec, n_strands=10000)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from scipy.spatial import cKDTree

from vid2haircut.prior.codec import StrandCodec
from vid2haircut.prior.scalp import points_to_scalp_uv, scalp_grid, scalp_mask_cached, uv_area_weight
from vid2haircut.prior.upsample import MapSamples, neighbour_similarity, sample_map, systematic_texel_samples
from vid2haircut.strands import StrandSet

__all__ = ["HairMap", "TexelAssignment", "Guides", "DenseStrands", "assign_texels", "encode_strands",
           "decode_texels", "decode_guides", "decode_dense"]


@dataclass
class HairMap:
    """A hair map.

    Attributes:
        z: (K,H,W) float coefficients (channel-first), H = W = res.
        mask: (H,W) float baldness mask in [0,1] (1 = hair-bearing).
    """

    z: torch.Tensor
    mask: torch.Tensor

    def __post_init__(self) -> None:
        if self.z.ndim != 3 or self.z.shape[1] != self.z.shape[2]:
            raise ValueError(f"HairMap: z must be (K,H,W) with H == W, got {tuple(self.z.shape)}")
        if tuple(self.mask.shape) != tuple(self.z.shape[1:]):
            raise ValueError(f"HairMap: mask {tuple(self.mask.shape)} does not match z {tuple(self.z.shape)}")

    @property
    def res(self) -> int:
        """Map resolution H = W."""
        return int(self.z.shape[-1])

    @property
    def k(self) -> int:
        """Coefficients per texel K."""
        return int(self.z.shape[0])

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> "HairMap":
        """The map on another device / dtype."""
        return HairMap(self.z.to(device=device, dtype=dtype), self.mask.to(device=device, dtype=dtype))


class TexelAssignment(NamedTuple):
    """Nearest ground-truth strand of every valid scalp texel.

    Attributes:
        strand_index: (H,W) int64 index of the strand whose root UV is nearest to the texel
            centre; -1 on texels off the scalp.
        distance: (H,W) float32 UV distance to that root (inf off the scalp).
        hair: (H,W) bool, valid texel with a root within ``radius_texels`` texel spacings.
    """

    strand_index: np.ndarray
    distance: np.ndarray
    hair: np.ndarray


class Guides(NamedTuple):
    """Guide strands decoded from a map.

    Attributes:
        points: (N,P,3) strands, root first (differentiable w.r.t. the map's z).
        texel_index: (N,) int64 row-major flat texel index (``row * res + col``).
        weight: (N,) mask value of each texel.
    """

    points: torch.Tensor
    texel_index: torch.Tensor
    weight: torch.Tensor

    def to_strand_set(self) -> StrandSet:
        """A detached numpy :class:`StrandSet` with ``texel_index`` as an attribute."""
        return StrandSet(self.points.detach().cpu().numpy(),
                         {"texel_index": self.texel_index.cpu().numpy()})


class DenseStrands(NamedTuple):
    """Dense strands upsampled from a map.

    Attributes:
        points: (M,P,3) strands, root first, differentiable w.r.t. the map's z.
        uv: (M,2) scalp UV of the roots.
        samples: the map evaluated at ``uv`` (nearest / bilinear coefficients, similarity s and
            blend weight w(s)); ``points == codec.decode(samples.blended(), points[:, 0])``.
    """

    points: torch.Tensor
    uv: torch.Tensor
    samples: MapSamples

    def to_strand_set(self) -> StrandSet:
        """A detached numpy :class:`StrandSet` with ``uv`` as an attribute."""
        return StrandSet(self.points.detach().cpu().numpy(), {"uv": self.uv.cpu().numpy()})


def _root_uv(strands: StrandSet, head: Any) -> np.ndarray:
    uv = strands.attributes.get("uv")
    if uv is not None and np.shape(uv) == (strands.n_strands, 2):
        return np.asarray(uv, np.float64)
    return points_to_scalp_uv(strands.roots, getattr(head, "center", None)).astype(np.float64)


def assign_texels(strands: StrandSet, head: Any, res: int = 32, radius_texels: float = 1.5) -> TexelAssignment:
    """Match every valid scalp texel to the strand with the nearest root in UV.

    Args:
        strands: N >= 1 strands; their attribute ``"uv"`` (N,2) is used for the roots' UV when
            present, else the UV is computed from the root positions.
        head: head model.
        res: map resolution.
        radius_texels: a texel is hair-bearing when a root lies within this many texel spacings
            (``radius_texels / res`` in UV).

    Returns:
        :class:`TexelAssignment`.
    """
    if strands.n_strands == 0:
        raise ValueError("assign_texels: the strand set is empty")
    grid = scalp_grid(head, res)
    dist, idx = cKDTree(_root_uv(strands, head)).query(grid.uv.reshape(-1, 2)[grid.index].astype(np.float64))
    strand_index = np.full(res * res, -1, np.int64)
    distance = np.full(res * res, np.inf, np.float32)
    strand_index[grid.index] = idx
    distance[grid.index] = dist
    hair = distance <= radius_texels / res
    return TexelAssignment(strand_index.reshape(res, res), distance.reshape(res, res), hair.reshape(res, res))


def encode_strands(strands: StrandSet, head: Any, codec: StrandCodec, res: int = 32,
                   radius_texels: float = 1.5, device: torch.device | str | None = None) -> HairMap:
    """Encode a strand set into a hair map (nearest root per texel).

    Every valid scalp texel gets the coefficients of its nearest strand (so bald-but-valid texels
    still hold plausible neighbours for interpolation); texels off the scalp get zeros (the mean
    strand). ``mask`` is 1 on valid texels with a root within ``radius_texels`` spacings, else 0.

    Args:
        strands: (N,P,3) strand set (resampled to ``codec.n_points`` when P differs).
        head: head model.
        codec: fitted strand codec with K components.
        res: map resolution (32 default, 64 allowed).
        radius_texels: see :func:`assign_texels`.
        device: device of the returned tensors.

    Returns:
        :class:`HairMap` with z (K,res,res) float32 and mask (res,res) float32.
    """
    assign = assign_texels(strands, head, res, radius_texels)
    pts = strands.resample(codec.n_points).points
    valid = assign.strand_index >= 0
    coeffs = codec.encode(torch.as_tensor(pts[assign.strand_index[valid]], device=device))  # (Nv,K)
    z = torch.zeros(res, res, codec.k, device=device)
    z[torch.as_tensor(valid, device=device)] = coeffs
    mask = torch.as_tensor(assign.hair, dtype=torch.float32, device=device)
    return HairMap(z.permute(2, 0, 1).contiguous(), mask)


def decode_texels(z: torch.Tensor, head: Any, codec: StrandCodec) -> torch.Tensor:
    """Decode the guide of every valid scalp texel (batched; for losses on decoded points).

    Args:
        z: (...,K,H,W) coefficient maps.
        head: head model.
        codec: strand codec (K components or more).

    Returns:
        (...,Nv,P,3) strands in the order of ``scalp_grid(head, H).index``.
    """
    res = int(z.shape[-1])
    grid = scalp_grid(head, res)
    flat = z.flatten(-2)[..., torch.as_tensor(grid.index, device=z.device)]  # (...,K,Nv)
    roots = torch.as_tensor(grid.roots.reshape(-1, 3)[grid.index], device=z.device, dtype=z.dtype)
    return codec.decode(flat.transpose(-1, -2), roots)


def decode_guides(hairmap: HairMap, head: Any, codec: StrandCodec, threshold: float = 0.5) -> Guides:
    """Guide strands of the hair-bearing texels.

    Args:
        hairmap: the map.
        head: head model (roots at texel centres from ``head.scalp_uv_to_root``, cached per res).
        codec: strand codec.
        threshold: texels with ``mask >= threshold`` on the valid scalp are decoded.

    Returns:
        :class:`Guides` (N = number of such texels).
    """
    grid = scalp_grid(head, hairmap.res)
    dev = hairmap.z.device
    keep = torch.as_tensor(grid.valid, device=dev) & (hairmap.mask >= threshold)
    index = torch.nonzero(keep.flatten(), as_tuple=False)[:, 0]
    coeffs = hairmap.z.flatten(1)[:, index].T                            # (N,K)
    roots = torch.as_tensor(grid.roots.reshape(-1, 3), device=dev, dtype=hairmap.z.dtype)[index]
    return Guides(codec.decode(coeffs, roots), index, hairmap.mask.flatten()[index])


def decode_dense(hairmap: HairMap, head: Any, codec: StrandCodec, n_strands: int = 10000,
                 upsample: int = 4, mask_threshold: float | None = None, seed: int = 0) -> DenseStrands:
    """Dense strands by the HAAR nearest / bilinear blend (see :mod:`vid2haircut.prior.upsample`).

    1. The mask is upsampled bilinearly by ``upsample``; a fine texel carries hair where it lies
       on the scalp (``head.scalp_mask(res * upsample)``) and the upsampled mask is
       ``>= mask_threshold``. Default threshold: 0.99 (published) for a hard 0/1 mask, 0.5 for a
       soft mask (a predicted sigmoid mask rarely reaches 0.99 away from the crown).
    2. ``n_strands`` roots are spread over those texels by systematic sampling weighted by surface
       area (``sin(theta)/theta``), jittered inside each texel (deterministic given ``seed``).
    3. At each root UV: nearest and bilinear coefficients, s = mean cosine similarity of the
       neighbouring guides' segment vectors (computed on the decoded guides, detached), blend
       ``w(s) * nearest + (1 - w(s)) * bilinear``, decode at the true scalp root of that UV.

    Args:
        hairmap: the map, z (K,H,W).
        head: head model.
        codec: strand codec.
        n_strands: number of dense strands M (fewer only when no texel carries hair: M = 0).
        upsample: mask upsampling factor (published 64 -> 256: 4).
        mask_threshold: see above.
        seed: seed of the root sampling.

    Returns:
        :class:`DenseStrands`, differentiable w.r.t. ``hairmap.z``.
    """
    if upsample < 1:
        raise ValueError(f"decode_dense: upsample must be >= 1, got {upsample}")
    z, mask = hairmap.z, hairmap.mask
    res, dev = hairmap.res, z.device
    if mask_threshold is None:
        hard = bool(((mask == 0) | (mask == 1)).all())
        mask_threshold = 0.99 if hard else 0.5
    grid = scalp_grid(head, res)
    hi = res * int(upsample)
    m_up = F.interpolate(mask.detach()[None, None].float(), size=(hi, hi), mode="bilinear",
                         align_corners=False)[0, 0].cpu().numpy()
    keep = scalp_mask_cached(head, hi) & (m_up >= mask_threshold)
    centres = (np.stack(np.meshgrid(np.arange(hi), np.arange(hi), indexing="xy"), -1) + 0.5) / hi
    uv = systematic_texel_samples(keep, uv_area_weight(centres), int(n_strands), int(seed))
    with torch.no_grad():
        offsets = codec.decode_offsets(z.detach().permute(1, 2, 0))     # (H,W,P-1,3)
        guide = torch.as_tensor(grid.valid, device=dev) & (mask.detach() >= 0.5)
        sim = neighbour_similarity(offsets, guide)
    uv_t = torch.as_tensor(uv, device=dev, dtype=z.dtype)
    samples = sample_map(z, mask, sim, uv_t)
    if len(uv):
        roots, _ = head.scalp_uv_to_root(uv)
        roots_t = torch.as_tensor(np.asarray(roots, np.float32), device=dev, dtype=z.dtype)
    else:
        roots_t = z.new_zeros(0, 3)
    return DenseStrands(codec.decode(samples.blended(), roots_t), uv_t, samples)
