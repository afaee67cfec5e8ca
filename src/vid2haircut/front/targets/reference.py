"""Reference ("true") 2D orientation maps from known 3D strands, for evaluating the targets.

Used on synthetic sequences, where the moved hair of every frame is known: the strands are placed
by the frame's head pose, projected, and rasterised with a z-buffer (front-most strand sample
wins) into a map of the projected segment direction, in the convention of
:mod:`vid2haircut.front.targets.orientation` (angle in [0, pi), vector (cos a, sin a) in pixel
axes x right, y down).
"""

from __future__ import annotations

import numpy as np

from vid2haircut.camera import Camera


def projected_direction_map(camera: Camera, world_from_head: np.ndarray, strands: np.ndarray,
                            step_px: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Rasterise the projected direction of strands.

    Args:
        camera: the camera; world_from_head: (4, 4) head pose of the frame.
        strands: (N, P, 3) strand points in the head frame (metres).
        step_px: spacing of the samples along each projected segment.
    Returns:
        angle (H, W) float32 in [0, pi) (NaN where no strand), depth (H, W) float32 camera z
        of the front-most sample (inf where none).
    """
    pts = np.asarray(strands, np.float64)
    world = pts @ world_from_head[:3, :3].T + world_from_head[:3, 3]
    uv, z = camera.project(world)  # (N, P, 2), (N, P)
    a, b = uv[:, :-1].reshape(-1, 2), uv[:, 1:].reshape(-1, 2)
    za, zb = z[:, :-1].reshape(-1), z[:, 1:].reshape(-1)
    d = b - a
    length = np.linalg.norm(d, axis=1)
    ok = (za > 0) & (zb > 0) & (length > 1e-6)
    a, d, za, zb, length = a[ok], d[ok], za[ok], zb[ok], length[ok]
    ang = np.mod(np.arctan2(d[:, 1], d[:, 0]), np.pi)
    n = np.maximum(1, np.ceil(length / step_px).astype(np.int64))
    seg = np.repeat(np.arange(len(n)), n)
    frac = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / np.repeat(n, n)
    p = a[seg] + frac[:, None] * d[seg]
    zz = za[seg] + frac * (zb[seg] - za[seg])
    col, row = np.round(p[:, 0]).astype(np.int64), np.round(p[:, 1]).astype(np.int64)
    h, w = camera.height, camera.width
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    pix, zz, sa = row[inside] * w + col[inside], zz[inside], ang[seg[inside]]
    order = np.lexsort((zz, pix))  # by pixel, then nearest first
    pix, zz, sa = pix[order], zz[order], sa[order]
    first = np.ones(len(pix), bool)
    first[1:] = pix[1:] != pix[:-1]
    angle = np.full(h * w, np.nan, np.float32)
    depth = np.full(h * w, np.inf, np.float32)
    angle[pix[first]] = sa[first]
    depth[pix[first]] = zz[first]
    angle[angle >= np.float32(np.pi)] = 0.0
    return angle.reshape(h, w), depth.reshape(h, w)
