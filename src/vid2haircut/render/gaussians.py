"""Strand segments -> screen-space 2D Gaussians (EWA projection of strand-aligned 3D Gaussians).

Each segment (p_i, p_{i+1}) becomes one 3D Gaussian centred at the midpoint m, with its long axis
along d = p_{i+1} - p_i (standard deviation L = |d| / 2, half the segment length) and the two other
axes equal to the strand width w (method.md, "Renderer"):

    Sigma_3D = w^2 I + (L^2 - w^2) u u^T,  u = d / |d|.

It is projected with the Jacobian J of the pinhole projection at m (EWA splatting):

    Sigma_2D = J R Sigma_3D R^T J^T + dilation * I
             = w^2 J J^T + (1/4 - w^2/|d|^2) (J R d)(J R d)^T + dilation * I,

R the camera rotation. ``dilation`` (default 0.3 px^2, as in 3D Gaussian splatting) is a
screen-space low-pass filter: it keeps sub-pixel strands (0.35 mm at typical distances is about
0.2 px) from aliasing, at the price of drawing them roughly one pixel wide. The 2D direction of
the segment is the direction of J R d, encoded as the doubled-angle vector (cos 2a, sin 2a),
which is the same for d and -d (undirected).
"""

from __future__ import annotations

import torch
from torch import Tensor

from vid2haircut.render.project import check_cameras, project_camera_points, rotate_to_camera, to_camera
from vid2haircut.render.types import Gaussians2D

DEFAULT_STRAND_WIDTH = 3.5e-4
"""Strand width (metres) used for the two short Gaussian axes (Im2Haircut: 0.35 mm)."""

DEFAULT_DILATION = 0.3
"""Screen-space dilation added to the 2D covariance diagonal (px^2)."""


def check_points(points: Tensor) -> None:
    """Raise ValueError unless ``points`` is a floating [B, N, P, 3] tensor with P >= 2."""
    if points.ndim != 4 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape (B, N, P, 3), got {tuple(points.shape)}")
    if points.shape[2] < 2:
        raise ValueError(f"strands need at least 2 points each, got P = {points.shape[2]}")
    if points.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"points must be a float32 or float64 tensor, got {points.dtype} (float16 / bfloat16 "
                         "covariances overflow: convert with points.float())")


def segment_gaussians(
    points: Tensor,  # [B, N, P, 3] world
    K: Tensor,  # [B, 3, 3]
    world_2_cam: Tensor,  # [B, 4, 4]
    strand_width: float = DEFAULT_STRAND_WIDTH,
    dilation: float = DEFAULT_DILATION,
    near: float = 1e-2,
) -> Gaussians2D:
    """Project every strand segment to a 2D Gaussian.

    Args:
        points: [B, N, P, 3] strand points in world space (metres), one set per frame.
        K: [B, 3, 3] intrinsics. world_2_cam: [B, 4, 4] extrinsics (OpenCV).
        strand_width: length of the two short 3D axes (metres).
        dilation: screen-space covariance dilation (px^2).
        near: segments whose midpoint is closer than ``near`` metres (or behind) are invalid.

    Returns:
        :class:`Gaussians2D` with S = N * (P - 1) Gaussians per frame, ordered strand-major
        (segment j of strand n is index n * (P - 1) + j).

    Example:
        >>> pts = torch.tensor([[[[-0.01, 0.0, 0.5], [0.01, 0.0, 0.5]]]])
        >>> K = torch.tensor([[[500.0, 0, 32], [0, 500.0, 32], [0, 0, 1]]])
        >>> g = segment_gaussians(pts, K, torch.eye(4)[None])
        >>> g.means.shape, g.dirs[0, 0].tolist()
        (torch.Size([1, 1, 2]), [1.0, 0.0])
    """
    check_points(points)
    B, N, P, _ = points.shape
    check_cameras(K, world_2_cam, B)
    K = K.to(points.dtype)
    world_2_cam = world_2_cam.to(points.dtype)
    S = N * (P - 1)
    mid = (0.5 * (points[:, :, 1:] + points[:, :, :-1])).reshape(B, S, 3)
    seg = (points[:, :, 1:] - points[:, :, :-1]).reshape(B, S, 3)

    mid_cam = to_camera(mid, world_2_cam)
    seg_cam = rotate_to_camera(seg, world_2_cam)
    means, depths = project_camera_points(mid_cam, K, near)
    # EWA: J = Kxy @ J0, J0 = [[1/z, 0, -x/z^2], [0, 1/z, -y/z^2]] at the midpoint (explicit 2x2
    # algebra; batched small matmuls are slow on CPU)
    iz = 1.0 / mid_cam[..., 2].clamp_min(near)
    X, Y = mid_cam[..., 0] * iz, mid_cam[..., 1] * iz
    a0 = iz * (seg_cam[..., 0] - X * seg_cam[..., 2])
    a1 = iz * (seg_cam[..., 1] - Y * seg_cam[..., 2])
    k00, k01 = K[:, None, 0, 0], K[:, None, 0, 1]
    k10, k11 = K[:, None, 1, 0], K[:, None, 1, 1]
    jd = torch.stack([k00 * a0 + k01 * a1, k10 * a0 + k11 * a1], dim=-1)  # [B, S, 2] projected segment (px)
    iz2 = iz * iz
    m00, m01, m11 = iz2 * (1.0 + X * X), iz2 * X * Y, iz2 * (1.0 + Y * Y)  # J0 J0^T
    r00, r01 = k00 * m00 + k01 * m01, k00 * m01 + k01 * m11  # rows of Kxy @ (J0 J0^T)
    r10, r11 = k10 * m00 + k11 * m01, k10 * m01 + k11 * m11
    jj00, jj01, jj11 = r00 * k00 + r01 * k01, r00 * k10 + r01 * k11, r10 * k10 + r11 * k11

    w2 = strand_width * strand_width
    len2 = (seg * seg).sum(-1)
    coef = 0.25 - w2 / (len2 + 1e-20)
    sxx = w2 * jj00 + coef * jd[..., 0] ** 2 + dilation
    sxy = w2 * jj01 + coef * jd[..., 0] * jd[..., 1]
    syy = w2 * jj11 + coef * jd[..., 1] ** 2 + dilation
    covs = torch.stack([sxx, sxy, syy], dim=-1)

    n2 = (jd * jd).sum(-1) + 1e-12
    dirs = torch.stack([(jd[..., 0] ** 2 - jd[..., 1] ** 2) / n2, 2.0 * jd[..., 0] * jd[..., 1] / n2], dim=-1)
    valid = (depths > near) & torch.isfinite(means).all(-1) & torch.isfinite(covs).all(-1)
    return Gaussians2D(means, covs, depths, dirs, valid)


def conics(covs: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Inverse of 2x2 covariances [..., 3] (xx, xy, yy) -> (q_xx, q_xy, q_yy), each [...]."""
    sxx, sxy, syy = covs.unbind(-1)
    det = (sxx * syy - sxy * sxy).clamp_min(1e-12)
    return syy / det, -sxy / det, sxx / det
