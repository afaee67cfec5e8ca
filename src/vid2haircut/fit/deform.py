"""Per-frame hair deformation (Vid2Haircut): canonical strands -> strands at keyframe t.

    x_t = T_t(x + dx_t),   dx_t = w(u) * max_offset * (a * n + b * b_),   (a, b) = clamp(f_theta(...), -1, 1)

``f_theta`` is a small MLP of the canonical point, its segment vector, a positional encoding of the
root-to-tip coordinate u in [0, 1], a per-strand (texel) embedding and a per-frame latent code.
The offset acts along the strand's normal ``n`` and binormal ``b_`` (a frame built from the strand's
tangent and the head's up axis), so the MLP cannot stretch strands; segment lengths are restored
afterwards by re-chaining each strand from its root with the canonical segment lengths.

Defaults follow method.md: frame code size 4 lifted by Linear(4,128)-SiLU-Linear(128,128)-SiLU;
texel embedding size 8 initialised to zero; 2 positional-encoding frequencies; MLP in->128 Softplus
->128 Softplus->2; max offset 8 mm; the first 10 of 99 segments pinned. The paper's weight
``0.095 u^2`` is given on the un-pinned part with u in segment units of a 100-point strand; we use its
normalised form ``w(u) = ((u - u_pin) / (1 - u_pin))^2`` for u > u_pin (0 at and near the root,
1 at the tip), so ``max_offset`` alone sets the largest tip motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn


@dataclass
class DeformConfig:
    """Deformation-MLP settings."""

    frame_code_dim: int = 4
    """Size of the per-frame latent code z_t."""
    frame_feat_dim: int = 128
    """Width of the lifted frame feature."""
    texel_dim: int = 8
    """Size of the per-strand (texel) embedding, zero-initialised."""
    hidden: int = 128
    """Hidden width of the offset MLP."""
    n_freqs: int = 2
    """Positional-encoding frequencies of the root-to-tip coordinate."""
    max_offset: float = 0.008
    """Largest offset in metres (at the tip)."""
    pinned_fraction: float = 10 / 99
    """Root part of every strand that never moves (first 10 of 99 segments)."""
    code_init_std: float = 0.01
    """Standard deviation of the initial frame codes (larger: frames distinguishable from the start)."""


def deformation_weight(u: torch.Tensor, pinned_fraction: float) -> torch.Tensor:
    """w(u): 0 on the pinned root part, growing quadratically to 1 at the tip. u: (...,) in [0,1]."""
    s = ((u - pinned_fraction) / (1.0 - pinned_fraction)).clamp(min=0.0)
    return s * s


def strand_frames(points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-point normal and binormal of strands. points: (N,P,3) -> ((N,P,3), (N,P,3)) unit vectors.

    The tangent comes from neighbouring points; the normal is the component of a reference axis
    (head up, +y, or +x where the tangent is nearly vertical) orthogonal to it.
    """
    t = torch.zeros_like(points)
    t[:, 1:-1] = points[:, 2:] - points[:, :-2]
    t[:, 0] = points[:, 1] - points[:, 0]
    t[:, -1] = points[:, -1] - points[:, -2]
    t = t / t.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    up = torch.tensor([0.0, 1.0, 0.0], dtype=points.dtype, device=points.device).expand_as(t)
    side = torch.tensor([1.0, 0.0, 0.0], dtype=points.dtype, device=points.device).expand_as(t)
    ref = torch.where((t * up).sum(-1, keepdim=True).abs() > 0.9, side, up)
    n = ref - (ref * t).sum(-1, keepdim=True) * t
    n = n / n.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    b = torch.cross(t, n, dim=-1)
    return n, b


def _segments(points: torch.Tensor) -> torch.Tensor:
    """Segment vectors of strands (...,P,3) -> (...,P,3): x_{i+1} - x_i, the last one repeated."""
    seg = points[..., 1:, :] - points[..., :-1, :]
    return torch.cat([seg, seg[..., -1:, :]], dim=-2)


def rechain(points: torch.Tensor, seg_len: torch.Tensor) -> torch.Tensor:
    """Restore segment lengths: walk each strand from its root along the moved segment directions.

    points: (..., P, 3); seg_len: (..., P-1) target lengths -> (..., P, 3) with points[..., 0] unchanged.
    """
    d = points[..., 1:, :] - points[..., :-1, :]
    d = d / d.norm(dim=-1, keepdim=True).clamp(min=1e-12) * seg_len[..., None]
    return torch.cat([points[..., :1, :], points[..., :1, :] + torch.cumsum(d, dim=-2)], dim=-2)


