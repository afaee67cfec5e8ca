"""Z-buffered numpy rasterisation for the photo-like synthetic images.

Two primitives, both vectorised (no per-primitive Python loop):

* :func:`rasterize_mesh` — a triangle mesh given in pixel coordinates + camera depth, with
  perspective-correct barycentrics (pixel centres at integer coordinates, OpenCV convention).
* :func:`splat_polylines` — polylines (strands) subdivided into point samples every ``step``
  pixels, each sample splatted to its nearest pixel, depth-tested against an opaque depth buffer
  (the head) and against each other.

Depth tests resolve with one ``np.minimum.at`` on int64 keys ``(quantised depth << 32) | id``,
so the nearest primitive wins and its id is recovered from the low bits.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

_ID_BITS = 32
_ID_MASK = (1 << _ID_BITS) - 1
_DEPTH_LEVELS = (1 << 30) - 1
_EMPTY = np.iinfo(np.int64).max


class MeshFragments(NamedTuple):
    """Per-pixel result of :func:`rasterize_mesh` (H, W image).

    depth: (H, W) float32 camera z of the nearest surface, +inf where empty.
    face: (H, W) int32 index of the nearest face, -1 where empty.
    bary: (H, W, 3) float32 perspective-correct barycentrics of that face (0 where empty).
    """

    depth: np.ndarray
    face: np.ndarray
    bary: np.ndarray


class StrandFragments(NamedTuple):
    """Per-pixel result of :func:`splat_polylines` (H, W image).

    depth: (H, W) float32 camera z of the nearest visible strand sample, +inf where none.
    segment: (H, W) int64 flat segment index ``strand * (P - 1) + j``, -1 where none.
    frac: (H, W) float32 position of the sample along its segment in [0, 1].
    """

    depth: np.ndarray
    segment: np.ndarray
    frac: np.ndarray


def _quantise(z: np.ndarray, z_min: float, z_max: float) -> np.ndarray:
    q = (z - z_min) * (_DEPTH_LEVELS / max(z_max - z_min, 1e-9))
    return np.clip(q, 0, _DEPTH_LEVELS).astype(np.int64)


def rasterize_mesh(verts: np.ndarray, faces: np.ndarray, height: int, width: int,
                   near: float = 1e-3, cull_back: bool = True) -> MeshFragments:
    """Z-buffer a triangle mesh.

    Args:
        verts: (V, 3) pixel x, pixel y, camera depth z (> 0 in front of the camera).
        faces: (F, 3) int vertex indices, counter-clockwise seen from outside.
        height, width: image size.
        near: faces with a vertex closer than this are dropped.
        cull_back: drop faces whose screen-space winding shows their back (closed meshes only).
    Returns:
        :class:`MeshFragments`.
    """
    verts = np.asarray(verts, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    tri = verts[faces]  # (F, 3, 3)
    keep = (tri[..., 2] > near).all(1)
    x, y = tri[..., 0], tri[..., 1]
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    # camera y points down, so a CCW (outward-facing) triangle has negative screen area
    keep &= (area < -1e-12) if cull_back else (np.abs(area) > 1e-12)
    x0 = np.maximum(np.ceil(x.min(1)), 0).astype(np.int64)
    x1 = np.minimum(np.floor(x.max(1)), width - 1).astype(np.int64)
    y0 = np.maximum(np.ceil(y.min(1)), 0).astype(np.int64)
    y1 = np.minimum(np.floor(y.max(1)), height - 1).astype(np.int64)
    keep &= (x1 >= x0) & (y1 >= y0)
    fid = np.flatnonzero(keep)
    bw, bh = (x1 - x0 + 1)[fid], (y1 - y0 + 1)[fid]
    count = bw * bh
    depth = np.full((height, width), np.inf, np.float32)
    face = np.full((height, width), -1, np.int32)
    bary = np.zeros((height, width, 3), np.float32)
    if count.sum() == 0:
        return MeshFragments(depth, face, bary)
    cand_face = np.repeat(fid, count)
    start = np.repeat(np.cumsum(count) - count, count)
    local = np.arange(cand_face.size, dtype=np.int64) - start
    rep_w = np.repeat(bw, count)
    px = np.repeat(x0[fid], count) + local % rep_w
    py = np.repeat(y0[fid], count) + local // rep_w
    b, zc = _barycentric(tri[cand_face], px.astype(np.float64), py.astype(np.float64), area[cand_face])
    inside = (b >= -1e-9).all(1)
    cand_face, px, py, zc = cand_face[inside], px[inside], py[inside], zc[inside]
    pix = py * width + px
    z_min, z_max = float(zc.min()), float(zc.max())
    buf = np.full(height * width, _EMPTY, np.int64)
    np.minimum.at(buf, pix, (_quantise(zc, z_min, z_max) << _ID_BITS) | cand_face)
    hit = np.flatnonzero(buf != _EMPTY)
    win = (buf[hit] & _ID_MASK).astype(np.int64)
    hy, hx = np.divmod(hit, width)
    bw_, zw = _barycentric(tri[win], hx.astype(np.float64), hy.astype(np.float64), area[win])
    depth.reshape(-1)[hit] = zw
    face.reshape(-1)[hit] = win
    bary.reshape(-1, 3)[hit] = np.clip(bw_, 0.0, 1.0)
    return MeshFragments(depth, face, bary)


def _barycentric(tri: np.ndarray, px: np.ndarray, py: np.ndarray, area: np.ndarray):
    """Screen-space edge functions -> (perspective-correct barycentrics (K, 3), depth (K,)).

    ``tri`` (K, 3, 3) pixel/depth corners; the returned barycentrics are the screen-space ones
    for the inside test (sign) but perspective-corrected in value.
    """
    x, y, z = tri[..., 0], tri[..., 1], tri[..., 2]
    w0 = (x[:, 1] - px) * (y[:, 2] - py) - (x[:, 2] - px) * (y[:, 1] - py)
    w1 = (x[:, 2] - px) * (y[:, 0] - py) - (x[:, 0] - px) * (y[:, 2] - py)
    w2 = (x[:, 0] - px) * (y[:, 1] - py) - (x[:, 1] - px) * (y[:, 0] - py)
    b = np.stack([w0, w1, w2], 1) / area[:, None]
    bz = b / z
    inv_z = bz.sum(1)
    zc = 1.0 / np.where(np.abs(inv_z) > 1e-12, inv_z, 1e-12)
    persp = bz * zc[:, None]
    # keep the sign information of the screen-space test in the returned values
    return np.where(b < 0, b, persp), zc


def _hidden_segments(a: np.ndarray, d: np.ndarray, occ: np.ndarray, max_len: float) -> np.ndarray:
    """(M,3) starts, (M,3) deltas, (H,W) occluder depth -> (M,) bool: certainly fully occluded.

    A segment no longer than ``max_len`` pixels is hidden when the largest occluder depth within
    ``max_len`` pixels of its start is in front of both of its ends (conservative: no sample of
    it could pass the depth test). Empty pixels are +inf, so segments near the silhouette stay.
    """
    import cv2

    r = int(np.ceil(max_len)) + 1
    occ = np.where(np.isfinite(occ), occ, np.float32(3.0e38)).astype(np.float32)
    dil = cv2.dilate(occ, np.ones((2 * r + 1, 2 * r + 1), np.uint8), borderType=cv2.BORDER_CONSTANT,
                     borderValue=3.0e38)
    h, w = occ.shape
    xi = np.floor(a[:, 0] + 0.5).astype(np.int64)
    yi = np.floor(a[:, 1] + 0.5).astype(np.int64)
    inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    front = np.take(dil.reshape(-1), np.where(inside, yi * w + xi, 0))
    short = np.hypot(d[:, 0], d[:, 1]) <= max_len
    return inside & short & (front < np.minimum(a[:, 2], a[:, 2] + d[:, 2]))


def splat_polylines(points: np.ndarray, height: int, width: int, occluder_depth: np.ndarray | None = None,
                    step: float = 1.0, near: float = 1e-3) -> StrandFragments:
    """Z-buffer polylines as dense point samples (one pixel wide).

    Args:
        points: (N, P, 3) pixel x, pixel y, camera depth z per polyline point.
        height, width: image size.
        occluder_depth: (H, W) opaque depth (e.g. the head), +inf where empty; samples behind it
            are discarded. None: nothing occludes.
        step: sample spacing along the projected polyline, pixels.
        near: segments with an end closer than this are dropped.
    Returns:
        :class:`StrandFragments`; ``segment`` indexes the N * (P - 1) segments.
    """
    pts = np.asarray(points, dtype=np.float32)
    a = pts[:, :-1].reshape(-1, 3)
    d = (pts[:, 1:] - pts[:, :-1]).reshape(-1, 3)
    inb = ((a[:, 2] > near) & (a[:, 2] + d[:, 2] > near)
           & (np.minimum(a[:, 0], a[:, 0] + d[:, 0]) < width) & (np.maximum(a[:, 0], a[:, 0] + d[:, 0]) > -1)
           & (np.minimum(a[:, 1], a[:, 1] + d[:, 1]) < height) & (np.maximum(a[:, 1], a[:, 1] + d[:, 1]) > -1))
    occ = None if occluder_depth is None else np.asarray(occluder_depth, np.float32).reshape(-1)
    if occ is not None:
        inb &= ~_hidden_segments(a, d, occ.reshape(height, width), max_len=8.0)
    seg = np.flatnonzero(inb)
    depth = np.full((height, width), np.inf, np.float32)
    segment = np.full((height, width), -1, np.int64)
    fr = np.zeros((height, width), np.float32)
    if seg.size == 0:
        return StrandFragments(depth, segment, fr)
    a, d = a[seg], d[seg]
    ax, ay, az = (np.ascontiguousarray(a[:, i]) for i in range(3))
    dx, dy, dz = (np.ascontiguousarray(d[:, i]) for i in range(3))
    k = np.maximum(np.ceil(np.hypot(dx, dy) / step), 1).astype(np.int64)
    total = int(k.sum())
    if total > _ID_MASK:
        raise ValueError(f"too many strand samples ({total}) for the z-buffer key")
    sid = np.repeat(np.arange(seg.size, dtype=np.int32), k)
    # position of each sample inside its segment, (i + 0.5) / k (float32 exact below 2^24 samples)
    ftype = np.float32 if total < (1 << 24) else np.float64
    frac = np.arange(total, dtype=ftype)
    frac -= np.repeat((np.cumsum(k) - k).astype(ftype) - ftype(0.5), k)
    frac *= np.repeat((1.0 / k).astype(ftype), k)
    frac = frac.astype(np.float32, copy=False)
    # nearest pixel; (x + 1.5) truncated - 1 == floor(x + 0.5) for x >= -1.5, negative below
    xs = (np.take(ax, sid) + frac * np.take(dx, sid) + np.float32(1.5)).astype(np.int32) - 1
    ys = (np.take(ay, sid) + frac * np.take(dy, sid) + np.float32(1.5)).astype(np.int32) - 1
    zs = np.take(az, sid) + frac * np.take(dz, sid)
    ok = (xs >= 0) & (xs < width) & (ys >= 0) & (ys < height)
    pix = ys * np.int32(width) + xs
    np.multiply(pix, ok, out=pix)  # out-of-image samples -> pixel 0, dropped below
    if occ is not None:
        ok &= zs < np.take(occ, pix)
    z_lo = float(np.minimum(az, az + dz).min())
    z_hi = float(np.maximum(az, az + dz).max())
    scale = np.float32((1 << 24) / max(z_hi - z_lo, 1e-9))
    q = ((zs - np.float32(z_lo)) * scale).astype(np.int64)
    np.left_shift(q, _ID_BITS, out=q)
    q |= np.arange(total, dtype=np.int64)
    keep = np.flatnonzero(ok)
    buf = np.full(height * width, _EMPTY, np.int64)
    np.minimum.at(buf, pix[keep], q[keep])
    hit = np.flatnonzero(buf != _EMPTY)
    win = buf[hit] & _ID_MASK
    depth.reshape(-1)[hit] = zs[win]
    segment.reshape(-1)[hit] = seg[sid[win]]
    fr.reshape(-1)[hit] = frac[win]
    return StrandFragments(depth, segment, fr)
