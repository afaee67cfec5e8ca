"""Stage 1: single-view fit on the reference keyframe (the Im2Haircut baseline).

The hair map Z is initialised from the learned prior's prediction on the reference keyframe's
targets (the baldness mask is that prediction, fixed), then optimised for ``iterations`` steps (100)
with the silhouette, direction, depth and penetration losses, coarse to fine over the PCA
components (the first ``coarse_components`` only for ``coarse_steps`` steps: the gradient of the
others is cut). Two parameterisations:

- ``finetune_prior=True`` (Im2Haircut's recipe): the prior network's weights are fine-tuned (AdamW,
  lr 1e-4, weight decay 1e-3) and Z = net(x), x the prior input of the reference view;
- ``finetune_prior=False`` (default): Z itself is the parameter, as an offset from the prior's
  prediction (:class:`~vid2haircut.fit.scene.ZMap`, :class:`~vid2haircut.fit.optim.SharedAdam`).
  Measured on generated sequences (benchmarks/quality.py), fine-tuning the network fits the
  reference view but moves the hair that view does not see (the back, hair hidden behind other
  hair) far from the truth, ending worse than the prior alone; optimising Z leaves it in place.

Without a prior, Z starts at zeros (the codec's mean strand) on every valid scalp texel.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from vid2haircut.fit.config import Stage1Config
from vid2haircut.fit.data import FitData
from vid2haircut.fit.losses import bend_loss, penetration_loss
from vid2haircut.fit.scene import (ZMap, decode_layout, guide_layout, image_losses, length_step_gain, render_frames,
                                   outside_term, z_optimizer)
from vid2haircut.fit.trainer import History, Trainer
from vid2haircut.prior.codec import StrandCodec, component_mask
from vid2haircut.render import StrandRender

__all__ = ["Stage1Model", "FitResult", "initial_hairmap", "fit_stage1"]

log = logging.getLogger(__name__)


@dataclass
class FitResult:
    """Result of a fitting stage.

    Attributes:
        z: (K,R,R) final coefficient map (detached). mask: (R,R) baldness mask.
        guides: (N,P,3) canonical guide strands (detached, P = codec points).
        texel_index: (N,) flat texel index of each guide.
        history: loss history.
        render: the last render of the fitted keyframes (B = frames fitted), with ``frames``.
        frames: (B,) keyframe positions of ``render``.
        seconds: wall time of the optimisation.
        extra: stage-specific tensors (Stage 2: deformed points per keyframe, visibility, ...).
    """

    z: Tensor
    mask: Tensor
    guides: Tensor
    texel_index: Tensor
    history: History
    render: StrandRender
    frames: Tensor
    seconds: float
    extra: dict[str, Any]


def initial_hairmap(data: FitData, codec: StrandCodec, prior: tuple[nn.Module, Tensor] | None = None,
                    map_res: int = 32) -> tuple[Tensor, Tensor]:
    """Initial (z (K,R,R), mask (R,R)): the prior's prediction, or zeros on the whole valid scalp."""
    dev = data.K.device
    if prior is not None:
        net, x = prior
        with torch.no_grad():
            z, logits = net(x)
        return z[0].detach().to(dev), torch.sigmoid(logits[0]).detach().to(dev)
    from vid2haircut.prior.scalp import scalp_mask_cached

    mask = torch.as_tensor(scalp_mask_cached(data.head, map_res), dtype=torch.float32, device=dev)
    return torch.zeros(codec.k, map_res, map_res, device=dev), mask


def prior_view_input(data: FitData, size: int, device: torch.device | str) -> Tensor:
    """The prior network's input (1,C,S,S) from the reference keyframe's full-resolution targets."""
    from vid2haircut.prior.model import prior_input

    if data.reference_targets is None or data.reference_camera is None:
        raise ValueError("the fit data has no full-resolution reference targets for the prior")
    t, (K, w2c) = data.reference_targets, data.reference_camera
    return prior_input(t["mask"], t["angle"], t["depth"], t["depth_valid"], K, w2c, data.world_from_head[0],
                       size=size, device=device)


