"""Scalp coverage map: how many keyframes saw each scalp texel.

For every hair-bearing texel of the scalp UV map (see :mod:`vid2haircut.head.scalp`) the root
point on the head surface is placed with each keyframe's head pose and tested against the camera:
it is seen when it projects inside the image, its outward normal faces the camera
(cos > ``min_cos``) and the head mesh does not hide it (its camera depth is within
``depth_tol`` of the head's z-buffer from :func:`vid2haircut.render.mesh_depth`). The map is
drawn in scalp UV (crown in the middle, face at the bottom) with a colour bar.
"""

from __future__ import annotations

import logging
import os
from typing import NamedTuple

import numpy as np
import torch

from vid2haircut.camera import Camera
from vid2haircut.io.atomic import write_image
from vid2haircut.report.common import figure_rgb, load_head

__all__ = ["CoverageMap", "scalp_coverage", "coverage_figure", "write_coverage"]

log = logging.getLogger(__name__)


class CoverageMap(NamedTuple):
    """Result of :func:`scalp_coverage` (R = UV resolution, M = keyframes).

    Attributes:
        counts: (R, R) int32 number of keyframes that saw each texel, 0 off the scalp;
            index [row = v, col = u].
        mask: (R, R) bool hair-bearing scalp texels.
        seen: (M, R, R) bool per-keyframe visibility (False off the scalp).
        frames: (M,) int64 frame index of each keyframe.
    """

    counts: np.ndarray
    mask: np.ndarray
    seen: np.ndarray
    frames: np.ndarray

    @property
    def seen_fraction(self) -> float:
        """Fraction of scalp texels seen by at least one keyframe."""
        return float((self.counts[self.mask] > 0).mean()) if self.mask.any() else 0.0


@torch.no_grad()
def scalp_coverage(head, camera: Camera, world_from_head: np.ndarray, frames: np.ndarray | None = None,
                   res: int = 64, min_cos: float = 0.1, depth_tol: float = 0.005,
                   device: str | torch.device = "cpu") -> CoverageMap:
    """Count, per scalp texel, the keyframes in which its root point is visible.

    Args:
        head: head model (``vertices`` (V,3), ``faces`` (F,3), ``scalp_mask(res)``,
            ``scalp_uv_to_root(uv)``), canonical frame.
        camera: the (fixed) camera of the sequence.
        world_from_head: (M, 4, 4) head pose per keyframe.
        frames: (M,) frame indices (default 0..M-1), stored in the result.
        res: UV map resolution.
        min_cos: a texel faces the camera when cos(normal, direction to the camera) > min_cos.
        depth_tol: metres a texel may lie behind the head's z-buffer and still count as seen.
        device: torch device of the z-buffer.

    Returns:
        :class:`CoverageMap`.
    """
    from vid2haircut.head import texel_uv
    from vid2haircut.render import mesh_depth

    poses = np.asarray(world_from_head, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) == 0:
        raise ValueError(f"world_from_head must be (M, 4, 4) with M >= 1, got {poses.shape}")
    m = len(poses)
    frames = np.arange(m, dtype=np.int64) if frames is None else np.asarray(frames, np.int64)
    if frames.shape != (m,):
        raise ValueError(f"frames must be ({m},), got {frames.shape}")
    mask = np.asarray(head.scalp_mask(res), bool)
    pts, nrm = head.scalp_uv_to_root(texel_uv(res)[mask])                      # (T,3) canonical
    cam_from_head = np.asarray(camera.world_2_cam, np.float64)[None] @ poses   # (M,4,4)
    rot, trans = cam_from_head[:, :3, :3], cam_from_head[:, :3, 3]
    p_cam = np.einsum("mij,tj->mti", rot, pts.astype(np.float64)) + trans[:, None]   # (M,T,3)
    n_cam = np.einsum("mij,tj->mti", rot, nrm.astype(np.float64))
    to_cam = -p_cam / np.linalg.norm(p_cam, axis=-1, keepdims=True)
    facing = (n_cam * to_cam).sum(-1) > min_cos
    z = p_cam[..., 2]
    zs = np.where(z > 1e-6, z, 1e-6)
    k = np.asarray(camera.K, np.float64)
    px = np.rint(p_cam[..., 0] / zs * k[0, 0] + k[0, 2]).astype(np.int64)
    py = np.rint(p_cam[..., 1] / zs * k[1, 1] + k[1, 2]).astype(np.int64)
    inside = (z > 1e-2) & (px >= 0) & (px < camera.width) & (py >= 0) & (py < camera.height)

    dev = torch.device(device)
    verts = torch.as_tensor(np.asarray(head.vertices, np.float32), device=dev)[None].expand(m, -1, -1)
    depth = mesh_depth(verts, torch.as_tensor(np.asarray(head.faces), device=dev),
                       torch.as_tensor(np.repeat(k[None], m, 0), dtype=torch.float32, device=dev),
                       torch.as_tensor(cam_from_head, dtype=torch.float32, device=dev),
                       camera.width, camera.height).cpu().numpy()               # (M,H,W)
    frame_idx = np.broadcast_to(np.arange(m)[:, None], px.shape)
    zbuf = depth[frame_idx, np.clip(py, 0, camera.height - 1), np.clip(px, 0, camera.width - 1)]
    visible = inside & facing & (z <= zbuf + depth_tol)

    seen = np.zeros((m, res, res), bool)
    seen[:, mask] = visible
    return CoverageMap(seen.sum(0).astype(np.int32), mask, seen, frames)


