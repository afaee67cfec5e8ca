"""Image loss terms of the fitting stages; each returns a scalar tensor (weights are applied by the
trainer). The geometry terms are in :mod:`.losses`.

Image terms compare a :class:`~vid2haircut.render.StrandRender` of B keyframes with the targets:

- :func:`silhouette_loss`: mean |s - s_hat| over the image.
- :func:`direction_loss`: undirected L1 of 2D directions: with o = (cos a, sin a) of the rendered
  and o_hat of the target direction, min(|o - o_hat|_1, |o + o_hat|_1) (the pi ambiguity), averaged
  with weight ``target mask * confidence`` over pixels where the render has hair.
- :func:`depth_loss`: L1 between rendered and target relative depth inside both masks; the rendered
  camera depth is normalised per frame like the targets (5% / 95% quantiles -> 0 / 1), or by the
  least-squares scale and shift to the target.
- :func:`outside_loss`: strand points that a keyframe shows outside its target silhouette (in the
  image, in front of the head) pay their distance to the silhouette, in pixels: the silhouette's
  distance field, which pulls stray strands back however few of them there are, where the L1 on
  coverage sees a lone translucent guide only faintly.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from vid2haircut.fit.components import DEPTH_ALIGNMENTS
from vid2haircut.render.project import project_points

__all__ = ["silhouette_loss", "direction_loss", "depth_loss", "quantile_normalize", "DEPTH_ALIGNMENTS",
           "outside_loss", "shown_pixels", "hidden_direction_loss"]


def silhouette_loss(pred: Tensor, target: Tensor) -> Tensor:
    """Mean L1 between silhouettes. pred, target: (B,H,W) in [0,1] -> scalar."""
    return (pred - target).abs().mean()


def _half_angle_vectors(doubled: Tensor, ok: Tensor) -> Tensor:
    """(...,2) doubled-angle vectors (cos 2a, sin 2a) -> (...,2) unit (cos a, sin a); (1,0) where not ok."""
    c = torch.where(ok, doubled[..., 0], torch.ones_like(doubled[..., 0]))
    s = torch.where(ok, doubled[..., 1], torch.zeros_like(doubled[..., 1]))
    a = 0.5 * torch.atan2(s, c)
    return torch.stack([torch.cos(a), torch.sin(a)], -1)


def direction_loss(pred_dir: Tensor, pred_mask: Tensor, target_dir: Tensor, weight: Tensor) -> Tensor:
    """Undirected L1 of 2D hair directions.

    Args:
        pred_dir: (B,H,W,2) rendered doubled-angle unit vectors ((0,0) where empty).
        pred_mask: (B,H,W) bool, pixels where the render has hair.
        target_dir: (B,H,W,2) target doubled-angle unit vectors.
        weight: (B,H,W) >= 0 per-pixel weight (target mask times confidence).

    Returns:
        Scalar weighted mean of min(|o - o_hat|_1, |o + o_hat|_1); 0 when no pixel has weight.
    """
    ok = pred_mask & ((pred_dir * pred_dir).sum(-1) > 1e-12)
    w = torch.where(ok, weight, torch.zeros_like(weight))
    o = _half_angle_vectors(pred_dir, ok)
    oh = _half_angle_vectors(target_dir, torch.ones_like(ok))
    err = torch.minimum((o - oh).abs().sum(-1), (o + oh).abs().sum(-1))
    return (err * w).sum() / w.sum().clamp_min(1e-6)


def quantile_normalize(depth: Tensor, region: Tensor, q: tuple[float, float] = (0.05, 0.95)) -> Tensor:
    """Map (H,W) depth inside the bool (H,W) region by its quantiles q to 0 and 1 (differentiable)."""
    vals = depth[region]
    qs = torch.quantile(vals, torch.tensor(q, dtype=depth.dtype, device=depth.device))
    return (depth - qs[0]) / (qs[1] - qs[0]).clamp_min(1e-6)


def depth_loss(pred_depth: Tensor, pred_mask: Tensor, target_depth: Tensor, target_valid: Tensor,
               min_pixels: int = 16, align: str = "quantile", quantile_mask: Tensor | None = None) -> Tensor:
    """L1 of relative depth.

    Args:
        pred_depth: (B,H,W) rendered camera z (metres); pred_mask: (B,H,W) bool.
        target_depth: (B,H,W) relative target depth (0 near, 1 far); target_valid: (B,H,W) bool.
        min_pixels: frames whose common region is smaller are skipped.
        align: how the rendered depth is brought to the target's relative scale, per frame, in the
            common region: "quantile" maps its 5% / 95% quantiles to 0 / 1 (as the targets are
            made, though over their own mask); "affine" takes the scale and shift that fit the
            target best in least squares (a monocular depth's scale-and-shift invariance; it does
            not depend on where the two masks differ), or the quantiles where that scale is not
            positive (a reversed depth order must still pay).
        quantile_mask: (B,H,W) bool, the part of the common region whose quantiles the "quantile"
            alignment uses (the hair, when the region also holds the head; None: all of it).

    Returns:
        Scalar mean over frames (with enough pixels) of the mean |d - d_hat| in the common region.
    """
    if align not in DEPTH_ALIGNMENTS:
        raise ValueError(f"depth alignment must be one of {DEPTH_ALIGNMENTS}, got {align!r}")
    terms = []
    for b in range(pred_depth.shape[0]):
        region = pred_mask[b] & target_valid[b]
        if int(region.sum()) < min_pixels:
            continue
        d = None
        if align == "affine":
            x = pred_depth[b][region]
            t = target_depth[b][region].to(x)
            xc = x - x.mean()
            scale = (xc * (t - t.mean())).sum() / xc.square().sum().clamp_min(1e-12)
            if float(scale.detach()) > 0.0:            # a reversed depth order falls back to the quantiles
                d = scale * xc + t.mean()
        if d is None:
            q_region = region if quantile_mask is None else region & quantile_mask[b]
            d = quantile_normalize(pred_depth[b], q_region if int(q_region.sum()) >= 2 else region)[region]
        terms.append((d - target_depth[b][region]).abs().mean())
    return torch.stack(terms).mean() if terms else pred_depth.sum() * 0.0


@torch.no_grad()
def shown_pixels(uv: Tensor, z: Tensor, head_depth: Tensor | None, width: int, height: int,
                 near: float = 1e-2) -> tuple[Tensor, Tensor]:
    """Which projected points a keyframe shows, and their nearest pixels.

    Args:
        uv: (B,Q,2) pixel coordinates (pixel centres at integers); z: (B,Q) camera depth.
        head_depth: (B,H,W) camera z of the head surface (+inf off it) or None.
        width, height: image size; near: points closer to the camera are not shown.

    Returns:
        shown: (B,Q) bool, in front of the camera, on a pixel of the image and not behind the head
        there; pix: (B,Q) int64 flat index of the nearest pixel (clamped into the image).
    """
    ui, vi = uv[..., 0].round().long(), uv[..., 1].round().long()
    shown = (z > near) & (ui >= 0) & (ui < width) & (vi >= 0) & (vi < height)
    pix = vi.clamp(0, height - 1) * width + ui.clamp(0, width - 1)
    if head_depth is not None:
        shown &= z < torch.gather(head_depth.reshape(z.shape[0], -1).to(z), 1, pix)
    return shown, pix


def outside_loss(points: Tensor, K: Tensor, cam_from_head: Tensor, outside: Tensor, head_depth: Tensor | None,
                 tolerance: float = 0.5, near: float = 1e-2) -> Tensor:
    """Mean distance (pixels) beyond ``tolerance`` from the target silhouette of the projected points.

    Args:
        points: (B,N,P,3) strands in the canonical head frame, one set per keyframe (metres).
        K: (B,3,3) intrinsics (pixel centres at integer coordinates); cam_from_head: (B,4,4).
        outside: (B,H,W) distance from each pixel to the target silhouette, pixels (0 on it).
        head_depth: (B,H,W) camera z of the head surface (+inf off it) or None: points behind the
            head at their pixel do not show and pay nothing.
        tolerance: distance (pixels) that costs nothing (masks are soft, poses off by a pixel).
        near: points closer to the camera than this pay nothing.

    Returns:
        scalar: mean over all B*N*P points of relu(d - tolerance), d sampled bilinearly from
        ``outside`` at the point's projection; points outside the image or hidden by the head give 0.
    """
    b, n, p, _ = points.shape
    h, w = outside.shape[-2:]
    uv, z = project_points(points.reshape(b, n * p, 3), K, cam_from_head, near)
    u, v = uv[..., 0], uv[..., 1]
    valid, _ = shown_pixels(uv, z, head_depth, w, h, near)
    grid = torch.stack([2.0 * u / max(w - 1, 1) - 1.0, 2.0 * v / max(h - 1, 1) - 1.0], -1)[:, None]
    d = F.grid_sample(outside[:, None].to(grid), grid, mode="bilinear", align_corners=True,
                      padding_mode="border")[:, 0, 0]                         # (B,N*P)
    return (torch.relu(d - tolerance) * valid).sum() / max(b * n * p, 1)


def hidden_direction_loss(points: Tensor, hidden: Tensor, K: Tensor, cam_from_head: Tensor, target_dir: Tensor,
                          weight: Tensor, head_depth: Tensor | None, near: float = 1e-2) -> Tensor:
    """Hidden segments run along the hair that covers them: the 2D direction of each segment that a
    keyframe does not show, against the target direction at its midpoint's pixel.

    Hair lies in layers that run alongside each other, so where a segment is hidden by hair in front
    of it, the orientation of that pixel (the covering hair's: Stage 2 passes its own rendered
    direction map, detached, or the keyframe's target) is the best guess of its own projected
    direction. This term carries only that: no silhouette or depth, which belong to the visible hair.

    Args:
        points: (B,N,P,3) strands in the canonical head frame, one set per keyframe (metres).
        hidden: (B,N,P-1) bool segments the keyframe does not show (hidden by hair in front of them).
        K: (B,3,3) intrinsics; cam_from_head: (B,4,4).
        target_dir: (B,H,W,2) doubled-angle unit vectors (cos 2a, sin 2a) to align with.
        weight: (B,H,W) >= 0 per-pixel weight (where ``target_dir`` holds a direction).
        head_depth: (B,H,W) camera z of the head surface (+inf off it) or None: segments whose midpoint
            lies behind the head pay nothing.

    Returns:
        Scalar weighted mean over hidden segments of 1 - cos(2 (a - a_target)) in [0, 2] (undirected);
        0 when no hidden segment lands on a weighted pixel.
    """
    b, n, p, _ = points.shape
    h, w = target_dir.shape[1:3]
    uv, z = project_points(points.reshape(b, n * p, 3), K, cam_from_head, near)
    uv = uv.reshape(b, n, p, 2)
    mid = 0.5 * (uv[:, :, 1:] + uv[:, :, :-1]).reshape(b, -1, 2)
    zm = 0.5 * (z.reshape(b, n, p)[:, :, 1:] + z.reshape(b, n, p)[:, :, :-1]).reshape(b, -1)
    shown, pix = shown_pixels(mid.detach(), zm.detach(), head_depth, w, h, near)
    wt = torch.gather(weight.reshape(b, -1), 1, pix) * (shown & hidden.reshape(b, -1))
    seg = (uv[:, :, 1:] - uv[:, :, :-1]).reshape(b, -1, 2)
    length2 = seg.square().sum(-1)
    wt = wt * (length2.detach() > 1e-8)
    doubled = torch.stack([seg[..., 0].square() - seg[..., 1].square(), 2.0 * seg[..., 0] * seg[..., 1]], -1)
    doubled = doubled / length2.clamp_min(1e-8)[..., None]
    tgt = torch.gather(target_dir.reshape(b, -1, 2), 1, pix[..., None].expand(-1, -1, 2))
    err = 1.0 - (doubled * tgt).sum(-1)
    return (err * wt).sum() / wt.sum().clamp_min(1e-6)