class Stage1Model(nn.Module):
    """Hair map of the reference keyframe with its loss dict.

    Args:
        data: fit data whose keyframe 0 is the reference (only it is used).
        codec: strand codec (K components).
        cfg: Stage 1 settings.
        z_init: (K,R,R) initial map (used when there is no prior net).
        mask: (R,R) baldness mask (fixed).
        net: prior network to fine-tune (None: optimise Z directly); x: its (1,C,S,S) input.
    """

    def __init__(self, data: FitData, codec: StrandCodec, cfg: Stage1Config, z_init: Tensor, mask: Tensor,
                 net: nn.Module | None = None, x: Tensor | None = None) -> None:
        super().__init__()
        self.data, self.codec, self.cfg = data.subset([0]), codec, cfg
        self.net = net
        if net is not None:
            if x is None:
                raise ValueError("Stage1Model: a prior net needs its input x")
            self.register_buffer("x", x)
        self.register_buffer("mask", mask.detach().clone())
        dev = mask.device
        self.layout = guide_layout(data.head, mask, cfg.mask_threshold, codec.n_points, cfg.render.n_points, dev)
        if net is None:
            tg = length_step_gain(z_init, self.layout, codec, cfg.length_step_ref)
            self.zmap = ZMap(z_init, codec.scales[: z_init.shape[0]], cfg.lr_gain_power, tg)
        self.frames = torch.zeros(1, dtype=torch.long, device=dev)
        self.last_render: StrandRender | None = None

    def current_z(self, step: int | None = None) -> Tensor:
        """(K,R,R) map; during the coarse steps only the first components carry a gradient."""
        z = self.net(self.x)[0][0] if self.net is not None else self.zmap()
        if step is not None and step < self.cfg.coarse_steps and self.cfg.coarse_components < z.shape[0]:
            keep = component_mask(self.cfg.coarse_components, z.shape[0], z.device, z.dtype)[:, None, None]
            z = z * keep + z.detach() * (1.0 - keep)
        return z

    def get_param_groups(self) -> list[dict]:
        """One group: the prior's weights (AdamW settings) or Z (Adam)."""
        if self.net is not None:
            return [{"params": [p for p in self.net.parameters() if p.requires_grad], "lr": self.cfg.lr_prior,
                     "weight_decay": self.cfg.weight_decay_prior, "name": "prior"}]
        return [{"params": [self.zmap.delta], "lr": self.cfg.lr_z, "name": "z"}]

    def make_optimizers(self) -> list[torch.optim.Optimizer]:
        """AdamW for the prior net; for Z the configured ``z_optimizer``."""
        groups = self.get_param_groups()
        if self.net is not None:
            return [torch.optim.AdamW(groups)]
        return [z_optimizer(self.cfg.z_optimizer, groups)]

    def get_loss_dict(self, step: int) -> dict[str, Tensor]:
        """silhouette, direction, depth (reference keyframe), penetration and (when weighted) bend terms."""
        pts = decode_layout(self.current_z(step), self.layout, self.codec)          # (N,P,3)
        render_pts = pts[:, self.layout.render_index]
        out = render_frames(render_pts[None], self.data, self.frames, self.cfg.render)
        self.last_render = out
        losses = image_losses(out, self.data, self.frames, depth_head=self.cfg.depth_head)
        losses["penetration"] = penetration_loss(pts, self.data.head.sdf, self.cfg.penetration_margin)
        if self.cfg.weights.outside > 0.0:
            losses["outside"] = outside_term(render_pts[None], self.data, self.frames, self.cfg.outside_tolerance)
        if self.cfg.weights.bend > 0.0:
            losses["bend"] = bend_loss(pts, self.cfg.min_bend_radius)
        return losses

    @torch.no_grad()
    def final(self) -> tuple[Tensor, Tensor]:
        """(z (K,R,R), guides (N,P,3)) of the current parameters, detached."""
        z = self.current_z().detach()
        return z, decode_layout(z, self.layout, self.codec)


def fit_stage1(data: FitData, codec: StrandCodec, cfg: Stage1Config, prior: tuple[nn.Module, Tensor] | None = None,
               z_init: Tensor | None = None, mask: Tensor | None = None, progress: bool = True) -> FitResult:
    """Run Stage 1.

    Args:
        data: fit data (keyframe 0 = reference).
        codec: strand codec.
        cfg: settings (iterations, learning rates, weights, ...).
        prior: (net, x) to fine-tune, or None to optimise Z directly.
        z_init, mask: initial map and mask (default :func:`initial_hairmap`).
        progress: show a tqdm bar.

    Returns:
        :class:`FitResult` (render of the reference keyframe).
    """
    dev = data.K.device
    codec = codec.to(dev)
    if z_init is None or mask is None:
        z0, m0 = initial_hairmap(data, codec, prior, cfg.map_res)
        z_init = z0 if z_init is None else z_init
        mask = m0 if mask is None else mask
    if prior is not None and cfg.finetune_prior:
        net = prior[0].to(dev)
        net.eval()
        for p in net.parameters():
            p.requires_grad_(True)
        model = Stage1Model(data, codec, cfg, z_init, mask, net, prior[1].to(dev))
    else:
        model = Stage1Model(data, codec, cfg, z_init.to(dev), mask.to(dev))
    trainer = Trainer(model, model.make_optimizers(), cfg.weights)
    t0 = time.perf_counter()
    trainer.run(0, cfg.iterations, desc="stage1", progress=progress)
    with torch.no_grad():
        model.get_loss_dict(cfg.iterations)            # render of the final state
    z, guides = model.final()
    seconds = time.perf_counter() - t0
    log.info("stage1: %d steps in %.1fs, final %s", cfg.iterations, seconds,
             {k: round(v[-1], 5) for k, v in trainer.history.terms.items()})
    return FitResult(z, model.mask, guides, model.layout.texel_index, trainer.history, model.last_render,
                     model.frames, seconds, {})
