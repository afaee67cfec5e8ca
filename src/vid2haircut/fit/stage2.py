"""Stage 2: joint refinement over all keyframes (Vid2Haircut).

Canonical guide strands are decoded from the shared hair map Z (initialised from Stage 1), copied
once per keyframe through the :class:`~vid2haircut.fit.visibility.VisibilityGate`, moved by the
deformation field (after ``canonical_steps`` steps, ramped in over ``ramp_steps``) and rendered with
the keyframe's camera ``cam_from_head = world_2_cam @ T_t`` (so ``x_t = T_t(x + dx_t)``). Loss:

    silhouette + direction + depth (all rendered keyframes) + penetration (canonical and deformed)
    + smoothness of length and direction (canonical) + PCA consistency (unobserved texels)
    + anchor (guide points that no keyframe shows stay near their Stage 1 positions; optional)
    + canonical (zero offsets in the reference keyframe) + motion + frame-code regularisers.

Switches (``Stage2Config.switches``) remove the deformation, the smoothness, the visibility
masking or the PCA consistency, each with one setting.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Callable

import torch
from torch import Tensor, nn

from vid2haircut.fit.config import Stage2Config
from vid2haircut.fit.data import FitData
from vid2haircut.fit.deform import DeformationField, DeformConfig, rechain
from vid2haircut.fit.hidden import harmonic_extension, head_normals
from vid2haircut.fit.losses import (anchor_loss, bend_loss, gravity_loss, motion_loss, pca_consistency_loss,
                                    penetration_loss, smoothness_losses, tip_height_loss,
                                    unit_directions)
from vid2haircut.fit.scene import (ZMap, decode_layout, drawn_compositing, guide_layout, image_losses, length_step_gain,
                                   render_frames, hidden_direction_term, outside_term, z_optimizer)
from vid2haircut.fit.stage1 import FitResult
from vid2haircut.fit.trainer import History, Trainer, lr_decay_factor
from vid2haircut.fit.visibility import (VisibilityGate, check_visibility_unit, gate_visibility, point_visibility,
                                        texel_visible_fraction)
from vid2haircut.prior.codec import StrandCodec

__all__ = ["Stage2Model", "fit_stage2"]

log = logging.getLogger(__name__)


class Stage2Model(nn.Module):
    """Canonical hair map + deformation field over M keyframes, with its loss dict.

    Args:
        data: fit data (keyframe 0 = the reference, whose offsets are regularised to zero).
        codec: strand codec.
        cfg: Stage 2 settings.
        z_init: (K,R,R) initial map (Stage 1's). mask: (R,R) baldness mask (fixed).
    """

    def __init__(self, data: FitData, codec: StrandCodec, cfg: Stage2Config, z_init: Tensor, mask: Tensor) -> None:
        super().__init__()
        self.data, self.codec, self.cfg = data, codec, cfg
        dev = z_init.device
        self.register_buffer("mask", mask.detach().clone())
        self.layout = guide_layout(data.head, mask, cfg.mask_threshold, codec.n_points, cfg.render.n_points, dev)
        tg = length_step_gain(z_init, self.layout, codec, cfg.length_step_ref)
        self.zmap = ZMap(z_init, codec.scales[: z_init.shape[0]].to(dev), cfg.lr_gain_power, tg)
        n = int(self.layout.texel_index.numel())
        dcfg = DeformConfig(max_offset=cfg.max_offset, code_init_std=cfg.code_init_std)
        self.deform = (DeformationField(data.n_frames, n, dcfg, seed=cfg.seed)
                       .to(dev) if cfg.switches.use_deformation else None)
        check_visibility_unit(cfg.visibility_unit)
        for key in ("pca_from", "smooth_direction_from", "smooth_length_from"):
            if getattr(cfg, key) < 0:
                raise ValueError(f"Stage 2: {key} must be >= 0, got {getattr(cfg, key)}")
        self.gate = VisibilityGate(cfg.switches.use_visibility)
        self.register_buffer("seen", torch.zeros(data.n_frames, n, device=dev))
        pr = int(self.layout.render_index.numel())
        # per keyframe, the guide points of its latest render that it shows (cfg.weights.anchor)
        self.register_buffer("points_seen", torch.zeros(data.n_frames, n, pr, dtype=torch.bool, device=dev))
        with torch.no_grad():
            self.register_buffer("start", decode_layout(z_init, self.layout, codec)[:, self.layout.render_index])
        # what the "relative" and "change" direction smoothness compare with (derived from the start,
        # so not part of a checkpoint)
        self.register_buffer("start_directions", unit_directions(self.start), persistent=False)
        # the anchor leaves hidden points free to move away from the head (cfg.anchor_outward)
        self.outward = head_normals(self.start, data.head.sdf) if cfg.anchor_outward else None
        # texels that follow the observed change (cfg.extend_unobserved): fixed after the first render
        self.register_buffer("follow", torch.zeros(n, dtype=torch.bool, device=dev))
        self._extension: Tensor | None = None
        # with cfg.render_dense: the guide whose offsets move each dense strand (the nearest in uv)
        self._dense_owner = self._nearest_guides(mask) if cfg.render_dense > 0 else None
        self.last_render = None
        self._bins_vis: dict[tuple, Tensor] = {}  # cfg.gate_bins_every: the binned visibility per (frames, shape)
        self._gate_from_bins = cfg.gate_bins_every > 0 and drawn_compositing(cfg.render, data) == "exact"
        self.last_frames: Tensor | None = None
        self.last_deformed: Tensor | None = None

    # -- schedule -------------------------------------------------------------------------------
    def frames_for_step(self, step: int) -> Tensor:
        """(B,) keyframe positions rendered at ``step``: all, or a rotating window of ``frames_per_step``."""
        m, k = self.data.n_frames, int(self.cfg.frames_per_step)
        if k <= 0 or k >= m:
            idx = list(range(m))
        else:
            start = (step * k) % m
            idx = sorted((start + i) % m for i in range(k))
        return torch.as_tensor(idx, dtype=torch.long, device=self.zmap.z0.device)

    def ramp(self, step: int) -> float:
        """Deformation scale at ``step``: 0 during the canonical steps, then linear to 1 over the ramp."""
        if self.deform is None or step < self.cfg.canonical_steps:
            return 0.0
        return float(min(1.0, (step - self.cfg.canonical_steps + 1) / max(1, self.cfg.ramp_steps)))

    # -- model API ------------------------------------------------------------------------------
    def get_param_groups(self) -> list[dict]:
        """Z, and the deformation MLP / frame codes (method.md learning rates)."""
        groups = [{"params": [self.zmap.delta], "lr": self.cfg.lr_z, "name": "z"}]
        if self.deform is not None:
            groups += self.deform.param_groups(self.cfg.lr_mlp, self.cfg.lr_codes)
        return groups

    def make_optimizers(self) -> list[torch.optim.Optimizer]:
        """The configured ``z_optimizer`` for Z, Adam for the deformation field."""
        groups = self.get_param_groups()
        opts = [z_optimizer(self.cfg.z_optimizer, groups[:1])]
        if len(groups) > 1:
            opts.append(torch.optim.Adam(groups[1:]))
        return opts

    @property
    def z(self) -> Tensor:
        """(K,R,R) current hair map.

        With ``cfg.extend_unobserved`` the guides that no keyframe observed at the start also move
        by the harmonic extension (over the scalp map's neighbour graph) of the change that Stage 2
        has made to the observed ones so far (detached: the unseen hair follows the seen hair,
        never the reverse); their own coefficients stay free for the geometry terms.
        """
        z = self.zmap()
        if not self.cfg.extend_unobserved or not bool(self.follow.any()):
            return z
        if self._extension is None:
            ext = harmonic_extension(self.layout.graph.pairs, int(self.follow.numel()), ~self.follow)
            self._extension = ext.to(z)
        k = z.shape[0]
        flat = z.reshape(k, -1)
        tix = self.layout.texel_index
        change = (flat[:, tix] - self.zmap.z0.reshape(k, -1)[:, tix]).detach()       # (K,N)
        add = torch.zeros_like(flat)
        add[:, tix[self.follow]] = change[:, ~self.follow] @ self._extension.T
        return z + add.reshape(z.shape)

    def _freeze_follow(self) -> None:
        """After the first render: the guides seen in no keyframe follow the seen ones from now on."""
        if self.cfg.extend_unobserved and not bool(self.follow.any()) and bool(self.seen.any()):
            seen = self._seen_guides()
            if bool(seen.any()) and not bool(seen.all()):
                self.follow.copy_(~seen)
                self._extension = None

    def canonical(self) -> Tensor:
        """(N,P,3) canonical guides (codec points) of the current Z."""
        return decode_layout(self.z, self.layout, self.codec)

    def _nearest_guides(self, mask: Tensor) -> Tensor:
        """(D,) index of the guide whose texel centre lies nearest (in scalp uv) to each of the
        ``cfg.render_dense`` dense strands' roots."""
        from vid2haircut.fit.outputs import decode_dense_map

        with torch.no_grad():
            uv = decode_dense_map(self.zmap.z0, mask, self.data.head, self.codec, self.cfg.render_dense,
                                  self.cfg.seed, self.cfg.mask_threshold).uv
        res, tix = self.layout.res, self.layout.texel_index
        centres = (torch.stack(((tix % res), (tix // res)), -1).to(uv) + 0.5) / res      # (N,2) u = column
        return torch.cdist(uv, centres).argmin(1)

    def draws_dense(self, step: int) -> bool:
        """Whether ``step`` draws the dense strands (``cfg.render_dense`` from ``cfg.dense_from_step``,
        or from ``cfg.canonical_steps`` when that is negative)."""
        start = self.cfg.dense_from_step if self.cfg.dense_from_step >= 0 else self.cfg.canonical_steps
        return self.cfg.render_dense > 0 and step >= start

    def dense(self) -> Tensor:
        """(D,P,3) ``cfg.render_dense`` dense strands of the current Z, decoded as the output is
        (:func:`vid2haircut.fit.outputs.decode_dense_map`), differentiable."""
        from vid2haircut.fit.outputs import decode_dense_map

        return decode_dense_map(self.z, self.mask, self.data.head, self.codec, self.cfg.render_dense,
                                self.cfg.seed, self.cfg.mask_threshold).points

    def deformed(self, canon_render: Tensor, frames: Tensor, scale: float,
                 guides: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """Per-frame strands, their offsets and the per-frame guides: (N,Pr,3) canonical ->
        ((B,N,Pr,3), (B,N,Pr,3), (B,G,Pr,3)).

        The per-frame copies pass through the visibility gate; with the deformation off (or scale
        0) the offsets are exactly zero and the strands equal the canonical ones. ``guides``
        (G,Pr,3): when ``canon_render`` holds ``cfg.render_dense`` dense strands, the field is
        evaluated at these canonical guides (detached) and every dense strand takes the offsets of
        its nearest guide, point by point, before its segment lengths are restored; the moved
        guides are returned too (the penetration term takes them, as without dense drawing).
        Without ``guides`` the third item is the first.
        """
        b = int(frames.numel())
        per_frame = self.gate(canon_render[None].expand(b, -1, -1, -1))
        if self.deform is None or scale == 0.0:
            still = per_frame if guides is None else guides[None].expand(b, -1, -1, -1)
            return per_frame, torch.zeros_like(per_frame), still
        if guides is None:
            moved, offs = self.deform.forward_batch(per_frame, frames, scale=scale)
            return moved, offs, moved
        g_moved, g_offs = self.deform.forward_batch(guides[None].expand(b, -1, -1, -1), frames, scale=scale,
                                                    detach_input=True)
        offs = g_offs[:, self._dense_owner]
        seg_len = (per_frame[:, :, 1:] - per_frame[:, :, :-1]).norm(dim=-1)
        return rechain(per_frame + offs, seg_len), offs, g_moved

    def _binned_visibility(self, moved: Tensor, frames: Tensor, drawing, step: int) -> Tensor:
        """(B,N,P-1) bool: the visibility of ``moved`` (B,N,P,3) in ``frames`` rendered with the binned
        model (``cfg.gate_bins_every``), made at the steps divisible by it and when these frames or
        this strand count have none yet, else the last one made."""
        key = (tuple(frames.tolist()), tuple(moved.shape))
        if step % self.cfg.gate_bins_every == 0 or key not in self._bins_vis:
            # (opaque: the visibility is the opaque render's either way, without a second silhouette to walk)
            binned = dataclasses.replace(drawing, compositing="bins", silhouette_opacity=1.0)
            with torch.no_grad():
                self._bins_vis[key] = render_frames(moved.detach(), self.data, frames, binned).visibility
        return self._bins_vis[key]

    def _fine_only(self, z: Tensor, canon: Tensor, first: int) -> Tensor:
        """(N,P,3) the canonical guides ``canon`` (decoded from the map ``z``) with the same values,
        through which gradients reach only the components ``first``.. of ``z`` (``canon`` for 0)."""
        if first <= 0:
            return canon
        return decode_layout(torch.cat((z[:first].detach(), z[first:])), self.layout, self.codec)

    def get_loss_dict(self, step: int) -> dict[str, Tensor]:
        """All Stage 2 terms at ``step`` (see the module docstring)."""
        cfg = self.cfg
        frames = self.frames_for_step(step)
        z_now = self.z                                                             # (K,R,R)
        canon = decode_layout(z_now, self.layout, self.codec)                      # (N,P,3)
        scale = self.ramp(step)
        dense = self.draws_dense(step)
        drawn = self.dense() if dense else canon
        moved, offs, moved_guides = self.deformed(drawn[:, self.layout.render_index], frames, scale,
                                                  canon[:, self.layout.render_index] if dense else None)
        drawing = cfg.render if not dense else dataclasses.replace(
            cfg.render, strand_width=cfg.dense_width, silhouette_opacity=cfg.dense_silhouette_opacity,
            vis_weight=cfg.dense_vis_weight)
        out = render_frames(moved, self.data, frames, drawing)
        if self._gate_from_bins:
            out = out._replace(visibility=self._binned_visibility(moved, frames, drawing, step))
        self.gate.set_visibility(gate_visibility(out.visibility, cfg.visibility_unit))
        with torch.no_grad():
            # what the guides show: their visibility, which is the opaque render's (no translucent silhouette)
            guides = out if not dense else render_frames(
                canon[None, :, self.layout.render_index].expand(len(frames), -1, -1, -1), self.data, frames,
                dataclasses.replace(cfg.render, silhouette_opacity=1.0))
            self.seen[frames] = texel_visible_fraction(guides.visibility).to(self.seen.dtype)
            self.points_seen[frames] = point_visibility(guides.visibility)
            self._freeze_follow()
        self.last_render, self.last_frames, self.last_deformed = out, frames, moved.detach()
        losses = image_losses(out, self.data, frames, cfg.depth_align, cfg.depth_head)
        if cfg.weights.hidden_direction > 0.0 and cfg.switches.use_visibility:
            hidden = ~gate_visibility(out.visibility, cfg.visibility_unit)
            losses["hidden_direction"] = hidden_direction_term(drawn[:, self.layout.render_index], moved, hidden, out,
                                                               self.data, frames, cfg.hidden_direction_from)
        if cfg.weights.outside > 0.0:
            losses["outside"] = outside_term(moved, self.data, frames, cfg.outside_tolerance)
        pen = penetration_loss(canon, self.data.head.sdf, self.cfg.penetration_margin)
        if scale > 0.0:
            pen = pen + penetration_loss(moved_guides, self.data.head.sdf, self.cfg.penetration_margin)
        losses["penetration"] = pen
        if cfg.switches.use_smoothness:
            back = cfg.weights.smooth_length_back / max(cfg.weights.smooth_length, 1e-12)
            ri = self.layout.render_index
            along = self._fine_only(z_now, canon, cfg.smooth_direction_from)
            length = (None if cfg.smooth_length_from == cfg.smooth_direction_from
                      else self._fine_only(z_now, canon, cfg.smooth_length_from)[:, ri])
            losses.update(smoothness_losses(along[:, ri], self.layout.graph, back,
                                            length_scale=cfg.smooth_length_scale,
                                            direction_scale=cfg.smooth_direction_scale,
                                            length_points=length, strand_weight=self._smooth_weight(),
                                            reference_directions=self.start_directions,
                                            direction_form=cfg.smooth_direction_form))
            if cfg.weights.smooth_tip > 0.0:
                losses["smooth_tip"] = tip_height_loss(canon[:, ri], self.layout.graph,
                                                       cfg.smooth_tip_scale)
        if cfg.weights.anchor > 0.0:
            # guides that follow the seen change are held at their start plus that change: the anchor
            # sees their own coefficients only, so it cannot undo the extension
            held = (decode_layout(self.zmap(), self.layout, self.codec) if bool(self.follow.any())
                    else canon)
            losses["anchor"] = anchor_loss(held[:, self.layout.render_index], self.start,
                                           ~self.points_seen.any(0), self.outward)
        if cfg.weights.bend > 0.0:
            losses["bend"] = bend_loss(canon, cfg.min_bend_radius)
        if cfg.weights.gravity > 0.0:
            losses["gravity"] = gravity_loss(canon[:, self.layout.render_index])
        if cfg.switches.use_pca_consistency:
            z = self.z - self.zmap.z0 if cfg.pca_change else self.z
            losses["pca"] = pca_consistency_loss(z[cfg.pca_from:], self.layout.hair, self.observed())
        if scale > 0.0:
            losses["motion"] = motion_loss(offs)
            ref = (frames == 0).nonzero()
            if ref.numel():
                losses["canonical"] = motion_loss(offs[int(ref[0, 0])])
            losses["frame_code"] = self.deform.regularizers()["frame_code"]
        return losses

    def observed(self) -> Tensor:
        """(R,R) bool texels whose guide was seen (visible fraction >= observed_fraction) in some keyframe."""
        res = self.layout.res
        obs = torch.zeros(res * res, dtype=torch.bool, device=self.zmap.z0.device)
        obs[self.layout.texel_index] = self._seen_guides()
        return obs.reshape(res, res)

    def _smooth_weight(self) -> Tensor | None:
        """(N,) factor on the smoothness of each guide (``smooth_seen_weight`` on the guides some
        keyframe observed, ``smooth_unseen_weight`` on the others), or None when both are 1."""
        cfg = self.cfg
        if cfg.smooth_seen_weight == 1.0 and cfg.smooth_unseen_weight == 1.0:
            return None
        seen = self._seen_guides()
        return torch.where(seen, cfg.smooth_seen_weight, cfg.smooth_unseen_weight).to(self.zmap.z0.dtype)

    def _seen_guides(self) -> Tensor:
        """(N,) bool guides whose visible fraction reached ``observed_fraction`` in some keyframe."""
        return self.seen.amax(0) >= self.cfg.observed_fraction

    @torch.no_grad()
    def render_all(self, step: int) -> None:
        """Render every keyframe at the deformation scale of ``step`` (sets ``last_*``)."""
        frames = torch.arange(self.data.n_frames, device=self.zmap.z0.device)
        canon = self.canonical()
        moved, _, _ = self.deformed(canon[:, self.layout.render_index], frames, self.ramp(step))
        out = render_frames(moved, self.data, frames, self.cfg.render)
        self.gate.mask = None
        self.last_render, self.last_frames, self.last_deformed = out, frames, moved


def fit_stage2(data: FitData, codec: StrandCodec, cfg: Stage2Config, z_init: Tensor, mask: Tensor,
               progress: bool = True, resume: dict | None = None,
               on_step: Callable[[int, "Stage2Model", Trainer], None] | None = None) -> FitResult:
    """Run Stage 2.

    Args:
        data: fit data with M keyframes (keyframe 0 = reference; use ``data.subset`` for fewer).
        codec: strand codec.
        cfg: settings.
        z_init, mask: Stage 1's map and baldness mask.
        progress: show a tqdm bar.
        resume: a checkpoint dict (:func:`checkpoint_state`) to continue from.
        on_step: called after every step with (step, model, trainer) (checkpointing).

    Returns:
        :class:`FitResult`; ``extra`` holds ``deform`` (the field or None), ``deformed`` (M,N,Pr,3)
        per-keyframe strands and ``observed`` (R,R).
    """
    dev = data.K.device
    codec = codec.to(dev)
    model = Stage2Model(data, codec, cfg, z_init.to(dev), mask.to(dev))
    optimizers = model.make_optimizers()
    history, start = History(), 0
    if resume is not None:
        model.load_state_dict(resume["model"])
        model._bins_vis = {(tuple(f), tuple(shape)): v.to(dev) for f, shape, v in resume.get("bins_visibility", [])}
        for opt, st in zip(optimizers, resume["optimizers"]):
            opt.load_state_dict(st)
        history, start = History.from_dict(resume["history"]), int(resume["step"]) + 1
        log.info("stage2: resuming after step %d", start - 1)
    decay = None if cfg.lr_decay_steps <= 0 else (
        lambda s: lr_decay_factor(s, cfg.iterations, cfg.lr_decay_steps, cfg.lr_final))
    trainer = Trainer(model, optimizers, cfg.weights, history, lr_factor=decay)
    t0 = time.perf_counter()
    trainer.run(start, cfg.iterations, desc="stage2", progress=progress,
                on_step=None if on_step is None else (lambda s: on_step(s, model, trainer)))
    model.render_all(cfg.iterations)
    seconds = time.perf_counter() - t0
    with torch.no_grad():
        z = model.z.detach().clone()
        guides = model.canonical().detach()
    log.info("stage2: steps %d..%d in %.1fs", start, cfg.iterations, seconds)
    return FitResult(z, model.mask, guides, model.layout.texel_index, trainer.history, model.last_render,
                     model.last_frames, seconds, {"deform": model.deform, "deformed": model.last_deformed,
                                                  "observed": model.observed(), "model": model})


def checkpoint_state(step: int, model: Stage2Model, trainer: Trainer) -> dict:
    """Everything needed to resume after ``step`` (tensors on the CPU; with ``gate_bins_every``, the
    binned visibility the gate holds until its next render, so that a resumed fit is the same for
    any ``checkpoint_every``)."""
    return {"step": int(step), "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
            "optimizers": [opt.state_dict() for opt in trainer.optimizers],
            "history": trainer.history.to_dict(),
            "bins_visibility": [[list(f), list(shape), v.cpu()] for (f, shape), v in model._bins_vis.items()]}
