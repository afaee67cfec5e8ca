"""Photo-like renderer of the synthetic frames: shaded strands over a shaded head.

The frame is rendered at ``supersample`` times the camera resolution and box-filtered down
(anti-aliasing): the head mesh is z-buffered with Lambert skin (plus painted eyes, brows and
lips), the strands are z-buffered as one-(super)pixel-wide point samples against the head and
each other, and each visible hair sample is shaded with a Kajiya-Kay model (diffuse from the
tangent-light angle, a white primary and a tinted secondary highlight from tangents tilted by
opposite shifts) times a per-point occlusion term. Background: a vertical gradient.

All arithmetic is numpy; colours are linear RGB until the final sRGB encoding.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from vid2haircut.camera import Camera
from vid2haircut.synth.photo_face import face_albedo_fast
from vid2haircut.synth.photo_raster import rasterize_mesh, splat_polylines


@dataclass(frozen=True)
class PhotoStyle:
    """Look of the synthetic photographs (all colours linear RGB)."""

    supersample: int = 2
    """Rendering resolution factor before the box-filter down-sampling (anti-aliasing)."""
    strand_step_px: float = 1.0
    """Spacing of the strand samples along the projected strand, in supersampled pixels."""
    light_dir: tuple[float, float, float] = (-0.45, -0.55, -0.70)
    """Direction towards the key light, camera frame (x right, y down, z forward)."""
    ambient: float = 0.28
    """Ambient light level (fraction of the albedo)."""
    skin: tuple[float, float, float] = (0.60, 0.36, 0.26)
    """Skin albedo."""
    background_top: tuple[float, float, float] = (0.42, 0.45, 0.50)
    background_bottom: tuple[float, float, float] = (0.16, 0.17, 0.19)
    spec_primary: float = 0.18
    """Strength of the white primary hair highlight."""
    spec_secondary: float = 0.45
    """Strength of the hair-coloured secondary highlight."""
    spec_exponents: tuple[float, float] = (90.0, 22.0)
    spec_shifts: tuple[float, float] = (-0.12, 0.10)
    """Tangent shifts along the outward normal of the two highlights."""


class PhotoFrame(NamedTuple):
    """One rendered frame (H, W = camera size).

    image: (H, W, 3) uint8 sRGB.
    alpha: (H, W) float32 foreground (head + hair) coverage in [0, 1].
    hair: (H, W) float32 visible-hair coverage in [0, 1] (<= alpha).
    hair_depth: (H, W) float32 mean camera z of the visible hair in the pixel, NaN where none.
    head: (H, W) float32 coverage of the head that no hair hides, in [0, 1] (None: not rendered).
    head_depth: (H, W) float32 mean camera z of that visible head in the pixel, NaN where none.
    """

    image: np.ndarray
    alpha: np.ndarray
    hair: np.ndarray
    hair_depth: np.ndarray
    head: np.ndarray | None = None
    head_depth: np.ndarray | None = None


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """Linear [0, 1] -> sRGB-encoded [0, 1] (IEC 61966-2-1)."""
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)


def supersampled_camera(camera: Camera, factor: int) -> Camera:
    """The same camera with ``factor`` times the resolution (pixel centres stay consistent)."""
    k = camera.K.copy()
    k[:2, :2] *= factor
    k[:2, 2] = (camera.K[:2, 2] + 0.5) * factor - 0.5
    return Camera(k, camera.world_2_cam, camera.width * factor, camera.height * factor)


def affine(points: np.ndarray, mat: np.ndarray, vec: np.ndarray | None = None) -> np.ndarray:
    """(K, 3) points -> (K, 3) ``points @ mat.T + vec`` in the points' dtype.

    Column by column: much faster than numpy's matmul for a 3-wide inner dimension.
    """
    points = np.asarray(points)
    mat = np.asarray(mat, dtype=points.dtype)
    out = np.empty(points.shape, dtype=points.dtype)
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    for i in range(3):
        out[:, i] = x * mat[i, 0] + y * mat[i, 1] + z * mat[i, 2]
        if vec is not None:
            out[:, i] += points.dtype.type(vec[i])
    return out


def _project(x_cam: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(K, 3) camera-frame points, (3, 3) intrinsics -> (K, 3) pixel x, pixel y, depth z."""
    out = np.empty_like(x_cam)
    k = np.asarray(k, dtype=x_cam.dtype)
    inv_z = 1.0 / x_cam[:, 2]
    out[:, 0] = x_cam[:, 0] * inv_z * k[0, 0] + k[0, 2]
    out[:, 1] = x_cam[:, 1] * inv_z * k[1, 1] + k[1, 2]
    out[:, 2] = x_cam[:, 2]
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3), (F, 3) -> (V, 3) area-weighted unit vertex normals."""
    fn = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    vn = np.zeros_like(verts)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    return _unit(vn)


def kajiya_kay(tangent: np.ndarray, light: np.ndarray, view: np.ndarray, exponent: float) -> np.ndarray:
    """(K, 3) unit tangents, (3,) or (K, 3) light and view directions -> (K,) specular term."""
    tl = (tangent * light).sum(-1)
    tv = (tangent * view).sum(-1)
    c = np.sqrt(np.clip(1 - tl * tl, 0, 1)) * np.sqrt(np.clip(1 - tv * tv, 0, 1)) - tl * tv
    return np.power(np.clip(c, 0.0, 1.0), exponent)


def _background(h: int, w: int, style: PhotoStyle) -> np.ndarray:
    t = np.linspace(0.0, 1.0, h, dtype=np.float64)[:, None, None]
    col = (1 - t) * np.asarray(style.background_top) + t * np.asarray(style.background_bottom)
    return np.ascontiguousarray(np.broadcast_to(col, (h, w, 3)), dtype=np.float32)


def _shade_head(frag, head, rot: np.ndarray, trans: np.ndarray, light: np.ndarray, style: PhotoStyle,
                hit: np.ndarray) -> np.ndarray:
    """Lambert + faint Blinn skin shading of the head pixels ``hit`` -> (K, 3) linear RGB."""
    v_can = np.asarray(head.vertices, dtype=np.float64)
    faces = np.asarray(head.faces, dtype=np.int64)
    tri = faces[frag.face.reshape(-1)[hit]]
    b = frag.bary.reshape(-1, 3)[hit].astype(np.float64)[..., None]
    normal = _unit(affine((_vertex_normals(v_can, faces)[tri] * b).sum(1), rot))
    p_can = (v_can[tri] * b).sum(1)
    albedo = face_albedo_fast(p_can, head.landmarks, np.asarray(style.skin))
    view = _unit(-affine(p_can, rot, trans))
    ndl = np.clip(normal @ light, 0.0, 1.0)
    spec = 0.06 * np.power(np.clip((normal * _unit(light + view)).sum(-1), 0, 1), 30.0)
    return (albedo * (style.ambient + (1 - style.ambient) * ndl)[:, None] + spec[:, None]).astype(np.float32)


def _shade_hair(x_cam: np.ndarray, seg: np.ndarray, frac: np.ndarray, centre: np.ndarray, colors: np.ndarray,
                occlusion: np.ndarray | None, light: np.ndarray, style: PhotoStyle) -> np.ndarray:
    """Kajiya-Kay shading of visible hair samples.

    Args:
        x_cam: (N, P, 3) strands in camera coordinates; seg: (K,) flat segment ids; frac: (K,) in [0,1].
        centre: (3,) head centre (camera frame); colors: (N, 3) albedo; occlusion: (N, P) or None.
    Returns:
        (K, 3) float32 linear RGB.
    """
    n, p = x_cam.shape[:2]
    flat = x_cam.reshape(-1, 3)
    strand, j = np.divmod(seg, p - 1)
    i0 = strand * p + j
    f = frac.astype(np.float32)[:, None]
    a = flat[i0]
    d = flat[i0 + 1] - a
    pos = a + f * d
    light = light.astype(np.float32)
    tangent = _unit(d)
    outward = _unit(pos - centre.astype(np.float32))
    view = _unit(-pos)
    u = (j + f[:, 0]) / np.float32(p - 1)
    base = np.asarray(colors, np.float32)[strand] * (0.85 + 0.3 * u)[:, None]
    tl = tangent @ light
    ol = outward @ light
    diffuse = np.sqrt(np.clip(1 - tl * tl, 0, 1)) * (0.55 + 0.45 * np.clip(ol, -1, 1))
    facing = np.clip(0.5 + ol, 0, 1)
    s1 = style.spec_primary * kajiya_kay(_unit(tangent + style.spec_shifts[0] * outward), light, view,
                                         style.spec_exponents[0]) * facing
    s2 = style.spec_secondary * kajiya_kay(_unit(tangent + style.spec_shifts[1] * outward), light, view,
                                           style.spec_exponents[1]) * facing
    col = base * (style.ambient + (1 - style.ambient) * diffuse + s2)[:, None] + s1[:, None]
    if occlusion is not None:
        occ = np.asarray(occlusion, np.float32).reshape(-1)
        col *= (occ[i0] * (1 - f[:, 0]) + occ[i0 + 1] * f[:, 0])[:, None]
    return col.astype(np.float32)


def render_photo(camera: Camera, head, world_from_head: np.ndarray, strands: np.ndarray | None,
                 colors: np.ndarray | None, style: PhotoStyle = PhotoStyle(),
                 occlusion: np.ndarray | None = None) -> PhotoFrame:
    """Render one photo-like frame.

    Args:
        camera: the camera (its size is the output size).
        head: a head model (``vertices`` (V,3), ``faces`` (F,3), ``landmarks`` (68,3), canonical frame).
        world_from_head: (4, 4) head pose.
        strands: (N, P, 3) hair in the head's canonical frame, or None for a bald head.
        colors: (N, 3) per-strand linear-RGB albedo (None: brown).
        style: look parameters.
        occlusion: (N, P) per-point light factor in [0, 1] (e.g. darker near the scalp); None = 1.
    Returns:
        :class:`PhotoFrame`.
    """
    s = int(style.supersample)
    cam = supersampled_camera(camera, s)
    hh, ww = cam.height, cam.width
    cam_from_head = cam.world_2_cam @ np.asarray(world_from_head, dtype=np.float64)
    rot, trans = cam_from_head[:3, :3], cam_from_head[:3, 3]
    light = _unit(np.asarray(style.light_dir, dtype=np.float64))
    img = _background(hh, ww, style).reshape(-1, 3)

    frag = rasterize_mesh(_project(affine(np.asarray(head.vertices, np.float64), rot, trans), cam.K),
                          head.faces, hh, ww)
    fg = (frag.face >= 0).reshape(-1)
    hit = np.flatnonzero(fg)
    img[hit] = _shade_head(frag, head, rot, trans, light, style, hit)
    hair_cov = np.zeros(hh * ww, np.float32)
    hair_z = np.zeros(hh * ww, np.float32)
    head_vis = fg.copy()

    if strands is not None and len(strands):
        pts = np.asarray(strands, dtype=np.float32)
        n, p = pts.shape[:2]
        if colors is None:
            colors = np.tile(np.array([[0.11, 0.058, 0.028]], np.float32), (n, 1))
        x_cam = affine(pts.reshape(-1, 3), rot, trans)
        sf = splat_polylines(_project(x_cam, cam.K).reshape(n, p, 3), hh, ww,
                             occluder_depth=frag.depth, step=style.strand_step_px)
        hit = np.flatnonzero(sf.segment.reshape(-1) >= 0)
        img[hit] = _shade_hair(x_cam.reshape(n, p, 3), sf.segment.reshape(-1)[hit], sf.frac.reshape(-1)[hit],
                               trans, colors, occlusion, light, style)
        hair_cov[hit] = 1.0
        hair_z[hit] = sf.depth.reshape(-1)[hit]
        fg[hit] = True
        head_vis[hit] = False

    def down(x: np.ndarray) -> np.ndarray:  # (H*s*W*s, C) -> (H, W, C) box filter
        return x.reshape(camera.height, s, camera.width, s, -1).mean(axis=(1, 3), dtype=np.float32)

    image = np.rint(linear_to_srgb(down(img)) * 255.0).astype(np.uint8)
    alpha = down(fg.astype(np.float32))[..., 0]
    hair = down(hair_cov)[..., 0]
    zsum = down(hair_z)[..., 0]
    head = down(head_vis.astype(np.float32))[..., 0]
    head_zsum = down(np.where(head_vis, frag.depth.reshape(-1), 0.0).astype(np.float32))[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        hair_depth = np.where(hair > 0, zsum / hair, np.nan).astype(np.float32)
        head_depth = np.where(head > 0, head_zsum / head, np.nan).astype(np.float32)
    return PhotoFrame(image, alpha, hair, hair_depth, head, head_depth)
