"""Loss terms of the fitting stages; each returns a scalar tensor (weights are applied by the trainer).

Image terms compare a :class:`~vid2haircut.render.StrandRender` of B keyframes with the targets:

- :func:`silhouette_loss`: mean |s - s_hat| over the image.
- :func:`direction_loss`: undirected L1 of 2D directions: with o = (cos a, sin a) of the rendered
  and o_hat of the target direction, min(|o - o_hat|_1, |o + o_hat|_1) (the pi ambiguity), averaged
  with weight ``target mask * confidence`` over pixels where the render has hair.
- :func:`depth_loss`: L1 between rendered and target relative depth inside both masks; the rendered
  camera depth is normalised per frame like the targets (5% / 95% quantiles -> 0 / 1).
- :func:`outside_loss`: strand points that a keyframe shows outside its target silhouette (in the
  image, in front of the head) pay their distance to the silhouette, in pixels: the silhouette's
  distance field, which pulls stray strands back however few of them there are, where the L1 on
  coverage sees a lone translucent guide only faintly.

Geometry terms act on strands in the canonical head frame:

- :func:`penetration_loss`: mean(relu(-sdf(x))) in metres.
- :func:`smoothness_losses`: over neighbouring texels (4-neighbours on the scalp map) strand
  length varies smoothly (a Laplacian, weighted up in the back region) and neighbouring strands
  run alongside each other (1 - cos between nearby segments).
- :func:`tip_height_loss`: neighbouring strands end at similar heights (a Laplacian of the tip's
  height over the scalp map): the cut line of hanging hair, which lets hidden strands follow the
  visible ones that the images lengthen.
- :func:`pca_consistency_loss`: the coefficients of texels not observed in any keyframe should
  agree with the mean of their hair-bearing neighbours (observed neighbours enter detached, so
  information flows from observed into unobserved regions, never back).
- :func:`anchor_loss`: guide points that no keyframe shows stay near their starting positions.
- :func:`bend_loss`: strands bend no tighter than a minimum radius (only the excess turn counts).
- :func:`gravity_loss`: hair hangs: segments that rise against gravity pay their rise per unit length.
- :func:`motion_loss`: mean squared deformation offset.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from vid2haircut.render.project import project_points

__all__ = ["silhouette_loss", "direction_loss", "depth_loss", "penetration_loss", "TexelGraph", "texel_graph",
           "smoothness_losses", "tip_height_loss", "robust", "pca_consistency_loss", "motion_loss",
           "quantile_normalize", "DEPTH_ALIGNMENTS", "anchor_loss", "bend_loss", "gravity_loss", "outside_loss",
           "shown_pixels"]


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


DEPTH_ALIGNMENTS = ("quantile", "affine")


def depth_loss(pred_depth: Tensor, pred_mask: Tensor, target_depth: Tensor, target_valid: Tensor,
               min_pixels: int = 16, align: str = "quantile") -> Tensor:
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
            d = quantile_normalize(pred_depth[b], region)[region]
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


def penetration_loss(points: Tensor, sdf: Callable[[Tensor], Tensor], margin: float = 0.0) -> Tensor:
    """mean(relu(-sdf(points) - margin)). points: (...,3) canonical head frame, metres -> scalar.

    ``margin`` (metres) tolerates points that far inside the head surface (for a fitted head whose
    pose is off by a millimetre or two, hair lying on the true scalp reads as slightly inside).
    """
    return torch.relu(-sdf(points) - margin).mean()


class TexelGraph(NamedTuple):
    """4-neighbour pairs of guide texels on the scalp map.

    Attributes:
        pairs: (E,2) int64 indices into the guide list (texel below or right of the first).
        back: (E,) bool, pair in the back region of the head.
    """

    pairs: Tensor
    back: Tensor


def texel_graph(texel_index: Tensor | np.ndarray, res: int, back_v: float = 0.45) -> TexelGraph:
    """Neighbour pairs of the guides at flat texel indices ``texel_index`` (N,) of a res x res map.

    The back region is v < ``back_v`` (v grows towards the face; the crown is at v = 0.5).
    """
    idx = np.asarray(torch.as_tensor(texel_index).cpu().numpy(), np.int64)
    pos = np.full(res * res, -1, np.int64)
    pos[idx] = np.arange(len(idx))
    grid = pos.reshape(res, res)
    pairs = []
    for a, b in ((grid[:, :-1], grid[:, 1:]), (grid[:-1, :], grid[1:, :])):
        ok = (a >= 0) & (b >= 0)
        pairs.append(np.stack([a[ok], b[ok]], -1))
    p = np.concatenate(pairs).reshape(-1, 2)
    row = idx[p[:, 0]] // res if len(p) else np.zeros(0, np.int64)
    back = (row + 0.5) / res < back_v
    dev = texel_index.device if torch.is_tensor(texel_index) else None
    return TexelGraph(torch.as_tensor(p, device=dev), torch.as_tensor(back, device=dev))


def robust(x: Tensor, scale: float) -> Tensor:
    """Edge-preserving penalty of residuals x >= 0: ``scale * x / (x + scale)`` (x itself for scale 0).

    Equal to x for x << scale and saturating at ``scale`` for x >> scale, so small disagreements are
    smoothed as by the plain L1 penalty while large ones (a parting, the edge of a fringe, a layered
    cut) are left alone: the gradient scale^2 / (x + scale)^2 vanishes across real discontinuities.
    """
    if scale <= 0.0:
        return x
    return scale * x / (x + scale)


def smoothness_losses(points: Tensor, graph: TexelGraph, back_weight: float = 100.0,
                      sigma: float = 0.005, length_scale: float = 0.0,
                      direction_scale: float = 0.0) -> dict[str, Tensor]:
    """Neighbour-strand smoothness of length and direction.

    - Length: |L_i - mean of L over i's 4-neighbours| (metres), a discrete Laplacian of strand
      length over the scalp map: lengths may vary smoothly (layers, cuts) but not jump. Guides in
      the back region are weighted by ``back_weight``.
    - Direction: neighbouring strands run alongside each other: for every segment of strand i,
      the nearest segment of its neighbour j (by midpoint, chosen without gradient) should point
      the same way; 1 - cos of the two directions, weighted by exp(-d^2 / (2 sigma^2)) of their
      distance d so that strands that part (a parting, a fringe) are not pulled together.

    (Measured on generated sequences: comparing segments by index, or penalising any length
    difference, pulls layered styles such as a bob far from the truth.)

    Args:
        points: (N,P,3) canonical guide strands (root first).
        graph: neighbour pairs of the guides.
        back_weight: factor on the length term of guides in the back region.
        sigma: distance scale of the direction term, metres.
        length_scale: :func:`robust` scale of the length residuals, metres (0: plain L1).
        direction_scale: :func:`robust` scale of the 1 - cos residuals (0: plain).

    Returns:
        {"smooth_length": scalar (metres), "smooth_direction": scalar in [0, 2]}.
    """
    if graph.pairs.numel() == 0:
        zero = points.sum() * 0.0
        return {"smooth_length": zero, "smooth_direction": zero}
    n = points.shape[0]
    seg = points[:, 1:] - points[:, :-1]                                    # (N,S,3)
    length = seg.norm(dim=-1).sum(-1)                                       # (N,)
    i, j = graph.pairs[:, 0], graph.pairs[:, 1]
    residual, has = _laplacian(length, graph)
    lap = robust(residual.abs(), length_scale)
    back = torch.zeros(n, dtype=torch.bool, device=points.device)
    back[i[graph.back]] = True
    w_len = torch.where(back, torch.full_like(lap, back_weight), torch.ones_like(lap))
    smooth_length = (w_len * lap)[has].mean()
    t = seg / seg.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    mid = 0.5 * (points[:, 1:] + points[:, :-1])
    with torch.no_grad():
        d2 = torch.cdist(mid[i], mid[j]).square()                          # (E,S,S)
        d2min, nn = d2.min(-1)                                              # (E,S)
        w = torch.exp(-d2min / (2.0 * sigma * sigma))
    tj = torch.gather(t[j], 1, nn[..., None].expand(-1, -1, 3))
    cos = (t[i] * tj).sum(-1)
    smooth_direction = (w * robust(1.0 - cos, direction_scale)).sum() / w.sum().clamp_min(1e-9)
    return {"smooth_length": smooth_length, "smooth_direction": smooth_direction}


def _laplacian(values: Tensor, graph: TexelGraph) -> tuple[Tensor, Tensor]:
    """(N,) per-guide values -> ((N,) value minus the mean over its graph neighbours, (N,) bool has neighbours)."""
    i, j = graph.pairs[:, 0], graph.pairs[:, 1]
    ones = torch.ones_like(values[i])
    deg = torch.zeros_like(values).index_add(0, i, ones).index_add(0, j, ones)
    nb_sum = torch.zeros_like(values).index_add(0, i, values[j]).index_add(0, j, values[i])
    return values - nb_sum / deg.clamp_min(1.0), deg > 0


def tip_height_loss(points: Tensor, graph: TexelGraph, scale: float = 0.0, up: int = 1) -> Tensor:
    """Neighbouring strands end at similar heights: mean robust |Laplacian of the tip height|.

    Hanging hair is cut along a line: neighbouring strands end at about the same height whatever
    the height of their roots (a bob, a shoulder-length or long cut; layers vary it slowly). The
    images lengthen the strands they see reach down to the cut, but not the strands hidden under
    them or at the back; this term lets those follow their visible neighbours. With ``scale`` > 0
    it is edge-preserving (:func:`robust`): a fringe ending on the forehead next to long side hair
    is left alone.

    Args:
        points: (N,P,3) canonical guide strands (root first), metres.
        graph: neighbour pairs of the guides.
        scale: :func:`robust` scale of the residuals, metres (0: plain L1).
        up: index of the head frame's up axis (1: +y up, the canonical head frame).

    Returns:
        Scalar (metres); 0 when no guide has a neighbour.
    """
    if graph.pairs.numel() == 0:
        return points.sum() * 0.0
    lap, has = _laplacian(points[:, -1, up], graph)
    return robust(lap.abs(), scale)[has].mean()


def pca_consistency_loss(z: Tensor, hair: Tensor, observed: Tensor) -> Tensor:
    """Consistency of unobserved texels' PCA coefficients with their neighbours.

    Args:
        z: (K,R,R) coefficient map (whitened units).
        hair: (R,R) bool, hair-bearing texels.
        observed: (R,R) bool, texels seen in some keyframe.

    Returns:
        Scalar: mean over unobserved hair texels of mean_k (z - zbar)^2, zbar the mean of the
        hair-bearing 8-neighbours (observed ones detached); 0 when every texel is observed.
    """
    h = hair.to(z.dtype)
    src = torch.where(observed[None], z.detach(), z) * h[None]
    kernel = torch.ones(1, 1, 3, 3, dtype=z.dtype, device=z.device)
    kernel[0, 0, 1, 1] = 0.0
    num = F.conv2d(src[:, None], kernel, padding=1)[:, 0]                  # (K,R,R)
    den = F.conv2d(h[None, None], kernel, padding=1)[0, 0]                  # (R,R)
    zbar = num / den.clamp_min(1.0)
    target = hair & ~observed & (den > 0)
    if not bool(target.any()):
        return z.sum() * 0.0
    return (z - zbar)[:, target].pow(2).mean()


def anchor_loss(points: Tensor, start: Tensor, hidden: Tensor) -> Tensor:
    """Hidden points stay where they started: mean |x - x_start|^2 (m^2) over the hidden points.

    Args:
        points: (N,P,3) current canonical guide points. start: (N,P,3) their starting positions.
        hidden: (N,P) bool, points that no keyframe shows.

    Returns:
        Scalar (0 when nothing is hidden).
    """
    if not bool(hidden.any()):
        return points.sum() * 0.0
    return (points - start).square().sum(-1)[hidden].mean()


def bend_loss(points: Tensor, min_radius: float) -> Tensor:
    """Strands bend no tighter than ``min_radius``: the mean over interior points of
    relu(|u_{i+1} - u_i|^2 - (l_i / r)^2), u the unit segment directions, l_i the mean length of the
    two segments, r = ``min_radius`` (metres). |u_{i+1} - u_i|^2 = 2 (1 - cos theta) ~ theta^2 for a
    turn of theta, and a circle of radius r turns by l / r over an arc l, so only bends tighter than r
    count (straight and wavy hair are left alone; millimetre zigzags of decoded short strands are not).

    Args:
        points: (...,P,3) strand points (P >= 3), metres. min_radius: r > 0.

    Returns:
        Scalar (squared radians).
    """
    d = points[..., 1:, :] - points[..., :-1, :]
    length = d.norm(dim=-1)
    u = d / length.clamp_min(1e-9)[..., None]
    turn = (u[..., 1:, :] - u[..., :-1, :]).square().sum(-1)
    allowed = (0.5 * (length[..., 1:] + length[..., :-1]) / min_radius).square()
    return torch.relu(turn - allowed).mean()


def gravity_loss(points: Tensor, up: int = 1) -> Tensor:
    """Hair hangs: the mean over segments of relu(u . up), u the unit segment direction.

    Gravity pulls hanging hair down; a segment that rises is held up only by the head or by the hair
    beneath it. Segments running level or down cost nothing (hanging hair, waves that keep
    descending); the rising part of a strand pays by the sine of its climb, whether it is a curl
    looping back up or hair combed up over the scalp. (method.md lists a gravity term of weight 0.1
    in Vid2Haircut's loss without defining it; this is our definition.)

    Args:
        points: (...,P,3) strand points (P >= 2) in the canonical head frame, metres.
        up: index of the head frame's up axis (1: +y up, the canonical head frame).

    Returns:
        Scalar in [0, 1].
    """
    d = points[..., 1:, :] - points[..., :-1, :]
    return torch.relu(d[..., up] / d.norm(dim=-1).clamp_min(1e-9)).mean()


def motion_loss(offsets: Tensor) -> Tensor:
    """Mean squared offset. offsets: (...,3) metres -> scalar (m^2)."""
    return offsets.pow(2).sum(-1).mean()
