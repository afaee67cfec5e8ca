"""Pinhole projection in torch (OpenCV convention: x right, y down, z forward; metres).

Pixel centres sit at integer coordinates (pixel (0, 0) covers [-0.5, 0.5]^2); image row = y,
column = x. Everything is batched over frames: frame ``b`` has its own intrinsics ``K[b]`` and
extrinsics ``world_2_cam[b]``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor


def check_cameras(K: Tensor, world_2_cam: Tensor, batch: int) -> None:
    """Raise ValueError unless ``K`` is (B, 3, 3) and ``world_2_cam`` is (B, 4, 4) with B = ``batch``,
    and, for CPU tensors, both are finite with positive focal lengths."""
    if K.shape != (batch, 3, 3):
        raise ValueError(f"K must have shape ({batch}, 3, 3), got {tuple(K.shape)}")
    if world_2_cam.shape != (batch, 4, 4):
        raise ValueError(f"world_2_cam must have shape ({batch}, 4, 4), got {tuple(world_2_cam.shape)}")
    if batch and K.device.type == "cpu" and not _cameras_ok(K, world_2_cam):
        raise ValueError("K and world_2_cam must be finite, with positive focal lengths K[:, 0, 0] and K[:, 1, 1]")


def _cameras_ok(K: Tensor, world_2_cam: Tensor) -> bool:
    """Finite entries and positive focal lengths of CPU cameras, in numpy (a few microseconds instead
    of torch's ~50 for these few numbers; not on a GPU, where it would be a device sync per render)."""
    k, e = (t.detach().numpy() if t.dtype in NUMPY_FLOATS else t.detach().double().numpy() for t in (K, world_2_cam))
    return bool(np.isfinite(k).all() and np.isfinite(e).all() and (k[:, 0, 0] > 0).all() and (k[:, 1, 1] > 0).all())


NUMPY_FLOATS = (torch.float32, torch.float64)


def _flat(points: Tensor) -> Tensor:
    """[B, ..., 3] -> [B, n, 3] (``reshape(B, -1, 3)`` cannot size an empty batch)."""
    return points.reshape(points.shape[0], math.prod(points.shape[1:-1]), 3)


def to_camera(points: Tensor, world_2_cam: Tensor) -> Tensor:
    """World points -> camera-frame points.

    Args:
        points: [B, ..., 3] world coordinates.
        world_2_cam: [B, 4, 4] extrinsics.

    Returns:
        [B, ..., 3] camera coordinates (z = depth along the optical axis).
    """
    flat = _flat(points)
    rot = world_2_cam[:, :3, :3]
    trans = world_2_cam[:, :3, 3]
    cam = torch.einsum("bij,bnj->bni", rot, flat) + trans[:, None, :]
    return cam.reshape(points.shape)


def rotate_to_camera(vectors: Tensor, world_2_cam: Tensor) -> Tensor:
    """World direction vectors [B, ..., 3] -> camera-frame vectors [B, ..., 3] (rotation only)."""
    flat = _flat(vectors)
    cam = torch.einsum("bij,bnj->bni", world_2_cam[:, :3, :3], flat)
    return cam.reshape(vectors.shape)


def project_camera_points(cam: Tensor, K: Tensor, near: float = 1e-3) -> tuple[Tensor, Tensor]:
    """Camera-frame points -> pixel coordinates.

    Args:
        cam: [B, ..., 3] camera coordinates.
        K: [B, 3, 3] intrinsics (skew allowed).
        near: depths below ``near`` are clamped to it before the division (callers mask them).

    Returns:
        uv: [B, ..., 2] pixel coordinates (x = column, y = row).
        z: [B, ..., ] camera depth.
    """
    flat = _flat(cam)
    z = flat[..., 2]
    zs = z.clamp_min(near)
    xy = flat[..., :2] / zs[..., None]
    uv = torch.einsum("bij,bnj->bni", K[:, :2, :2], xy) + K[:, None, :2, 2]
    return uv.reshape(cam.shape[:-1] + (2,)), z.reshape(cam.shape[:-1])


def project_points(points: Tensor, K: Tensor, world_2_cam: Tensor, near: float = 1e-3) -> tuple[Tensor, Tensor]:
    """World points [B, ..., 3] -> (pixel coordinates [B, ..., 2], camera depth [B, ...]).

    Example:
        >>> K = torch.tensor([[[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]]])
        >>> uv, z = project_points(torch.tensor([[[0.0, 0.0, 1.0]]]), K, torch.eye(4)[None])
        >>> uv.tolist(), z.tolist()
        ([[[32.0, 32.0]]], [[1.0]])
    """
    return project_camera_points(to_camera(points, world_2_cam), K, near)


def projection_jacobian(cam: Tensor, K: Tensor, near: float = 1e-3) -> Tensor:
    """Jacobian of the pinhole projection at camera-frame points (the EWA linearisation).

    Args:
        cam: [B, M, 3] camera coordinates.
        K: [B, 3, 3] intrinsics.

    Returns:
        [B, M, 2, 3]: d(uv)/d(cam) = K[:2, :2] @ [[1/z, 0, -x/z^2], [0, 1/z, -y/z^2]].
    """
    x, y = cam[..., 0], cam[..., 1]
    z = cam[..., 2].clamp_min(near)
    iz = 1.0 / z
    zero = torch.zeros_like(iz)
    j = torch.stack([iz, zero, -x * iz * iz, zero, iz, -y * iz * iz], dim=-1).reshape(cam.shape[:-1] + (2, 3))
    return torch.einsum("bij,bmjk->bmik", K[:, :2, :2], j)