def coverage_figure(cov: CoverageMap, title: str = "scalp coverage", dpi: int = 100) -> np.ndarray:
    """Heat map of ``cov.counts`` in scalp UV with a discrete colour bar -> (H, W, 3) uint8 RGB.

    Off-scalp texels are light grey. Orientation: u (columns) grows to the subject's left, v (rows)
    to the face, so the forehead is at the bottom and the nape at the top.
    """
    from matplotlib import colormaps
    from matplotlib.colors import BoundaryNorm
    from matplotlib.figure import Figure

    m = int(cov.seen.shape[0])
    data = np.ma.masked_array(cov.counts.astype(float), mask=~cov.mask)
    cmap = colormaps["viridis"].resampled(m + 1).with_extremes(bad=(0.88, 0.88, 0.88))
    norm = BoundaryNorm(np.arange(-0.5, m + 1.0), cmap.N)
    fig = Figure(figsize=(4.6, 4.0), dpi=dpi)
    ax = fig.add_subplot()
    im = ax.imshow(data, cmap=cmap, norm=norm, origin="upper", extent=(0, 1, 1, 0), interpolation="nearest")
    ax.set_xlabel("u  (subject's right → left)")
    ax.set_ylabel("v  (nape → face)")
    ax.text(0.5, 0.98, "face", ha="center", va="bottom", fontsize=8)
    ax.text(0.5, 0.02, "nape", ha="center", va="top", fontsize=8)
    ax.plot([0.5], [0.5], "+", color="white", markersize=8)
    ax.set_title(f"{title}\n{m} keyframes; seen by ≥1: {100 * cov.seen_fraction:.0f}% of the scalp", fontsize=9)
    ticks = np.arange(m + 1) if m <= 12 else np.linspace(0, m, 7).round().astype(int)
    bar = fig.colorbar(im, ax=ax, ticks=ticks, fraction=0.046, pad=0.04)
    bar.set_label("keyframes that saw the texel")
    fig.tight_layout()
    return figure_rgb(fig)


def write_coverage(out: str | os.PathLike, dataset_root: str | os.PathLike, subject: str, seq: str,
                   keyframes: str | os.PathLike, head_fit: str | os.PathLike, res: int = 64,
                   device: str = "cpu") -> CoverageMap:
    """Coverage map of one sequence from its keyframes and fitted head poses -> PNG (atomic).

    Args:
        out: output PNG.
        dataset_root, subject, seq: locate ``<root>/<subject>/calibration/camera_params.json``.
        keyframes: ``keyframes.json`` (its ``frames`` and camera ``serial``).
        head_fit: ``head.npz`` (head model, shape, per-frame ``world_from_head``).
        res: UV resolution of the map.
    Returns:
        the :class:`CoverageMap` drawn.
    """
    from vid2haircut.camera import load_cameras
    from vid2haircut.front.headfile import load_head_fit
    from vid2haircut.front.keyframes import load_keyframes
    from vid2haircut.io.sequence import calibration_path

    sel = load_keyframes(keyframes)
    fit, meta = load_head_fit(head_fit)
    calib = calibration_path(dataset_root, subject)
    cams = load_cameras(calib)
    serial = sel.serial or meta["serial"]
    if serial not in cams:
        raise ValueError(f"{calib}: camera serial '{serial}' (from {keyframes}) not in the calibration "
                         f"(has {sorted(cams)})")
    index = {int(t): i for i, t in enumerate(fit.frames)}
    missing = [t for t in sel.frames if t not in index]
    if missing:
        log.warning("%s: keyframes %s have no head pose in %s; left out of the coverage map",
                    keyframes, missing, head_fit)
    keep = [index[t] for t in sel.frames if t in index]
    if not keep:
        raise ValueError(f"{head_fit}: none of the keyframes {sel.frames} of {keyframes} has a head pose")
    cov = scalp_coverage(load_head(head_fit), cams[serial], fit.world_from_head[keep], fit.frames[keep],
                         res=res, device=device)
    write_image(out, coverage_figure(cov, title=f"scalp coverage: {subject}/{seq}"))
    return cov
