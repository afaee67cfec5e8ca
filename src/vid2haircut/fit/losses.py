"""Geometry loss terms of the fitting stages, on strands in the canonical head frame; each returns a
scalar tensor (weights are applied by the trainer). The image terms are in :mod:`.image_terms`.

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

from vid2haircut.fit.components import SMOOTH_DIRECTION_FORMS

__all__ = ["penetration_loss", "TexelGraph", "texel_graph", "smoothness_losses", "SMOOTH_DIRECTION_FORMS", "unit_directions", "tip_height_loss", "robust",
           "pca_consistency_loss", "motion_loss", "anchor_loss", "bend_loss", "gravity_loss"]


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


def unit_directions(points: Tensor) -> Tensor:
    """(...,P,3) strand points -> (...,P-1,3) unit directions of their segments."""
    seg = points[..., 1:, :] - points[..., :-1, :]
    return seg / seg.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def smoothness_losses(points: Tensor, graph: TexelGraph, back_weight: float = 100.0,
                      sigma: float = 0.005, length_scale: float = 0.0,
                      direction_scale: float = 0.0, length_points: Tensor | None = None,
                      strand_weight: Tensor | None = None, reference_directions: Tensor | None = None,
                      direction_form: str = "absolute") -> dict[str, Tensor]:
    """Neighbour-strand smoothness of length and direction.

    - Length: |L_i - mean of L over i's 4-neighbours| (metres), a discrete Laplacian of strand
      length over the scalp map: lengths may vary smoothly (layers, cuts) but not jump. Guides in
      the back region are weighted by ``back_weight``.
    - Direction: neighbouring strands run alongside each other: for every segment of strand i,
      the nearest segment of its neighbour j (by midpoint, chosen without gradient) should point
      the same way; 1 - cos of the two directions, weighted by exp(-d^2 / (2 sigma^2)) of their
      distance d so that strands that part (a parting, a fringe) are not pulled together.
      ``direction_form`` chooses what is penalised of each segment pair (see
      :data:`SMOOTH_DIRECTION_FORMS`): "absolute", 1 - cos (the plain form); "relative", only how
      much less aligned the pair is than the same pair of reference strands, relu(cos_ref -
      cos), so neighbours that fan out at the start may keep fanning out while a guide that turns
      drags its neighbours along; "change", 0.5 |(t_i - t_i,ref) - (t_j - t_j,ref)|^2, the
      difference of the two segments' changes of direction since the reference.

    (Measured on generated sequences: comparing segments by index, or penalising any length
    difference, pulls layered styles such as a bob far from the truth.)

    Args:
        points: (N,P,3) canonical guide strands (root first).
        graph: neighbour pairs of the guides.
        back_weight: factor on the length term of guides in the back region.
        sigma: distance scale of the direction term, metres.
        length_scale: :func:`robust` scale of the length residuals, metres (0: plain L1).
        direction_scale: :func:`robust` scale of the 1 - cos residuals (0: plain).
        length_points: (N,P,3) the strands the length term measures, when they are to carry other
            gradients than ``points`` (the same values, parts of them detached); default ``points``.
        strand_weight: (N,) factor on each guide's terms (a pair takes the mean of its two guides');
            the terms keep their unweighted normalisation, so a factor below 1 lowers them. Default 1.
        reference_directions: (N,P-1,3) :func:`unit_directions` of the strands the "relative" and
            "change" forms compare with (Stage 2: its start); required by those forms, unused by
            "absolute".
        direction_form: "absolute", "relative" or "change".

    Returns:
        {"smooth_length": scalar (metres), "smooth_direction": scalar in [0, 2]}.
    """
    if direction_form not in SMOOTH_DIRECTION_FORMS:
        raise ValueError(f"smoothness: direction_form must be one of {SMOOTH_DIRECTION_FORMS}, "
                         f"got {direction_form!r}")
    want = (*points.shape[:-2], points.shape[-2] - 1, 3)
    ref = reference_directions
    if direction_form != "absolute" and (ref is None or tuple(ref.shape) != want):
        raise ValueError(f"smoothness: direction_form {direction_form!r} needs reference directions of "
                         f"shape {want}, got {None if ref is None else tuple(ref.shape)}")
    if graph.pairs.numel() == 0:
        zero = points.sum() * 0.0
        return {"smooth_length": zero, "smooth_direction": zero}
    n = points.shape[0]
    lp = points if length_points is None else length_points
    length = (lp[:, 1:] - lp[:, :-1]).norm(dim=-1).sum(-1)                   # (N,)
    i, j = graph.pairs[:, 0], graph.pairs[:, 1]
    residual, has = _laplacian(length, graph)
    lap = robust(residual.abs(), length_scale)
    back = torch.zeros(n, dtype=torch.bool, device=points.device)
    back[i[graph.back]] = True
    w_len = torch.where(back, torch.full_like(lap, back_weight), torch.ones_like(lap))
    if strand_weight is not None:
        w_len = w_len * strand_weight
    smooth_length = (w_len * lap)[has].mean()
    t = unit_directions(points)
    mid = 0.5 * (points[:, 1:] + points[:, :-1])
    with torch.no_grad():
        d2 = torch.cdist(mid[i], mid[j]).square()                          # (E,S,S)
        d2min, nn = d2.min(-1)                                              # (E,S)
        w = torch.exp(-d2min / (2.0 * sigma * sigma))
    tj = torch.gather(t[j], 1, nn[..., None].expand(-1, -1, 3))
    cos = (t[i] * tj).sum(-1)
    if direction_form == "absolute":
        residual_dir = 1.0 - cos
    else:
        r = ref.detach()
        rj = torch.gather(r[j], 1, nn[..., None].expand(-1, -1, 3))
        if direction_form == "relative":
            residual_dir = torch.relu((r[i] * rj).sum(-1) - cos)
        else:
            residual_dir = 0.5 * ((t[i] - r[i]) - (tj - rj)).square().sum(-1)
    pen = w * robust(residual_dir, direction_scale)
    if strand_weight is not None:
        pen = pen * (0.5 * (strand_weight[i] + strand_weight[j]))[:, None]
    smooth_direction = pen.sum() / w.sum().clamp_min(1e-9)
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
        hair-bearing 8-neighbours (observed ones detached); 0 when every texel is observed or K is 0.
    """
    if z.shape[0] == 0:
        return z.sum() * 0.0
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


def anchor_loss(points: Tensor, start: Tensor, hidden: Tensor, outward: Tensor | None = None) -> Tensor:
    """Hidden points stay where they started: mean |x - x_start|^2 (m^2) over the hidden points.

    Args:
        points: (N,P,3) current canonical guide points. start: (N,P,3) their starting positions.
        hidden: (N,P) bool, points that no keyframe shows.
        outward: (N,P,3) unit directions away from the head at the starting points, or None: with
            them, the part of a move along that direction that leads away from the head is free.

    Returns:
        Scalar (0 when nothing is hidden).
    """
    if not bool(hidden.any()):
        return points.sum() * 0.0
    r = points - start
    sq = r.square().sum(-1)
    if outward is not None:
        sq = sq - torch.relu((r * outward).sum(-1)).square()
    return sq[hidden].mean()


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
    length = (points[..., 1:, :] - points[..., :-1, :]).norm(dim=-1)
    u = unit_directions(points)
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
    return torch.relu(unit_directions(points)[..., up]).mean()


def motion_loss(offsets: Tensor) -> Tensor:
    """Mean squared offset. offsets: (...,3) metres -> scalar (m^2)."""
    return offsets.pow(2).sum(-1).mean()
