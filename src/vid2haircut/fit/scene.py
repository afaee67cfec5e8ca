"""Guide strands of a hair map, rendered into the keyframes, compared with the targets.

Shared by both stages: which texels carry a guide (:class:`GuideLayout`), decoding the guides of
a coefficient map with gradients (:func:`decode_layout`), rendering B keyframes
(:func:`render_frames`) and the image loss terms (:func:`image_losses`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor, nn

from vid2haircut.fit.components import HIDDEN_DIRECTION_SOURCES, RenderSettings
from vid2haircut.fit.data import FitData
from vid2haircut.fit.image_terms import (depth_loss, direction_loss, hidden_direction_loss, outside_loss,
                                         silhouette_loss)
from vid2haircut.fit.losses import TexelGraph, texel_graph
from vid2haircut.prior.codec import StrandCodec
from vid2haircut.prior.scalp import scalp_grid
from vid2haircut.render import StrandRender, render_strands
from vid2haircut.render.api import resolve_compositing
from vid2haircut.render.numba_backend import resolve_backend

__all__ = ["GuideLayout", "guide_layout", "decode_layout", "drawn_compositing", "render_frames", "image_losses",
           "outside_term", "hidden_direction_term",
           "HIDDEN_DIRECTION_SOURCES", "ZMap",
           "length_step_gain", "z_optimizer"]


class GuideLayout(NamedTuple):
    """The guide strands of a map: one per hair-bearing texel.

    Attributes:
        res: map resolution R.
        texel_index: (N,) int64 row-major flat texel indices of the guides.
        roots: (N,3) float32 root points (canonical head frame).
        hair: (R,R) bool, texels carrying a guide.
        render_index: (Pr,) int64 indices of the codec points that are rendered (root and tip kept).
        graph: 4-neighbour pairs of the guides (for smoothness).
    """

    res: int
    texel_index: Tensor
    roots: Tensor
    hair: Tensor
    render_index: Tensor
    graph: TexelGraph


def guide_layout(head: Any, mask: Tensor, threshold: float, n_codec_points: int, n_render_points: int,
                 device: torch.device | str | None = None) -> GuideLayout:
    """Guides where ``mask`` (R,R) >= ``threshold`` on the head's valid scalp texels.

    Raises:
        ValueError when no texel carries hair.
    """
    res = int(mask.shape[-1])
    grid = scalp_grid(head, res)
    hair = np.asarray(grid.valid) & (mask.detach().cpu().numpy() >= threshold)
    idx = np.flatnonzero(hair.ravel())
    if idx.size == 0:
        raise ValueError(f"the hair map has no hair-bearing texel (mask >= {threshold} on the scalp)")
    roots = grid.roots.reshape(-1, 3)[idx]
    n_r = int(min(max(2, n_render_points), n_codec_points))
    ridx = np.unique(np.round(np.linspace(0, n_codec_points - 1, n_r)).astype(np.int64))
    tix = torch.as_tensor(idx, device=device)
    return GuideLayout(res, tix, torch.as_tensor(roots, dtype=torch.float32, device=device),
                       torch.as_tensor(hair, device=device), torch.as_tensor(ridx, device=device),
                       texel_graph(tix, res))


def decode_layout(z: Tensor, layout: GuideLayout, codec: StrandCodec) -> Tensor:
    """Guides of the layout from a (K,R,R) map -> (N,P,3) strands (P = codec.n_points), differentiable."""
    coeffs = z.flatten(1)[:, layout.texel_index].T                          # (N,K)
    return codec.decode(coeffs, layout.roots.to(z))


def drawn_compositing(settings: RenderSettings, data: FitData) -> str:
    """The compositing model ("bins" or "exact") that :func:`render_frames` draws ``data``'s
    keyframes with under ``settings`` ("auto": "exact" where the numba backend renders, on the CPU)."""
    return resolve_compositing(settings.compositing, resolve_backend("auto", data.K))


def render_frames(points: Tensor, data: FitData, frames: Tensor, settings: RenderSettings,
                  shading: bool = True) -> StrandRender:
    """Render canonical-frame strands into keyframes.

    Args:
        points: (B,N,P,3) strands in the canonical head frame, one set per rendered keyframe.
        data: the sequence; frames: (B,) int64 keyframe positions into ``data``.
        settings: strand width, depth bins, the silhouette's opacity (below 1 the silhouette is
            that of the strands drawn at that opacity, the other channels the opaque render's;
            ``render_strands(silhouette_opacity=...)``, one window walk for both on the CPU).
        shading: False renders the silhouette only.

    Raises:
        ValueError when ``settings.silhouette_opacity`` is not in (0, 1].
    """
    if not 0.0 < settings.silhouette_opacity <= 1.0:
        raise ValueError(f"render.silhouette_opacity must be in (0, 1], got {settings.silhouette_opacity}")
    fr = frames.to(data.K.device)
    head_depth = data.head_depth[fr] if data.head_depth is not None else None

    translucent = settings.silhouette_opacity if settings.silhouette_opacity < 1.0 else None
    return render_strands(points, data.K[fr], data.cam_from_head[fr], data.width, data.height,
                          strand_width=settings.strand_width, head_depth=head_depth, bins=settings.bins,
                          depth_bin=settings.depth_bin, vis_weight=settings.vis_weight, shading=shading,
                          silhouette_opacity=translucent, compositing=settings.compositing, t_min=settings.t_min)


def image_losses(out: StrandRender, data: FitData, frames: Tensor, depth_align: str = "quantile",
                 depth_head: bool = False) -> dict[str, Tensor]:
    """Silhouette, direction and depth terms of rendered keyframes ``frames`` (B,) -> dict of scalars
    (``depth_align``: see :func:`~vid2haircut.fit.image_terms.depth_loss`).

    With ``depth_head`` (and a head occluder in ``data``), target depth outside the target hair
    silhouette where no hair is rendered but the fitted head is (the visible head, when the targets
    carry its depth) is compared with the head's own depth there, in the same per-keyframe
    alignment as the hair (the quantile alignment takes its quantiles from the hair, as the targets
    are made): the head, whose shape and pose are known, then fixes the shift and scale of that
    alignment, and so how far the hair stands off it.
    """
    fr = frames.to(data.mask.device)
    mask_t = data.mask[fr]
    weight = data.confidence[fr] * (mask_t > 0.5)
    pred_depth, pred_mask, hair = out.depth, out.mask.detach(), None
    if depth_head and data.head_depth is not None:
        hair = pred_mask
        head = data.head_depth[fr].to(pred_depth)
        context = data.depth_valid[fr] & (mask_t < 0.5) & torch.isfinite(head) & ~pred_mask
        pred_depth = torch.where(context, torch.nan_to_num(head, posinf=0.0), pred_depth)
        pred_mask = pred_mask | context
    return {"silhouette": silhouette_loss(out.silhouette, mask_t),
            "direction": direction_loss(out.direction, out.mask.detach(), data.direction[fr], weight),
            "depth": depth_loss(pred_depth, pred_mask, data.depth[fr], data.depth_valid[fr], align=depth_align,
                                quantile_mask=hair)}


def hidden_direction_term(drawn: Tensor, moved: Tensor, hidden: Tensor, out: StrandRender, data: FitData,
                          frames: Tensor, source: str = "render") -> Tensor:
    """:func:`~vid2haircut.fit.image_terms.hidden_direction_loss` of the ``hidden`` segments of keyframes ``frames`` (B,).

    drawn: (N,P,3) canonical strands; moved: (B,N,P,3) their per-frame copies, of which only the
    per-frame displacement is taken (held fixed: the term reaches ``drawn`` directly); hidden:
    (B,N,P-1) bool segments each keyframe does not show; out: the keyframes' render.
    ``source`` "render": the rendered direction of the hair drawn over each segment (detached, where
    the render has hair), so no keyframe's image reaches a segment it does not show; "target": the
    keyframe's target direction, weighted by confidence inside the target mask.
    """
    fr = frames.to(data.K.device)
    free = drawn[None] + (moved - drawn[None]).detach()
    if source == "render":
        target = out.direction.detach()                                          # unit where not empty
        weight = (out.mask.detach() & (target.square().sum(-1) > 1e-12)).to(target.dtype)
    else:
        target = data.direction[fr]
        weight = data.confidence[fr] * (data.mask[fr] > 0.5)
    head = data.head_depth[fr] if data.head_depth is not None else None
    return hidden_direction_loss(free, hidden, data.K[fr], data.cam_from_head[fr], target, weight, head)


def outside_term(points: Tensor, data: FitData, frames: Tensor, tolerance: float) -> Tensor:
    """:func:`~vid2haircut.fit.image_terms.outside_loss` of (B,N,P,3) canonical strands in keyframes ``frames`` (B,).

    Raises:
        ValueError when ``data`` has no distance field (``FitData.outside``).
    """
    if data.outside is None:
        raise ValueError("the outside term needs FitData.outside (the targets' silhouette distance field)")
    fr = frames.to(data.K.device)
    hd = data.head_depth[fr] if data.head_depth is not None else None
    return outside_loss(points, data.K[fr], data.cam_from_head[fr], data.outside[fr], hd, tolerance)


class ZMap(nn.Module):
    """A coefficient map as an offset from its start: ``z = z0 + gain * texel_gain * delta`` (delta optimised).

    ``gain_k = (s_k / s_0) ** power`` with ``s_k`` the codec's per-component standard deviations
    (decreasing with k). Adam moves every parameter by about its learning rate per step whatever
    the gradient's size, so in the whitened PCA space it would move the fine (high-frequency)
    components as fast as the coarse ones and make strands wiggle; the gain slows the fine ones
    down (power 0: plain whitened coefficients; power 1: equal steps in metres).

    ``texel_gain`` (R,R) scales the steps of each texel (see :func:`length_step_gain`): a step of
    one whitened unit moves a strand by the same metres whether it is 4 cm or 40 cm long, so short
    hair would be moved proportionally much faster than long hair.

    Args:
        z0: (K,R,R) start map. scales: (K,) codec scales. power: see above.
        texel_gain: optional (R,R) per-texel step factor (default 1).
    """

    def __init__(self, z0: Tensor, scales: Tensor, power: float, texel_gain: Tensor | None = None) -> None:
        super().__init__()
        s = scales.detach().to(z0)
        gain = (s / s[0]).clamp_min(1e-12) ** float(power)
        self.register_buffer("z0", z0.detach().clone())
        g = gain[:, None, None]
        if texel_gain is not None:
            if texel_gain.shape != z0.shape[1:]:
                raise ValueError(f"ZMap: texel_gain shape {tuple(texel_gain.shape)} != map {tuple(z0.shape[1:])}")
            g = g * texel_gain.detach().to(z0)[None]
        self.register_buffer("gain", g)
        self.delta = nn.Parameter(torch.zeros_like(z0))

    def forward(self) -> Tensor:
        """(K,R,R) current map."""
        return self.z0 + self.gain * self.delta


@torch.no_grad()
def length_step_gain(z: Tensor, layout: GuideLayout, codec: StrandCodec, ref_length: float,
                     floor: float = 0.1) -> Tensor:
    """Per-texel step factor ``clamp(L / ref_length, floor, 1)`` of a (K,R,R) map -> (R,R).

    L is the length (metres) of the texel's guide decoded from ``z``; texels without a guide get 1.
    ``ref_length <= 0`` gives all ones (no scaling).
    """
    out = torch.ones(z.shape[1:], dtype=z.dtype, device=z.device)
    if ref_length <= 0:
        return out
    pts = decode_layout(z, layout, codec)
    length = (pts[:, 1:] - pts[:, :-1]).norm(dim=-1).sum(-1)
    out.view(-1)[layout.texel_index] = (length / ref_length).clamp(floor, 1.0)
    return out


def z_optimizer(kind: str, groups: list[dict]) -> torch.optim.Optimizer:
    """The optimiser of the hair-map groups: "shared_adam" (:class:`~vid2haircut.fit.optim.SharedAdam`) or "adam"."""
    from vid2haircut.fit.optim import SharedAdam

    if kind == "shared_adam":
        return SharedAdam(groups)
    if kind == "adam":
        return torch.optim.Adam(groups)
    raise ValueError(f"unknown z_optimizer {kind!r} (expected 'shared_adam' or 'adam')")
