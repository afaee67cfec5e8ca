"""Small rigid-geometry helpers shared by every package folder (numpy, float64 inside)."""

from __future__ import annotations

import numpy as np


def axis_angle_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: (..., 3) axis-angle vectors -> (..., 3, 3) rotation matrices."""
    rv = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(rv, axis=-1, keepdims=True)
    safe = np.where(theta > 1e-12, theta, 1.0)
    k = rv / safe
    kx, ky, kz = k[..., 0], k[..., 1], k[..., 2]
    zero = np.zeros_like(kx)
    kmat = np.stack([zero, -kz, ky, kz, zero, -kx, -ky, kx, zero], axis=-1).reshape(rv.shape[:-1] + (3, 3))
    th = theta[..., None]
    eye = np.broadcast_to(np.eye(3), kmat.shape)
    rot = eye + np.sin(th) * kmat + (1.0 - np.cos(th)) * (kmat @ kmat)
    return np.where(theta[..., None] > 1e-12, rot, eye)


def matrix_to_axis_angle(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) axis-angle vectors (angle in [0, pi])."""
    from scipy.spatial.transform import Rotation

    r = np.asarray(rot, dtype=np.float64)
    flat = Rotation.from_matrix(r.reshape(-1, 3, 3)).as_rotvec()
    return flat.reshape(r.shape[:-2] + (3,))


def make_transform(rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """Build (..., 4, 4) homogeneous transforms from (..., 3, 3) rotations and (..., 3) translations."""
    rot = np.asarray(rot, dtype=np.float64)
    trans = np.asarray(trans, dtype=np.float64)
    out = np.zeros(rot.shape[:-2] + (4, 4))
    out[..., :3, :3] = rot
    out[..., :3, 3] = trans
    out[..., 3, 3] = 1.0
    return out


def apply_transform(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) transform to (..., 3) points."""
    t = np.asarray(transform, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return p @ t[:3, :3].T + t[:3, 3]


def rotation_angle_deg(r_a: np.ndarray, r_b: np.ndarray) -> float:
    """Geodesic angle in degrees between two (3, 3) rotations."""
    r = np.asarray(r_a, dtype=np.float64).T @ np.asarray(r_b, dtype=np.float64)
    c = np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(c)))
