"""Slow, obviously-correct reference renderer for strand Gaussians (numpy, float64, tiny scenes).

Written independently of ``vid2haircut.render``: explicit 3x3 covariances built from an
orthonormal frame, an explicit projection Jacobian, and per pixel an explicit depth sort of every
Gaussian followed by front-to-back alpha compositing:

    weight_i = T_i * alpha_i,  T_{i+1} = T_i * (1 - alpha_i),  silhouette = 1 - T_end,
    depth = sum weight_i z_i / sum weight_i,  direction = normalise(sum weight_i (cos 2a, sin 2a)).

Alpha follows the same rules as the fast renderer: alpha = opacity * exp(-m / 2) (m the squared
Mahalanobis distance of the pixel centre), dropped below ``alpha_min``, clamped to ``alpha_max``,
and 0 where the Gaussian centre depth is not in front of the head depth at that pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class ReferenceRender:
    silhouette: np.ndarray  # [B, H, W]
    depth: np.ndarray  # [B, H, W], 0 where empty
    direction: np.ndarray  # [B, H, W, 2] doubled-angle unit vectors, 0 where empty
    max_weight: np.ndarray  # [B, S] largest compositing weight T_i * alpha_i of each segment


def _perpendicular(u: np.ndarray) -> np.ndarray:
    a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    v = np.cross(u, a)
    return v / np.linalg.norm(v)


def reference_gaussians(points, K, world_2_cam, strand_width=3.5e-4, dilation=0.3):
    """[B, N, P, 3] -> lists per frame of (mean [S, 2], cov [S, 2, 2], z [S], dir2 [S, 2])."""
    points = np.asarray(points, np.float64)
    out = []
    for b in range(points.shape[0]):
        R, t, Kb = world_2_cam[b][:3, :3], world_2_cam[b][:3, 3], K[b]
        means, covs, zs, dirs = [], [], [], []
        for strand in points[b]:
            for i in range(len(strand) - 1):
                p0, p1 = strand[i], strand[i + 1]
                m = 0.5 * (p0 + p1)
                d = p1 - p0
                L = 0.5 * np.linalg.norm(d)
                u = d / np.linalg.norm(d)
                v = _perpendicular(u)
                w = np.cross(u, v)
                frame = np.stack([u, v, w], axis=1)
                cov3 = frame @ np.diag([L * L, strand_width**2, strand_width**2]) @ frame.T
                x, y, z = R @ m + t
                J = Kb[:2, :2] @ np.array([[1 / z, 0, -x / z**2], [0, 1 / z, -y / z**2]])
                cov2 = J @ R @ cov3 @ R.T @ J.T + dilation * np.eye(2)
                uv = Kb[:2, :2] @ np.array([x / z, y / z]) + Kb[:2, 2]
                e = J @ R @ d
                a = math.atan2(e[1], e[0])
                means.append(uv)
                covs.append(cov2)
                zs.append(z)
                dirs.append([math.cos(2 * a), math.sin(2 * a)])
        out.append((np.array(means), np.array(covs), np.array(zs), np.array(dirs)))
    return out


def reference_render(points, K, world_2_cam, width, height, strand_width=3.5e-4, head_depth=None,
                     opacity=1.0, dilation=0.3, alpha_min=math.exp(-4.5), alpha_max=0.99,
                     t_min=0.0) -> ReferenceRender:
    """Exact front-to-back compositing of every Gaussian at every pixel centre; ``t_min`` > 0: a
    pixel stops once its transmittance is below it (the exact renderer's early termination)."""
    K = np.asarray(K, np.float64)
    world_2_cam = np.asarray(world_2_cam, np.float64)
    gauss = reference_gaussians(points, K, world_2_cam, strand_width, dilation)
    B = len(gauss)
    S = len(gauss[0][2])
    sil = np.zeros((B, height, width))
    depth = np.zeros((B, height, width))
    direction = np.zeros((B, height, width, 2))
    max_w = np.zeros((B, S))
    for b, (means, covs, zs, dirs) in enumerate(gauss):
        inv = np.linalg.inv(covs)
        order = np.argsort(zs, kind="stable")
        for row in range(height):
            for col in range(width):
                delta = np.array([col, row], np.float64)[None] - means
                m = np.einsum("si,sij,sj->s", delta, inv, delta)
                alpha = opacity * np.exp(-0.5 * m)
                alpha = np.where(alpha >= alpha_min, np.minimum(alpha, alpha_max), 0.0)
                if head_depth is not None:
                    alpha = np.where(zs < head_depth[b, row, col], alpha, 0.0)
                trans, wsum, zsum, dsum = 1.0, 0.0, 0.0, np.zeros(2)
                for i in order:
                    if trans < t_min:
                        break
                    wi = trans * alpha[i]
                    wsum += wi
                    zsum += wi * zs[i]
                    dsum += wi * dirs[i]
                    max_w[b, i] = max(max_w[b, i], wi)
                    trans *= 1.0 - alpha[i]
                sil[b, row, col] = 1.0 - trans
                if wsum > 0:
                    depth[b, row, col] = zsum / wsum
                    n = np.linalg.norm(dsum)
                    if n > 1e-12:
                        direction[b, row, col] = dsum / n
    return ReferenceRender(sil, depth, direction, max_w)
