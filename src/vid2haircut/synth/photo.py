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
from vid2haircut.synth.photo_face import face_albedo
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
    spec_primary: float = 0.28
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
    """

    image: np.ndarray
    alpha: np.ndarray
    hair: np.ndarray
    hair_depth: np.ndarray


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


def render_photo(camera: Camera, head, world_from_head: np.ndarray, strands: np.ndarray | None,
                 colors: np.ndarray | None, style: PhotoStyle = PhotoStyle(),
                 occlusion: np.ndarray | None = None) -> PhotoFrame:
    """Render one photo-like frame.

    Args:
        camera: the camera (its size is the output size).
        head: a head model (``vertices`` (V,3), ``faces`` (F,3), ``landmarks`` (68,3), canonical frame).
        world_from_head: (4, 4) head pose.
        strands: (N, P, 3) hair in the head's canonical frame, or None for a bald head.
        colors: (N, 3) per-strand linear-RGB albedo.
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
    img = _background(hh, ww, style)

    # head
    v_can = np.asarray(head.vertices, dtype=np.float64)
    faces = np.asarray(head.faces, dtype=np.int64)
    v_cam = v_can @ rot.T + trans
    uv = v_cam[:, :2] / v_cam[:, 2:3] @ cam.K[:2, :2].T + cam.K[:2, 2]
    frag = rasterize_mesh(np.c_[uv, v_cam[:, 2]], faces, hh, ww)
    hit = np.flatnonzero(frag.face.reshape(-1) >= 0)
    fidx = frag.face.reshape(-1)[hit]
    b = frag.bary.reshape(-1, 3)[hit].astype(np.float64)
    tri = faces[fidx]
    normal = _unit((_vertex_normals(v_can, faces)[tri] * b[..., None]).sum(1) @ rot.T)
    p_can = (v_can[tri] * b[..., None]).sum(1)
    albedo = face_albedo(p_can, head.landmarks, np.asarray(style.skin))
    p_cam = p_can @ rot.T + trans
    view = _unit(-p_cam)
    ndl = np.clip(normal @ light, 0.0, 1.0)
    half = _unit(light + view)
    spec = 0.06 * np.power(np.clip((normal * half).sum(-1), 0, 1), 30.0)
    shade = albedo * (style.ambient + (1 - style.ambient) * ndl)[:, None] + spec[:, None]
    img.reshape(-1, 3)[hit] = shade
    fg = frag.face >= 0
    hair_cov = np.zeros((hh, ww), bool)
    hair_z = np.zeros((hh, ww), np.float32)

    if strands is not None and len(strands):
        pts = np.asarray(strands, dtype=np.float64)
        n, p = pts.shape[:2]
        x_cam = (pts.reshape(-1, 3) @ rot.T + trans).reshape(n, p, 3)
        xy = x_cam[..., :2] / x_cam[..., 2:3] @ cam.K[:2, :2].T + cam.K[:2, 2]
        sf = splat_polylines(np.concatenate([xy, x_cam[..., 2:3]], -1).astype(np.float32), hh, ww,
                             occluder_depth=frag.depth, step=style.strand_step_px)
        hit = np.flatnonzero(sf.segment.reshape(-1) >= 0)
        seg = sf.segment.reshape(-1)[hit]
        fr = sf.frac.reshape(-1)[hit].astype(np.float64)[:, None]
        strand, j = np.divmod(seg, p - 1)
        a = x_cam[strand, j]
        d = x_cam[strand, j + 1] - a
        pos = a + fr * d
        tangent = _unit(d)
        centre = trans  # head centre (canonical origin) in camera coordinates
        outward = _unit(pos - centre)
        view = _unit(-pos)
        u = (j + fr[:, 0]) / (p - 1)
        base = np.asarray(colors, dtype=np.float64)[strand] * (0.85 + 0.3 * u)[:, None]
        occ = 1.0 if occlusion is None else (np.asarray(occlusion)[strand, j] * (1 - fr[:, 0])
                                             + np.asarray(occlusion)[strand, j + 1] * fr[:, 0])
        tl = tangent @ light
        diffuse = np.sqrt(np.clip(1 - tl * tl, 0, 1)) * (0.55 + 0.45 * np.clip(outward @ light, -1, 1))
        t1 = _unit(tangent + style.spec_shifts[0] * outward)
        t2 = _unit(tangent + style.spec_shifts[1] * outward)
        facing = np.clip(0.5 + (outward @ light), 0, 1)
        s1 = style.spec_primary * kajiya_kay(t1, light, view, style.spec_exponents[0]) * facing
        s2 = style.spec_secondary * kajiya_kay(t2, light, view, style.spec_exponents[1]) * facing
        col = (base * (style.ambient + (1 - style.ambient) * np.clip(diffuse, 0, 1))[:, None]
               + s1[:, None] + base * s2[:, None]) * np.reshape(occ, (-1, 1))
        img.reshape(-1, 3)[hit] = col
        hair_cov.reshape(-1)[hit] = True
        hair_z.reshape(-1)[hit] = sf.depth.reshape(-1)[hit]
        fg |= hair_cov

    def down(x: np.ndarray) -> np.ndarray:
        return x.reshape(camera.height, s, camera.width, s, *x.shape[2:]).mean(axis=(1, 3))

    image = np.rint(linear_to_srgb(down(img)) * 255.0).astype(np.uint8)
    alpha = down(fg.astype(np.float32)).astype(np.float32)
    hair = down(hair_cov.astype(np.float32)).astype(np.float32)
    zsum = down(hair_z)
    with np.errstate(invalid="ignore", divide="ignore"):
        hair_depth = np.where(hair > 0, zsum / hair, np.nan).astype(np.float32)
    return PhotoFrame(image, alpha, hair, hair_depth)
