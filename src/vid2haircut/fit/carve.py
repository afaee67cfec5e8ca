"""Silhouette carving of the dense output strands.

The fit moves guide strands; the dense strands are decoded from the hair map by interpolating
them (:func:`vid2haircut.fit.outputs.dense_strands`), with uneven ends. Where neighbouring guides
differ, an interpolated strand can run where no guide does: past the lower edge of the hair, or
off the side of the head. Every keyframe's silhouette says where hair can be seen: a point that
a keyframe shows in front of the head, inside the image and outside the target silhouette is not
hair. Carving cuts such strands back:

1. :func:`silhouette_excess`: per point, the largest distance (fitting pixels) outside the target
   silhouette over the keyframes (0 where a keyframe cannot tell: outside its image or behind the
   head at that pixel).
2. :func:`carve_lengths`: a strand is cut just before its first point that is more than
   ``tolerance`` outside, provided at least ``min_fraction`` of the points from there to the tip
   are outside too; a strand that leaves the silhouette and comes back (a bulge) is kept whole,
   as its remainder still runs through the hair.
3. :func:`vid2haircut.polylines.cut_strands` resamples each cut strand to its P points.

The decoding is rigid per keyframe (the fitted head pose, no per-frame sway), so the tolerance
also covers the hair motion between keyframes: the ground truth of the quality benchmark itself
loses 1.4-10.8% of its strands' ends this way at 1 pixel, 0.0015e-4 m^2 of Chamfer_pts.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from vid2haircut.fit.data import FitData
from vid2haircut.fit.image_terms import shown_pixels
from vid2haircut.polylines import cut_strands
from vid2haircut.render.project import project_points

__all__ = ["silhouette_excess", "carve_lengths", "carve_strands", "Carving"]


class Carving(NamedTuple):
    """Result of :func:`carve_strands`.

    Attributes:
        points: (N,P,3) carved strands (input dtype).
        keep: (N,) int64 points of each input strand kept before resampling (P = not cut).
    """

    points: np.ndarray
    keep: np.ndarray

    @property
    def cut_fraction(self) -> float:
        """Fraction of strands that were cut."""
        return float(np.mean(self.keep < self.points.shape[1])) if len(self.keep) else 0.0


@torch.no_grad()
def silhouette_excess(points: Tensor, K: Tensor, cam_from_head: Tensor, outside: Tensor,
                      head_depth: Tensor | None = None, near: float = 1e-2, chunk: int = 2_000_000) -> Tensor:
    """Largest distance outside the target silhouettes of each point, over the keyframes.

    Args:
        points: (N,P,3) strands in the canonical head frame, metres.
        K: (M,3,3) keyframe intrinsics (pixel centres at integer coordinates); cam_from_head: (M,4,4).
        outside: (M,H,W) distance from each pixel to the target silhouette, pixels (0 on it).
        head_depth: (M,H,W) camera z of the head surface (+inf off it) or None.
        near: points closer to the camera than this are not judged.
        chunk: points handled at once.

    Returns:
        (N,P) float distance in pixels at each point's nearest pixel, the maximum over keyframes; 0
        where no keyframe can tell (outside its image, behind the head, behind the camera).
    """
    n, p, _ = points.shape
    m, h, w = outside.shape
    flat = points.reshape(-1, 3)
    out = torch.zeros(flat.shape[0], dtype=outside.dtype, device=outside.device)
    for s in range(0, flat.shape[0], chunk):
        x = flat[s:s + chunk].to(outside)
        uv, z = project_points(x[None].expand(m, -1, -1), K.to(x), cam_from_head.to(x), near)
        ok, pix = shown_pixels(uv, z, head_depth, w, h, near)
        d = torch.gather(outside.reshape(m, -1), 1, pix)
        out[s:s + chunk] = torch.where(ok, d, torch.zeros_like(d)).amax(0)
    return out.reshape(n, p)


def carve_lengths(excess: Tensor | np.ndarray, tolerance: float, min_fraction: float = 0.5) -> np.ndarray:
    """Points to keep per strand from its silhouette excess.

    Args:
        excess: (N,P) distance outside the silhouettes per point (:func:`silhouette_excess`).
        tolerance: distance (pixels) that does not count.
        min_fraction: a strand is cut before its first point beyond ``tolerance`` whose remainder
            (that point to the tip) has at least this fraction of points beyond it.

    Returns:
        (N,) int64 in [2, P]: the number of leading points kept (P = uncut; at least the first
        segment stays, so no strand vanishes or degenerates to a point).
    """
    e = np.asarray(excess.cpu() if isinstance(excess, Tensor) else excess, np.float64)
    if e.ndim != 2:
        raise ValueError(f"carve_lengths: excess must be (N,P), got {e.shape}")
    n, p = e.shape
    flag = e > float(tolerance)
    beyond = np.cumsum(flag[:, ::-1], 1)[:, ::-1]                       # flagged points in [i, P)
    remain = p - np.arange(p)[None]
    cut_at = flag & (beyond >= float(min_fraction) * remain)
    keep = np.where(cut_at.any(1), cut_at.argmax(1), p)
    return np.clip(keep, min(2, p), p).astype(np.int64)


def carve_strands(points: np.ndarray, data: FitData, tolerance: float, min_fraction: float = 0.5) -> Carving:
    """Cut dense strands back to the keyframes' silhouettes (see the module docstring).

    Args:
        points: (N,P,3) dense canonical strands, metres.
        data: the keyframes (``outside``, ``K``, ``cam_from_head``, ``head_depth``) at the fitting size.
        tolerance: pixels of the fitting resolution; min_fraction: see :func:`carve_lengths`.

    Raises:
        ValueError when ``data`` has no silhouette distance field or ``tolerance`` is negative.
    """
    if data.outside is None:
        raise ValueError("carving needs FitData.outside (the targets' silhouette distance field)")
    if tolerance < 0:
        raise ValueError(f"carve tolerance must be >= 0 pixels, got {tolerance}")
    pts = np.asarray(points)
    if len(pts) == 0:
        return Carving(pts.copy(), np.zeros(0, np.int64))
    ex = silhouette_excess(torch.as_tensor(pts, dtype=torch.float32, device=data.K.device), data.K,
                           data.cam_from_head, data.outside, data.head_depth)
    keep = carve_lengths(ex, tolerance, min_fraction)
    return Carving(cut_strands(pts, keep), keep)
