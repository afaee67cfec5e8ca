"""2D hair orientation maps from a Gabor filter bank (batched torch conv2d).

Conventions:
- ``angle`` (H, W) float32 in [0, pi): the undirected 2D hair direction at each pixel, as the
  image-plane vector (cos a, sin a) in pixel axes (x right, y down). a = 0 is horizontal,
  a = pi/2 is vertical (along +y, i.e. downwards on screen).
- filter energy F_i: the magnitude of the quadrature pair (cosine + sine Gabor) response, which
  does not depend on where in a stripe the pixel lies (``quadrature=False``: |cosine response|).
- ``confidence`` (H, W) float32 in [0, 1]: 1 - V / V_uniform, where
  V = sum_i d(a_hat, a_i)^2 F_i / sum_i F_i is the response-weighted angular variance of the bank
  around the winning angle (d wrapped to [-pi/2, pi/2)), F_i the filter energy above the
  bank's minimum, and V_uniform = pi^2 / 12 the variance of a flat response. 1 = one sharp
  orientation, 0 = no preferred orientation. Pixels outside the hair mask get confidence 0.

Defaults follow Neural Haircut / GaussianHaircut (``shared/docs/method.md``): 180 orientations,
sigma 1.8 across the strand (along the carrier), 2.4 along the strand, frequency 0.23 cycles/px,
difference-of-Gaussians pre-filter with sigmas (0.4, 10).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F


@dataclass(frozen=True)
class GaborConfig:
    """Gabor bank settings."""

    n_orientations: int = 180
    """number of filter angles evenly covering [0, pi)."""
    sigma_across: float = 1.8
    """Gaussian sigma (px) across the strand, i.e. along the cosine carrier."""
    sigma_along: float = 2.4
    """Gaussian sigma (px) along the strand."""
    frequency: float = 0.23
    """carrier frequency, cycles per pixel."""
    dog_sigmas: tuple[float, float] = (0.4, 10.0)
    """difference-of-Gaussians pre-filter (fine, coarse); None-like (0, 0) disables it."""
    quadrature: bool = True
    """filter energy = |cos + i sin response| (phase invariant); False: |cos response| only, as in
    Neural Haircut (biased towards stripe phases)."""
    tile: int = 256
    """image tile edge (px) processed at once; bounds memory to n_orientations * (tile+2r)^2."""


class OrientationMap(NamedTuple):
    """Result of :func:`orientation_map`."""

    angle: np.ndarray  # (H, W) float32 in [0, pi)
    confidence: np.ndarray  # (H, W) float32 in [0, 1]
    energy: np.ndarray  # (H, W) float32, max |response| of the bank


def gabor_bank(cfg: GaborConfig, device: torch.device | str | None = None,
               dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Build the zero-mean cosine Gabor bank (plus the sine partners when ``cfg.quadrature``).

    Returns:
        kernels: (n, 1, k, k) — or (2n, 1, k, k), cosine kernels first, with quadrature — with
            k = 2 * ceil(3 * max sigma) + 1; kernel i responds to strands with direction angle
            ``angles[i]`` (stripes along that direction).
        angles: (n,) filter angles in [0, pi).
    """
    r = int(math.ceil(3.0 * max(cfg.sigma_across, cfg.sigma_along)))
    ys, xs = torch.meshgrid(torch.arange(-r, r + 1, dtype=torch.float64),
                            torch.arange(-r, r + 1, dtype=torch.float64), indexing="ij")
    angles = torch.arange(cfg.n_orientations, dtype=torch.float64) * (math.pi / cfg.n_orientations)
    c, s = torch.cos(angles)[:, None, None], torch.sin(angles)[:, None, None]
    along = xs * c + ys * s  # coordinate along the strand direction
    across = -xs * s + ys * c  # coordinate across it
    env = torch.exp(-0.5 * (along / cfg.sigma_along) ** 2 - 0.5 * (across / cfg.sigma_across) ** 2)
    carrier = torch.cos(2.0 * math.pi * cfg.frequency * across)
    dc = (env * carrier).sum(dim=(1, 2), keepdim=True) / env.sum(dim=(1, 2), keepdim=True)
    k = env * (carrier - dc)  # exactly zero-mean: no response to flat regions
    norm = k.abs().sum(dim=(1, 2), keepdim=True).mean()  # one constant: per-angle norms would bias angles
    k = k / norm
    if cfg.quadrature:  # odd (sine) partners, same envelope and scale
        k = torch.cat([k, env * torch.sin(2.0 * math.pi * cfg.frequency * across) / norm])
    return k[:, None].to(device=device, dtype=dtype), angles.to(device=device, dtype=dtype)