class DeformationField(nn.Module):
    """f_theta with its per-frame codes and per-strand embeddings.

    Args:
        n_frames: number of keyframes T.
        n_strands: number of guide strands (texels) N.
        cfg: settings.
    """

    def __init__(self, n_frames: int, n_strands: int, cfg: DeformConfig | None = None, seed: int = 0):
        super().__init__()
        self.cfg = cfg or DeformConfig()
        c = self.cfg
        self.frame_codes = nn.Embedding(n_frames, c.frame_code_dim)
        self.frame_lift = nn.Sequential(nn.Linear(c.frame_code_dim, c.frame_feat_dim), nn.SiLU(),
                                        nn.Linear(c.frame_feat_dim, c.frame_feat_dim), nn.SiLU())
        self.texel_embed = nn.Embedding(n_strands, c.texel_dim)
        in_dim = 3 + 3 + 1 + 4 * c.n_freqs + c.texel_dim + c.frame_feat_dim
        self.mlp = nn.Sequential(nn.Linear(in_dim, c.hidden), nn.Softplus(),
                                 nn.Linear(c.hidden, c.hidden), nn.Softplus(), nn.Linear(c.hidden, 2))
        self.reset_parameters(seed)

    @torch.no_grad()
    def reset_parameters(self, seed: int = 0) -> None:
        """Deterministic initialisation from ``seed`` (a private ``torch.Generator``, global RNG untouched).

        Frame codes ~ N(0, code_init_std^2); linear layers uniform in +-1/sqrt(fan_in) (PyTorch's default
        bounds); texel embeddings zero; the last layer zero, so the field starts at rest (zero offsets).
        """
        g = torch.Generator().manual_seed(int(seed))
        w = self.frame_codes.weight
        w.copy_(torch.randn(w.shape, generator=g) * self.cfg.code_init_std)
        for layer in [m for m in self.modules() if isinstance(m, nn.Linear)]:
            bound = 1.0 / math.sqrt(layer.in_features)
            for p in (layer.weight, layer.bias):
                p.copy_((torch.rand(p.shape, generator=g) * 2.0 - 1.0) * bound)
        nn.init.zeros_(self.texel_embed.weight)
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)

    def param_groups(self, lr_mlp: float, lr_codes: float) -> list[dict]:
        """Optimiser parameter groups; the learning rates come from ``Stage2Config.lr_mlp`` / ``lr_codes``."""
        codes = [self.frame_codes.weight]
        rest = [p for n, p in self.named_parameters() if n != "frame_codes.weight"]
        return [{"params": rest, "lr": lr_mlp, "name": "deform_mlp"},
                {"params": codes, "lr": lr_codes, "name": "frame_codes"}]

    def offsets(self, points: torch.Tensor, frame: int, strand_index: torch.Tensor | None = None) -> torch.Tensor:
        """Canonical-space offsets dx_t of one keyframe. points: (N,P,3) canonical strands -> (N,P,3).

        ``strand_index`` (N,) selects the texel embeddings (default arange(N)).
        """
        frames = torch.tensor([int(frame)], device=points.device)
        return self.offsets_batch(points[None], frames, strand_index)[0]

    def offsets_batch(self, points: torch.Tensor, frames: torch.Tensor,
                      strand_index: torch.Tensor | None = None) -> torch.Tensor:
        """Offsets of several keyframes in one pass. points: (B,N,P,3) canonical strands (one copy
        per keyframe, or one copy expanded); frames: (B,) keyframe positions -> (B,N,P,3).

        The MLP's input is the concatenation [10 x, 100 dx, enc(u), texel embedding, frame feature]
        (``in_dim`` wide); its first layer is evaluated block by block, which is the same function
        with fewer operations: the texel and positional-encoding blocks give one (N,P,hidden) term
        shared by every keyframe, the frame feature one hidden-wide bias per keyframe, and only the
        six geometric inputs are multiplied per point (one matrix product per keyframe that also
        adds the shared term and the keyframe's bias). :meth:`offsets_reference` is the plain
        concatenated form.
        """
        c = self.cfg
        b, n_str, n_pts, _ = points.shape
        dev, dt = points.device, points.dtype
        if strand_index is None:
            strand_index = torch.arange(n_str, device=dev)
        u, enc = self._encoding(n_pts, dev, dt)
        first = self.mlp[0]
        weight = first.weight                                               # (hidden, in_dim)
        n_enc, n_tex = enc.shape[1], c.texel_dim
        w_geo, w_enc = weight[:, :6], weight[:, 6:6 + n_enc]
        w_tex, w_frame = weight[:, 6 + n_enc:6 + n_enc + n_tex], weight[:, 6 + n_enc + n_tex:]
        shared = (self.texel_embed(strand_index) @ w_tex.T)[:, None, :] + (enc @ w_enc.T)[None]     # (N,P,H)
        frame_bias = self.frame_lift(self.frame_codes(frames.to(dev))) @ w_frame.T + first.bias   # (B,H)
        geo = torch.cat([points * 10.0, _segments(points) * 100.0, torch.ones_like(points[..., :1])], -1)
        shared = shared.reshape(n_str * n_pts, -1)
        # one keyframe at a time: its (N*P, hidden) activations stay small enough for the cache
        ab = torch.stack([self.mlp[1:](torch.addmm(shared, geo[i].reshape(n_str * n_pts, 7),
                                                   torch.cat([w_geo.T, frame_bias[i:i + 1]], 0)))
                          for i in range(b)])
        return self._offsets_from(ab.reshape(b, n_str, n_pts, 2).clamp(-1.0, 1.0), points, u)

    def offsets_reference(self, points: torch.Tensor, frame: int,
                          strand_index: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`offsets` with the MLP applied to the concatenated input, as written (the slow
        reference of :meth:`offsets_batch`, for tests). points: (N,P,3) -> (N,P,3)."""
        n_str, n_pts, _ = points.shape
        dev = points.device
        if strand_index is None:
            strand_index = torch.arange(n_str, device=dev)
        u, enc = self._encoding(n_pts, dev, points.dtype)
        frame_feat = self.frame_lift(self.frame_codes(torch.tensor([frame], device=dev)))  # (1,F)
        feats = torch.cat([
            points * 10.0,  # decimetres: O(1) inputs
            _segments(points) * 100.0,
            enc[None].expand(n_str, -1, -1),
            self.texel_embed(strand_index)[:, None, :].expand(-1, n_pts, -1),
            frame_feat[:, None, :].expand(n_str, n_pts, -1),
        ], dim=-1)
        ab = self.mlp(feats).clamp(-1.0, 1.0)
        return self._offsets_from(ab, points, u)

    def _encoding(self, n_pts: int, dev, dt) -> tuple[torch.Tensor, torch.Tensor]:
        """(u (P,), positional encoding (P, 1 + 4 n_freqs)) of the root-to-tip coordinate."""
        u = torch.linspace(0.0, 1.0, n_pts, device=dev, dtype=dt)
        freqs = (2.0 ** torch.arange(self.cfg.n_freqs, device=dev, dtype=dt)) * math.pi
        enc = torch.cat([u[:, None], torch.sin(u[:, None] * freqs), torch.cos(u[:, None] * freqs),
                         torch.sin(2 * u[:, None] * freqs), torch.cos(2 * u[:, None] * freqs)], dim=-1)
        return u, enc

    def _offsets_from(self, ab: torch.Tensor, points: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Offsets along the strands' normal and binormal from the clamped MLP output ab (...,N,P,2)."""
        nrm, bin_ = strand_frames(points.reshape(-1, *points.shape[-2:]))
        nrm, bin_ = nrm.reshape(points.shape), bin_.reshape(points.shape)
        w = deformation_weight(u, self.cfg.pinned_fraction)[:, None]
        return w * self.cfg.max_offset * (ab[..., :1] * nrm + ab[..., 1:] * bin_)

    def forward(self, points: torch.Tensor, frame: int, strand_index: torch.Tensor | None = None,
                scale: float = 1.0, detach_input: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """Deformed canonical strands of keyframe ``frame`` and their offsets.

        Args:
            points: (N,P,3) canonical strands (root first).
            frame: keyframe position (index into the frame codes).
            strand_index: (N,) texel-embedding indices (default arange(N)).
            scale: factor on the offsets (the ramp-in of the schedule; 0 gives exactly ``points``).
            detach_input: the MLP sees ``points`` detached (the offsets then reach the strands
                only by being added to them, not through the MLP's inputs).

        Returns:
            (x + scale * dx_t with segment lengths restored (N,P,3), scale * dx_t (N,P,3)).
        """
        frames = torch.tensor([int(frame)], device=points.device)
        moved, off = self.forward_batch(points[None], frames, strand_index, scale, detach_input)
        return moved[0], off[0]

    def forward_batch(self, points: torch.Tensor, frames: torch.Tensor, strand_index: torch.Tensor | None = None,
                      scale: float = 1.0, detach_input: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`forward` for several keyframes at once: points (B,N,P,3) (one copy per keyframe,
        or one expanded), frames (B,) -> (moved (B,N,P,3), scale * dx (B,N,P,3))."""
        if scale == 0.0:
            return points, torch.zeros_like(points)
        off = self.offsets_batch(points.detach() if detach_input else points, frames, strand_index) * scale
        seg_len = (points[..., 1:, :] - points[..., :-1, :]).norm(dim=-1)
        return rechain(points + off, seg_len), off

    def regularizers(self) -> dict[str, torch.Tensor]:
        """Small penalties on the frame codes (method.md: 1e-6 weight applied by the caller)."""
        return {"frame_code": self.frame_codes.weight.pow(2).mean()}
