"""Skin albedo of the synthetic head: plain skin with eyes, eyebrows and lips painted procedurally.

The features are placed from the head model's iBUG-68 landmarks in the canonical frame (face
towards +z), so they follow any head shape. Albedo is evaluated per rendered pixel from the
canonical surface point, which keeps the features sharp whatever the mesh resolution.
"""

from __future__ import annotations

import numpy as np

SKIN = np.array([0.60, 0.36, 0.26])
SCLERA = np.array([0.72, 0.68, 0.64])
IRIS = np.array([0.10, 0.06, 0.035])
BROW = np.array([0.07, 0.045, 0.03])
LIPS = np.array([0.42, 0.14, 0.12])
MOUTH_LINE = np.array([0.12, 0.04, 0.035])


def _soft_inside(dist: np.ndarray, width: float) -> np.ndarray:
    """1 where dist <= -width/2, 0 where dist >= width/2, smooth in between."""
    t = np.clip(0.5 - dist / max(width, 1e-9), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _polyline_distance(q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(K, 2) points, (L, 2) polyline -> (K,) distance to the polyline."""
    a, b = poly[:-1], poly[1:]
    ab = b - a
    t = np.clip(((q[:, None] - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0, 1)
    closest = a + t[..., None] * ab
    return np.linalg.norm(q[:, None] - closest, axis=-1).min(1)


def face_albedo(points: np.ndarray, landmarks: np.ndarray, skin: np.ndarray = SKIN) -> np.ndarray:
    """Linear-RGB albedo of canonical head surface points.

    Args:
        points: (K, 3) canonical-frame surface points, metres.
        landmarks: (68, 3) iBUG-68 landmarks of the same head.
        skin: (3,) base skin albedo (linear RGB).
    Returns:
        (K, 3) float32 albedo.
    """
    q = np.asarray(points, dtype=np.float64)
    lm = np.asarray(landmarks, dtype=np.float64)
    out = np.broadcast_to(np.asarray(skin, np.float64), q.shape).copy()
    if q.size == 0:
        return out.astype(np.float32)
    front_z = lm[27:36, 2].min() - 0.035
    front = q[:, 2] > front_z
    xy = q[:, :2]
    soft = 0.0008
    # lips: ellipse through the outer mouth contour, dark line along the inner contour
    mc = lm[48:60, :2].mean(0)
    hw = 0.5 * np.linalg.norm(lm[54, :2] - lm[48, :2])
    hh = 0.5 * max(abs(lm[51, 1] - lm[57, 1]), 0.2 * hw)
    r = np.sqrt(((xy[:, 0] - mc[0]) / hw) ** 2 + ((xy[:, 1] - mc[1]) / hh) ** 2)
    a = _soft_inside((r - 1.0) * hh, soft) * front
    out += a[:, None] * (LIPS - out)
    inner = np.concatenate([lm[60:65, :2], lm[[64], :2]]) if len(lm) >= 68 else lm[48:55, :2]
    line = _polyline_distance(xy, np.vstack([lm[[48], :2], inner, lm[[54], :2]]))
    a = _soft_inside(line - 0.0007, soft) * front
    out += a[:, None] * (MOUTH_LINE - out)
    # eyes: almond ellipses with a dark iris
    for lo in (36, 42):
        eye = lm[lo:lo + 6, :2]
        ec = eye.mean(0)
        ew = 0.5 * np.linalg.norm(eye[3] - eye[0])
        eh = max(0.5 * (abs(eye[1, 1] - eye[5, 1]) + abs(eye[2, 1] - eye[4, 1])) * 0.5, 0.3 * ew)
        r = np.sqrt(((xy[:, 0] - ec[0]) / ew) ** 2 + ((xy[:, 1] - ec[1]) / eh) ** 2)
        a = _soft_inside((r - 1.0) * eh, soft) * front
        out += a[:, None] * (SCLERA - out)
        ri = np.linalg.norm(xy - ec, axis=1)
        a = _soft_inside(ri - 0.42 * ew, soft) * _soft_inside((r - 1.0) * eh, soft) * front
        out += a[:, None] * (IRIS - out)
    # eyebrows: thick tapered lines along the brow landmarks
    for lo in (17, 22):
        brow = lm[lo:lo + 5, :2]
        dist = _polyline_distance(xy, brow)
        a = 0.85 * _soft_inside(dist - 0.0028, 0.0015) * front
        out += a[:, None] * (BROW - out)
    return out.astype(np.float32)


_TEXTURES: dict[bytes, tuple[np.ndarray, float, float, float]] = {}


def _face_texture(landmarks: np.ndarray, skin: np.ndarray, texel: float):
    """Bake :func:`face_albedo` on the canonical x-y plane over the feature region (cached).

    Returns (texture (H, W, 3) float32, x0, y0, texel) with texel (i, j) at (x0 + j*texel, y0 + i*texel).
    """
    lm = np.asarray(landmarks, np.float64)
    key = lm.astype(np.float32).tobytes() + np.asarray(skin, np.float32).tobytes() + np.float32(texel).tobytes()
    if key not in _TEXTURES:
        lo = lm[17:68, :2].min(0) - 0.008
        hi = lm[17:68, :2].max(0) + 0.008
        nx, ny = (np.ceil((hi - lo) / texel).astype(int) + 1)
        gx, gy = np.meshgrid(lo[0] + texel * np.arange(nx), lo[1] + texel * np.arange(ny))
        q = np.stack([gx, gy, np.full_like(gx, lm[27:36, 2].max())], -1).reshape(-1, 3)
        tex = face_albedo(q, lm, skin).reshape(ny, nx, 3)
        if len(_TEXTURES) > 16:
            _TEXTURES.clear()
        _TEXTURES[key] = (tex, float(lo[0]), float(lo[1]), float(texel))
    return _TEXTURES[key]


def face_albedo_fast(points: np.ndarray, landmarks: np.ndarray, skin: np.ndarray = SKIN,
                     texel: float = 2.5e-4) -> np.ndarray:
    """Same as :func:`face_albedo`, looked up (bilinear) in a baked x-y texture.

    Args:
        points: (K, 3) canonical-frame surface points.
        landmarks: (68, 3) landmarks; skin: (3,) base albedo; texel: texture spacing, metres.
    Returns:
        (K, 3) float32 albedo.
    """
    q = np.asarray(points, np.float64)
    tex, x0, y0, tx = _face_texture(landmarks, skin, texel)
    out = np.empty((q.shape[0], 3), np.float32)
    out[:] = np.asarray(skin, np.float32)
    lm = np.asarray(landmarks, np.float64)
    fx = (q[:, 0] - x0) / tx
    fy = (q[:, 1] - y0) / tx
    ny, nx = tex.shape[:2]
    sel = np.flatnonzero((q[:, 2] > lm[27:36, 2].min() - 0.035) & (fx >= 0) & (fx < nx - 1)
                         & (fy >= 0) & (fy < ny - 1))
    if sel.size:
        fx, fy = fx[sel], fy[sel]
        ix, iy = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
        wx, wy = (fx - ix)[:, None], (fy - iy)[:, None]
        out[sel] = ((1 - wy) * ((1 - wx) * tex[iy, ix] + wx * tex[iy, ix + 1])
                    + wy * ((1 - wx) * tex[iy + 1, ix] + wx * tex[iy + 1, ix + 1]))
    return out