def _gauss1d(sigma: float, device, dtype) -> torch.Tensor:
    r = max(1, int(math.ceil(3.0 * sigma)))
    x = torch.arange(-r, r + 1, device=device, dtype=dtype)
    g = torch.exp(-0.5 * (x / sigma) ** 2)
    return g / g.sum()


def _blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of (1, 1, H, W) with reflect padding (clamped for tiny images)."""
    g = _gauss1d(sigma, img.device, img.dtype)
    r = g.numel() // 2
    h, w = img.shape[-2:]
    if r >= min(h, w):  # reflect padding needs r < size: replicate instead
        x = F.pad(img, (r, r, r, r), mode="replicate")
    else:
        x = F.pad(img, (r, r, r, r), mode="reflect")
    x = F.conv2d(x, g.view(1, 1, 1, -1))
    return F.conv2d(x, g.view(1, 1, -1, 1))


def dog_filter(gray: torch.Tensor, sigmas: tuple[float, float]) -> torch.Tensor:
    """Difference of Gaussians G(s0)*I - G(s1)*I of a (1, 1, H, W) image; identity if s0 = s1 = 0."""
    s0, s1 = sigmas
    if s0 <= 0 and s1 <= 0:
        return gray
    fine = _blur(gray, s0) if s0 > 0 else gray
    return fine - _blur(gray, s1)


def _to_gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    img = img.astype(np.float32)
    if np.asarray(image).dtype == np.uint8:
        img = img / 255.0
    return img


@functools.lru_cache(maxsize=8)
def _cached_bank(cfg: GaborConfig, device: str) -> tuple[torch.Tensor, torch.Tensor, float]:
    kernels, angles = gabor_bank(cfg, device=device)
    d0 = torch.remainder(angles - angles[0] + math.pi / 2, math.pi) - math.pi / 2
    return kernels, angles, float((d0 * d0).sum())  # sum_i d_i^2 is the same for every winner


def _bbox(mask: np.ndarray, pad: int) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    return max(0, ys.min() - pad), min(h, ys.max() + pad + 1), max(0, xs.min() - pad), min(w, xs.max() + pad + 1)


@torch.no_grad()
def orientation_map(image: np.ndarray, mask: np.ndarray | None = None, cfg: GaborConfig = GaborConfig(),
                    device: torch.device | str | None = None) -> OrientationMap:
    """Per-pixel hair orientation and confidence of one image.

    Args:
        image: (H, W, 3) uint8 RGB or (H, W) grayscale (uint8 or float in [0, 1]).
        mask: optional (H, W) hair mask in [0, 1]; only its bounding box is filtered, and
            confidence is zeroed where mask < 0.5 (angle there is 0).
        cfg: bank settings.
        device: torch device for the convolutions (default CPU).
    Returns:
        :class:`OrientationMap` with (H, W) float32 arrays (see the module docstring).
    """
    device = torch.device(device) if device is not None else torch.device("cpu")
    gray_np = _to_gray(image)
    h, w = gray_np.shape
    angle_np = np.zeros((h, w), np.float32)
    conf_np = np.zeros((h, w), np.float32)
    energy_np = np.zeros((h, w), np.float32)
    m = None
    if mask is not None:
        m = np.asarray(mask, dtype=np.float32) >= 0.5
        if m.shape != (h, w):
            raise ValueError(f"mask shape {m.shape} does not match image shape {(h, w)}")
        if not m.any():
            return OrientationMap(angle_np, conf_np, energy_np)
    kernels, angles, sum_d2 = _cached_bank(cfg, str(device))
    r = kernels.shape[-1] // 2
    n = angles.numel()
    # the DoG needs context: filter a box around the mask padded by the coarse sigma
    y0, y1, x0, x1 = (0, h, 0, w) if m is None else _bbox(m, r + int(math.ceil(3 * max(cfg.dog_sigmas))))
    gray = torch.from_numpy(np.ascontiguousarray(gray_np[y0:y1, x0:x1])).to(device)[None, None]
    pre = dog_filter(gray, cfg.dog_sigmas)
    # then only the mask's own box (plus the kernel radius) goes through the bank
    by0, by1, bx0, bx1 = (0, h, 0, w) if m is None else _bbox(m, 0)
    bh, bw = by1 - by0, bx1 - bx0
    oy, ox = by0 - y0, bx0 - x0
    ch, cw = pre.shape[-2:]
    mode = "reflect" if r < min(ch, cw) else "replicate"
    padded = F.pad(pre, (r, r, r, r), mode=mode)
    var_uniform = math.pi ** 2 / 12.0
    t = max(16, int(cfg.tile))
    for ty in range(0, bh, t):
        for tx in range(0, bw, t):
            ty1, tx1 = min(bh, ty + t), min(bw, tx + t)
            patch = padded[:, :, oy + ty:oy + ty1 + 2 * r, ox + tx:ox + tx1 + 2 * r]
            resp = F.conv2d(patch, kernels)[0]  # (n or 2n, th, tw)
            resp = torch.hypot(resp[:n], resp[n:]) if cfg.quadrature else resp.abs_()
            best_val, best = resp.max(dim=0)
            low = resp.min(dim=0).values
            total = resp.sum(dim=0)
            d = angles[:, None, None] - angles[best][None]
            d.add_(math.pi / 2).remainder_(math.pi).sub_(math.pi / 2).square_()
            num = d.mul_(resp).sum(dim=0)
            # variance with weights F_i = resp_i - min_j resp_j
            var = (num - low * sum_d2) / (total - n * low).clamp_min(1e-12)
            sl = (slice(by0 + ty, by0 + ty1), slice(bx0 + tx, bx0 + tx1))
            angle_np[sl] = angles[best].cpu().numpy()
            conf_np[sl] = (1.0 - var / var_uniform).clamp(0.0, 1.0).cpu().numpy()
            energy_np[sl] = best_val.cpu().numpy()
    if m is not None:
        conf_np[~m] = 0.0
        angle_np[~m] = 0.0
    angle_np = np.mod(angle_np, np.float32(math.pi)).astype(np.float32)
    angle_np[angle_np >= np.float32(math.pi)] = 0.0
    return OrientationMap(angle_np, conf_np, energy_np)


def angle_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Undirected angular difference in [0, pi/2] between angle arrays (radians, any shape)."""
    d = np.abs(np.mod(np.asarray(a) - np.asarray(b), np.pi))
    return np.minimum(d, np.pi - d)


def orientation_colour(angle: np.ndarray, confidence: np.ndarray | None = None) -> np.ndarray:
    """(H, W) angles in [0, pi) (+ optional confidence in [0, 1]) -> (H, W, 3) uint8 RGB.

    Hue encodes the angle over its full period (0 and pi share a colour); value is the
    confidence normalised by its 99th percentile (black = no confidence).
    """
    import cv2

    hue = (np.mod(angle, np.pi) / np.pi * 180.0).astype(np.float32)
    sat = np.ones_like(hue)
    if confidence is None:
        val = np.ones_like(hue)
    else:
        c = np.asarray(confidence, dtype=np.float32)
        hi = float(np.percentile(c[c > 0], 99)) if np.any(c > 0) else 1.0
        val = np.clip(c / max(hi, 1e-6), 0.0, 1.0)
    hsv = np.stack([hue, sat, val], axis=-1)
    rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)
