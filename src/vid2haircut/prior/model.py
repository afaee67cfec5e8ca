"""The image-conditioned hair prior: one view's targets -> hair map coefficients + baldness mask.

Architecture (Im2Haircut's prior sized for CPU training):

1. CNN encoder: ``len(enc_channels)`` stride-2 stages (conv3x3 s2 + conv3x3, GroupNorm, GELU) take
   the ``(B, 6, S, S)`` input (:func:`vid2haircut.prior.views.prior_input`) to a ``(B, d, S/2^n, S/2^n)``
   feature grid of image tokens.
2. Transformer: the image tokens (plus learned position embeddings) and ``q x q`` learned *scalp
   queries* (one per coarse texel of the hair map, ``q = map_res / 2^len(dec_channels)``) go through
   ``n_blocks`` pre-norm self-attention blocks; the attention moves information from the image
   layout to the scalp-UV layout.
3. Convolutional decoder: the scalp queries, reshaped to ``(B, d, q, q)``, are upsampled (bilinear
   x2 + conv3x3) to ``(B, c, R, R)``; a 1x1 head gives K coefficients and one baldness logit per
   texel, added to learned per-texel bias maps (initialised by the trainer to the training set's
   mean map, so an untrained net predicts the average hairstyle).

Example::

    net = PriorNet(PriorConfig())                 # default: S=128, R=32, K=64
    z, mask_logits = net(torch.zeros(2, 6, 128, 128))   # (2,64,32,32), (2,32,32)
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import torch
from torch import nn

from vid2haircut.prior.views import INPUT_CHANNELS, prior_input

__all__ = ["PriorConfig", "PriorNet", "load_prior", "predict_hairmap", "prior_input", "PRIOR_FILES"]

PRIOR_FILES = ("codec.npz", "prior.pt", "prior.json")
"""Files of a prior artifact folder."""


@dataclass(frozen=True)
class PriorConfig:
    """Sizes of :class:`PriorNet`."""

    input_size: int = 128
    """Side S of the input crop (a multiple of ``2 ** len(enc_channels)``)."""
    in_channels: int = len(INPUT_CHANNELS)
    """Input channels (:data:`vid2haircut.prior.views.INPUT_CHANNELS`)."""
    map_res: int = 32
    """Hair map resolution R (a multiple of ``2 ** len(dec_channels)``)."""
    k: int = 64
    """Coefficients per texel K (= the codec's K)."""
    stem_stride: int = 4
    """Stride (= kernel size) of the patchifying stem convolution."""
    enc_channels: tuple[int, ...] = (24, 48, 96)
    """Channels of the stem, then of each stride-2 encoder stage (tokens at S / (stem * 2^(n-1)))."""
    d_model: int = 96
    """Transformer width."""
    n_heads: int = 4
    """Attention heads."""
    n_blocks: int = 2
    """Transformer blocks."""
    mlp_ratio: int = 2
    """Hidden width of the transformer MLP, in units of ``d_model``."""
    dec_channels: tuple[int, ...] = (64, 32)
    """Channels of the x2 decoder stages (from the q x q query grid to R x R)."""

    @property
    def token_res(self) -> int:
        """Side of the image token grid."""
        return self.input_size // (self.stem_stride * 2 ** (len(self.enc_channels) - 1))

    def __post_init__(self) -> None:
        n_enc, n_dec = len(self.enc_channels), len(self.dec_channels)
        down = self.stem_stride * 2 ** max(n_enc - 1, 0)
        if n_enc < 1 or self.stem_stride < 1 or self.input_size % down:
            raise ValueError(f"PriorConfig: input_size {self.input_size} must be a multiple of {down} "
                             f"(stem stride x 2^(stages-1))")
        if self.map_res % (2 ** n_dec) or self.map_res // (2 ** n_dec) < 1:
            raise ValueError(f"PriorConfig: map_res {self.map_res} must be a multiple of 2^{n_dec}")
        if self.d_model % self.n_heads:
            raise ValueError(f"PriorConfig: d_model {self.d_model} not divisible by n_heads {self.n_heads}")

    @staticmethod
    def tiny() -> "PriorConfig":
        """A very small net for tests (S=64, R=16, K=16)."""
        return PriorConfig(input_size=64, map_res=16, k=16, stem_stride=4, enc_channels=(8, 16), d_model=32,
                           n_heads=2, n_blocks=2, dec_channels=(16,))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (tuples as lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "PriorConfig":
        """Inverse of :meth:`to_dict` (unknown keys raise ValueError)."""
        names = {f.name for f in fields(PriorConfig)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"PriorConfig: unknown keys {sorted(unknown)}")
        return PriorConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def _groups(c: int) -> int:
    """GroupNorm groups: 8 channels per group where possible."""
    for g in (c // 8, 4, 2, 1):
        if g >= 1 and c % g == 0:
            return g
    return 1


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.GroupNorm(_groups(cout), cout), nn.GELU())


class _Block(nn.Module):
    """Pre-norm transformer block: x + MHA(LN(x)); x + MLP(LN(x)). x: (B,T,d)."""

    def __init__(self, d: int, heads: int, ratio: int) -> None:
        super().__init__()
        self.norm1, self.norm2 = nn.LayerNorm(d), nn.LayerNorm(d)
        self.attn = nn.MultiheadAttention(d, heads, batch_first=True)
        self.mlp = nn.Sequential(nn.Linear(d, ratio * d), nn.GELU(), nn.Linear(ratio * d, d))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.norm1(x)
        x = x + self.attn(h, h, h, need_weights=False)[0]
        return x + self.mlp(self.norm2(x))


class PriorNet(nn.Module):
    """Image -> hair map network (see the module docstring).

    Args:
        cfg: sizes.
    """

    def __init__(self, cfg: PriorConfig = PriorConfig()) -> None:
        super().__init__()
        self.cfg = cfg
        c0 = cfg.enc_channels[0]
        stages = [nn.Sequential(nn.Conv2d(cfg.in_channels, c0, cfg.stem_stride, cfg.stem_stride, bias=False),
                                nn.GroupNorm(_groups(c0), c0), nn.GELU())]
        cin = c0
        for c in cfg.enc_channels[1:]:
            stages.append(nn.Sequential(_conv(cin, c, 2), _conv(c, c)))
            cin = c
        self.encoder = nn.Sequential(*stages)
        self.proj = nn.Conv2d(cin, cfg.d_model, 1)
        g = cfg.token_res
        q = cfg.map_res // (2 ** len(cfg.dec_channels))
        self.grid, self.query_res = g, q
        self.pos = nn.Parameter(0.02 * torch.randn(g * g, cfg.d_model))
        self.queries = nn.Parameter(0.02 * torch.randn(q * q, cfg.d_model))
        self.blocks = nn.ModuleList(_Block(cfg.d_model, cfg.n_heads, cfg.mlp_ratio) for _ in range(cfg.n_blocks))
        self.norm = nn.LayerNorm(cfg.d_model)
        dec, cin = [], cfg.d_model
        for c in cfg.dec_channels:
            dec.append(nn.Sequential(nn.ConvTranspose2d(cin, c, 2, 2, bias=False), nn.GroupNorm(_groups(c), c),
                                     nn.GELU(), _conv(c, c)))
            cin = c
        self.decoder = nn.Sequential(*dec)
        self.head = nn.Conv2d(cin, cfg.k + 1, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        self.z_bias = nn.Parameter(torch.zeros(cfg.k, cfg.map_res, cfg.map_res))
        self.mask_bias = nn.Parameter(torch.zeros(cfg.map_res, cfg.map_res))
        # training-set statistics (baselines, initialisation): mean target map and mean mask
        self.register_buffer("train_mean_z", torch.zeros(cfg.k, cfg.map_res, cfg.map_res))
        self.register_buffer("train_mean_mask", torch.zeros(cfg.map_res, cfg.map_res))

    def set_training_means(self, mean_z: torch.Tensor, mean_mask: torch.Tensor) -> None:
        """Store the training set's mean map (K,R,R) and mean mask (R,R) and start the bias maps there."""
        with torch.no_grad():
            self.train_mean_z.copy_(mean_z)
            self.train_mean_mask.copy_(mean_mask)
            self.z_bias.copy_(mean_z)
            m = mean_mask.clamp(0.02, 0.98)
            self.mask_bias.copy_(torch.log(m / (1 - m)))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Predict a hair map.

        Args:
            x: (B, C, S, S) input crops (:func:`prior_input`, concatenated over the batch).

        Returns:
            z: (B, K, R, R) coefficient maps (whitened PCA space of the codec);
            mask_logits: (B, R, R) baldness logits (sigmoid > 0.5 = hair).
        """
        cfg = self.cfg
        if x.ndim != 4 or x.shape[1:] != (cfg.in_channels, cfg.input_size, cfg.input_size):
            raise ValueError(f"PriorNet: expected input (B,{cfg.in_channels},{cfg.input_size},"
                             f"{cfg.input_size}), got {tuple(x.shape)}")
        b = x.shape[0]
        f = self.proj(self.encoder(x)).flatten(2).transpose(1, 2) + self.pos       # (B,g*g,d)
        tokens = torch.cat([f, self.queries.expand(b, -1, -1)], dim=1)
        for blk in self.blocks:
            tokens = blk(tokens)
        q = self.norm(tokens[:, f.shape[1]:])                                      # (B,q*q,d)
        grid = q.transpose(1, 2).reshape(b, cfg.d_model, self.query_res, self.query_res)
        out = self.head(self.decoder(grid))                                        # (B,K+1,R,R)
        return out[:, :cfg.k] + self.z_bias, out[:, cfg.k] + self.mask_bias

    def n_parameters(self) -> int:
        """Number of trainable parameters."""
        return sum(p.numel() for p in self.parameters())


def load_prior(prior_dir: str | Path, device: torch.device | str | None = "cpu"):
    """Load a trained prior artifact.

    Args:
        prior_dir: folder holding ``codec.npz``, ``prior.pt`` and ``prior.json``
            (written by :func:`vid2haircut.prior.train.train_prior`).
        device: device of the network and the codec.

    Returns:
        ``(net, codec, record)``: :class:`PriorNet` in eval mode, the
        :class:`~vid2haircut.prior.codec.StrandCodec`, and the training record (dict).
    """
    from vid2haircut.prior.codec import StrandCodec

    prior_dir = Path(prior_dir)
    missing = [name for name in PRIOR_FILES if not (prior_dir / name).is_file()]
    if missing:
        raise FileNotFoundError(f"{prior_dir}: prior artifact misses {missing} (train it with "
                                "`vid2haircut train_prior --out-dir ...`)")
    try:
        record = json.loads((prior_dir / "prior.json").read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{prior_dir / 'prior.json'}: unreadable training record ({exc})") from exc
    try:
        blob = torch.load(prior_dir / "prior.pt", map_location="cpu", weights_only=True)
        cfg = PriorConfig.from_dict(json.loads(blob["config"]))
        net = PriorNet(cfg)
        net.load_state_dict(blob["state_dict"])
    except Exception as exc:  # noqa: BLE001 - any decoding failure is reported with the file name
        raise ValueError(f"{prior_dir / 'prior.pt'}: not a PriorNet checkpoint ({exc})") from exc
    codec = StrandCodec.load(prior_dir / "codec.npz")
    if codec.k != cfg.k:
        raise ValueError(f"{prior_dir}: codec has K={codec.k} but the network predicts K={cfg.k}")
    if record.get("codec_fingerprint") not in (None, codec.fingerprint()):
        raise ValueError(f"{prior_dir}: codec.npz does not match the codec recorded in prior.json")
    return net.to(device).eval(), codec.to(device), record


def predict_hairmap(net: PriorNet, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Inference helper: ``(z (K,R,R), mask (R,R) probabilities)`` of one input ``(1,C,S,S)``."""
    with torch.no_grad():
        z, logits = net(x.to(next(net.parameters()).device))
    return z[0], torch.sigmoid(logits[0])

