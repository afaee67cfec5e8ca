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
        """Canonical-space offsets dx_t. points: (N,P,3) canonical strands -> (N,P,3).

        ``strand_index`` (N,) selects the texel embeddings (default arange(N)).
        """
        n_str, n_pts, _ = points.shape
        c = self.cfg
        dev = points.device
        if strand_index is None:
            strand_index = torch.arange(n_str, device=dev)
        u = torch.linspace(0.0, 1.0, n_pts, device=dev, dtype=points.dtype)
        freqs = (2.0 ** torch.arange(c.n_freqs, device=dev, dtype=points.dtype)) * math.pi
        enc = torch.cat([u[:, None], torch.sin(u[:, None] * freqs), torch.cos(u[:, None] * freqs),
                         torch.sin(2 * u[:, None] * freqs), torch.cos(2 * u[:, None] * freqs)], dim=-1)
        seg = torch.zeros_like(points)
        seg[:, :-1] = points[:, 1:] - points[:, :-1]
        seg[:, -1] = seg[:, -2]
        frame_feat = self.frame_lift(self.frame_codes(torch.tensor([frame], device=dev)))  # (1,F)
        feats = torch.cat([
            points * 10.0,  # decimetres: O(1) inputs
            seg * 100.0,
            enc[None].expand(n_str, -1, -1),
            self.texel_embed(strand_index)[:, None, :].expand(-1, n_pts, -1),
            frame_feat[:, None, :].expand(n_str, n_pts, -1),
        ], dim=-1)
        ab = self.mlp(feats).clamp(-1.0, 1.0)
        nrm, bin_ = strand_frames(points)
        w = deformation_weight(u, c.pinned_fraction)[None, :, None]
        return w * c.max_offset * (ab[..., :1] * nrm + ab[..., 1:] * bin_)

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
        if scale == 0.0:
            return points, torch.zeros_like(points)
        off = self.offsets(points.detach() if detach_input else points, frame, strand_index) * scale
        seg_len = (points[:, 1:] - points[:, :-1]).norm(dim=-1)
        return rechain(points + off, seg_len), off

    def regularizers(self) -> dict[str, torch.Tensor]:
        """Small penalties on the frame codes (method.md: 1e-6 weight applied by the caller)."""
        return {"frame_code": self.frame_codes.weight.pow(2).mean()}
