"""2D hair orientation maps from a Gabor filter bank (batched torch conv2d).

Conventions:
- ``angle`` (H, W) float32 in [0, pi): the undirected 2D hair direction at each pixel, as the
  image-plane vector (cos a, sin a) in pixel axes (x right, y down). a = 0 is horizontal,
  a = pi/2 is vertical (along +y, i.e. downwards on screen).
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
    tile: int = 256
    """image tile edge (px) processed at once; bounds memory to n_orientations * (tile+2r)^2."""


class OrientationMap(NamedTuple):
    """Result of :func:`orientation_map`."""

    angle: np.ndarray  # (H, W) float32 in [0, pi)
    confidence: np.ndarray  # (H, W) float32 in [0, 1]
    energy: np.ndarray  # (H, W) float32, max |response| of the bank


def gabor_bank(cfg: GaborConfig, device: torch.device | str | None = None,
               dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Build the zero-mean cosine Gabor bank.

    Returns:
        kernels: (n, 1, k, k) with k = 2 * ceil(3 * max sigma) + 1; kernel i responds to strands
            with direction angle ``angles[i]`` (stripes along that direction).
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
    k = k / k.abs().sum(dim=(1, 2), keepdim=True)
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


@torch.no_grad()
def orientation_map(image: np.ndarray, mask: np.ndarray | None = None, cfg: GaborConfig = GaborConfig(),
                    device: torch.device | str | None = None) -> OrientationMap:
    """Per-pixel hair orientation and confidence of one image.

    Args:
        image: (H, W, 3) uint8 RGB or (H, W) grayscale (uint8 or float in [0, 1]).
        mask: optional (H, W) hair mask in [0, 1]; confidence is zeroed where mask < 0.5.
        cfg: bank settings.
        device: torch device for the convolutions (default CPU).
    Returns:
        :class:`OrientationMap` with (H, W) float32 arrays (see the module docstring).
    """
    device = torch.device(device) if device is not None else torch.device("cpu")
    gray = torch.from_numpy(_to_gray(image)).to(device)[None, None]
    h, w = gray.shape[-2:]
    pre = dog_filter(gray, cfg.dog_sigmas)
    kernels, angles = gabor_bank(cfg, device=device)
    r = kernels.shape[-1] // 2
    mode = "reflect" if r < min(h, w) else "replicate"
    padded = F.pad(pre, (r, r, r, r), mode=mode)
    var_uniform = math.pi ** 2 / 12.0

    angle = torch.empty(h, w, device=device)
    conf = torch.empty(h, w, device=device)
    energy = torch.empty(h, w, device=device)
    t = max(16, int(cfg.tile))
    for y0 in range(0, h, t):
        for x0 in range(0, w, t):
            y1, x1 = min(h, y0 + t), min(w, x0 + t)
            patch = padded[:, :, y0:y1 + 2 * r, x0:x1 + 2 * r]
            resp = F.conv2d(patch, kernels)[0].abs()  # (n, th, tw)
            best_val, best = resp.max(dim=0)
            a_hat = angles[best]  # (th, tw)
            d = angles[:, None, None] - a_hat[None]
            d = torch.remainder(d + math.pi / 2, math.pi) - math.pi / 2
            wgt = resp - resp.min(dim=0, keepdim=True).values
            var = (d * d * wgt).sum(0) / wgt.sum(0).clamp_min(1e-12)
            angle[y0:y1, x0:x1] = a_hat
            conf[y0:y1, x0:x1] = (1.0 - var / var_uniform).clamp(0.0, 1.0)
            energy[y0:y1, x0:x1] = best_val
    conf_np = conf.cpu().numpy().astype(np.float32)
    if mask is not None:
        m = np.asarray(mask, dtype=np.float32)
        if m.shape != (h, w):
            raise ValueError(f"mask shape {m.shape} does not match image shape {(h, w)}")
        conf_np = np.where(m >= 0.5, conf_np, 0.0).astype(np.float32)
    ang = np.mod(angle.cpu().numpy().astype(np.float32), np.float32(math.pi))
    ang[ang >= np.float32(math.pi)] = 0.0
    return OrientationMap(ang, conf_np, energy.cpu().numpy().astype(np.float32))


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
