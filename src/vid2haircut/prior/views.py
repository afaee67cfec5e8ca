"""Inputs of the hair prior: the canonical head-centred crop, and the training-view renderer.

:func:`prior_input` turns the targets of ONE view (hair mask, orientation angle, relative depth)
plus the camera and the head pose into the network input: a ``(1, C, S, S)`` tensor sampled on a
square window of the head's image plane. The window is centred on the projection of the head-frame
point ``crop_center`` (default 4 cm below the head centre, so long hair fits) and spans
``2 * half_extent`` metres at the depth of that point, so the crop is the same whatever the head's
position in the image, the camera distance or the image resolution. Channels
(:data:`INPUT_CHANNELS`): mask, mask*cos(2a), mask*sin(2a), depth*valid, valid, in_image (1 where
the crop sees the image: hair that runs off the image border is then told apart from hair that ends).

The same function builds training inputs from views rendered by :func:`render_view` (a generated
hairstyle on the proxy head, posed by :func:`random_pose`, rendered through
:func:`vid2haircut.render.render_strands` with the head mesh as occluder, with the camera of the
synthetic sequences, ``vid2haircut.synth.sequence.make_camera``, scaled to a small sensor).

Example::

    cfg = ViewConfig()
    pose = random_pose(np.random.default_rng(0), cfg)
    maps = render_view(strands.points, head, pose, cfg, seed=0)
    x = prior_input(*maps.as_tuple(), maps.K, maps.world_2_cam, pose, size=128)   # (1,6,128,128)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from vid2haircut.geometry import apply_transform, axis_angle_to_matrix, make_transform

__all__ = ["INPUT_CHANNELS", "CROP_HALF_EXTENT", "CROP_CENTER", "prior_input", "crop_affine", "ViewConfig",
           "ViewMaps", "random_pose", "render_view", "photo_view", "relative_depth_quantile"]

INPUT_CHANNELS = ("mask", "mask_cos2a", "mask_sin2a", "depth", "depth_valid", "in_image")
"""Channel order of :func:`prior_input`."""
CROP_HALF_EXTENT = 0.2
"""Half the side of the crop window, metres at the depth of the crop centre."""
CROP_CENTER = (0.0, -0.04, 0.0)
"""Crop centre in the head's canonical frame (metres): 4 cm below the head centre."""
PIVOT = (0.0, -0.09, -0.02)
"""Neck pivot of the training poses (the pivot of ``vid2haircut.synth.motion.MotionParams``)."""


def crop_affine(K: np.ndarray, world_2_cam: np.ndarray, world_from_head: np.ndarray, size: int,
                half_extent: float = CROP_HALF_EXTENT, center: tuple[float, float, float] = CROP_CENTER,
                ) -> np.ndarray:
    """Affine map from crop pixel coordinates to image pixel coordinates.

    Args:
        K: (3,3) intrinsics; world_2_cam: (4,4); world_from_head: (4,4) head pose.
        size: crop side S in pixels.
        half_extent, center: the window (see the module docstring).

    Returns:
        (2,3) float64 ``A`` with ``[x_img, y_img] = A @ [x_crop, y_crop, 1]`` (pixel centres at
        integer coordinates in both images). Raises ValueError when the centre is behind the camera.
    """
    K = np.asarray(K, np.float64)
    p = apply_transform(np.asarray(world_2_cam, np.float64) @ np.asarray(world_from_head, np.float64),
                        np.asarray(center, np.float64))
    if p[2] <= 1e-6:
        raise ValueError(f"prior_input: the head centre is behind the camera (camera z = {p[2]:.4f} m)")
    c = K[:2, :2] @ (p[:2] / p[2]) + K[:2, 2]                   # projected centre (x, y)
    m_per_px = 2.0 * half_extent / size
    sx, sy = K[0, 0] / p[2] * m_per_px, K[1, 1] / p[2] * m_per_px   # image px per crop px
    off = 0.5 * (size - 1)
    return np.array([[sx, 0.0, c[0] - sx * off], [0.0, sy, c[1] - sy * off]])


def prior_input(mask: np.ndarray, angle: np.ndarray, depth: np.ndarray, depth_valid: np.ndarray | None,
                K: np.ndarray, world_2_cam: np.ndarray, world_from_head: np.ndarray, size: int = 128,
                half_extent: float = CROP_HALF_EXTENT, center: tuple[float, float, float] = CROP_CENTER,
                device: torch.device | str | None = None) -> torch.Tensor:
    """Network input of one view: its maps resampled into the canonical head-centred crop.

    Args:
        mask: (H,W) hair mask in [0,1] (bool or float).
        angle: (H,W) undirected 2D hair direction in [0,pi) (x right, y down; Gabor or rendered).
        depth: (H,W) relative depth (about [0,1] inside the mask; 0 = near); clipped to [-0.5, 1.5].
        depth_valid: (H,W) bool where ``depth`` is meaningful (None = nowhere: no depth channel).
        K: (3,3) intrinsics; world_2_cam: (4,4) extrinsics; world_from_head: (4,4) head pose
            (all of the view the maps come from).
        size: crop side S.
        half_extent, center: crop window (see :func:`crop_affine`).
        device: device of the result.

    Returns:
        (1,6,S,S) float32 tensor, channels :data:`INPUT_CHANNELS`; the first five are zero outside
        the image, ``in_image`` is 1 inside it. Downsampling is anti-aliased with a Gaussian pre-blur.
    """
    mask = np.asarray(mask)
    h, w = mask.shape[:2]
    for name, arr in (("angle", angle), ("depth", depth)) + ((("depth_valid", depth_valid),)
                                                             if depth_valid is not None else ()):
        if np.shape(arr) != (h, w):
            raise ValueError(f"prior_input: {name} has shape {np.shape(arr)}, expected the mask's {(h, w)}")
    m = np.clip(mask.astype(np.float32), 0.0, 1.0)
    a = np.asarray(angle, np.float32)
    if depth_valid is None:
        dv = np.zeros((h, w), np.float32)
    else:
        dv = ((np.asarray(depth_valid) > 0) & (m > 0.5)).astype(np.float32)
    d = np.clip(np.nan_to_num(np.asarray(depth, np.float32)), -0.5, 1.5) * dv
    chans = np.stack([m, m * np.cos(2 * a), m * np.sin(2 * a), d, dv], axis=-1)      # (H,W,5)
    A = crop_affine(K, world_2_cam, world_from_head, size, half_extent, center)
    scale = 0.5 * (A[0, 0] + A[1, 1])
    if scale > 1.25:   # anti-alias: blur so that the sampled grid sees ~one input pixel per sample
        sigma = 0.5 * math.sqrt(scale * scale - 1.0)
        chans = cv2.GaussianBlur(chans, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_CONSTANT)
    src = torch.as_tensor(np.ascontiguousarray(chans.transpose(2, 0, 1)))[None]     # (1,5,H,W)
    js, is_ = np.meshgrid(np.arange(size, dtype=np.float64), np.arange(size, dtype=np.float64), indexing="xy")
    x = A[0, 0] * js + A[0, 2]
    y = A[1, 1] * is_ + A[1, 2]
    grid = np.stack([(2.0 * x + 1.0) / w - 1.0, (2.0 * y + 1.0) / h - 1.0], -1)   # align_corners=False
    out = F.grid_sample(src, torch.as_tensor(grid, dtype=torch.float32)[None], mode="bilinear",
                        padding_mode="zeros", align_corners=False)
    inside = (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5)
    out = torch.cat([out, torch.as_tensor(inside, dtype=torch.float32)[None, None]], dim=1)
    return out.to(device=device)


# -- training views -------------------------------------------------------------------------


@dataclass(frozen=True)
class ViewConfig:
    """How training views are posed and rendered."""

    render_size: int = 128
    """Rendered image side (the 512 px synthetic camera with its intrinsics scaled to this size)."""
    yaw_deg: float = 25.0
    """Head yaw drawn uniformly in [-yaw_deg, yaw_deg]."""
    pitch_deg: float = 10.0
    """Head pitch drawn uniformly in [-pitch_deg, pitch_deg]."""
    translation_m: float = 0.015
    """Head translation jitter (x, y) drawn uniformly in [-t, t] metres."""
    distance_m: tuple[float, float] = (0.6, 0.8)
    """Camera distance range (fixed lens of the 0.7 m set-up: the scale jitter)."""
    render_strands: int = 1000
    """Strands drawn per view (a random subset; the hair is rendered thicker to stay solid)."""
    render_points: int = 25
    """Points per strand for rendering (resampled by index stride)."""
    strand_width: float = 2.0e-3
    """Strand width used for the training renders, metres."""
    source: str = "render"
    """"render": maps drawn directly by the strand renderer (:func:`render_view`); "photo": a
    photo-like frame of a denser copy of the style, turned into maps as the pipeline's targets are
    (the frame's hair coverage as the mask, the Gabor orientation of the photo; :func:`photo_view`)."""
    photo_strands: int = 10000
    """Strands of the denser copy drawn in "photo" views (the synthetic sequences use 10k)."""
    photo_size: int = 512
    """Side of the "photo" frames (the synthetic sequences' 512 px camera)."""

    def __post_init__(self) -> None:
        if self.source not in ("render", "photo"):
            raise ValueError(f"ViewConfig.source must be 'render' or 'photo', got {self.source!r}")

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "ViewConfig":
        """Inverse of the ``view`` entry of a prior's training record (``prior.json``; keys that a
        direct-render record leaves out take their defaults, unknown keys are an error)."""
        known = {f.name for f in fields(ViewConfig)}
        extra = sorted(set(d) - known)
        if extra:
            raise ValueError(f"ViewConfig: unknown keys {extra}")
        return ViewConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


class ViewMaps(NamedTuple):
    """One rendered training view (numpy, image size H = W = ``render_size``).

    Attributes:
        mask: (H,W) float32 visible-hair mask in {0,1}.
        angle: (H,W) float32 2D direction in [0,pi).
        depth: (H,W) float32 relative depth (5%/95% quantiles -> 0/1 inside the mask), 0 outside.
        depth_valid: (H,W) bool.
        K: (3,3) float64 intrinsics; world_2_cam: (4,4) float64.
    """

    mask: np.ndarray
    angle: np.ndarray
    depth: np.ndarray
    depth_valid: np.ndarray
    K: np.ndarray
    world_2_cam: np.ndarray

    def as_tuple(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(mask, angle, depth, depth_valid)``, the first arguments of :func:`prior_input`."""
        return self.mask, self.angle, self.depth, self.depth_valid


def random_pose(rng: np.random.Generator, cfg: ViewConfig = ViewConfig()) -> np.ndarray:
    """A frontal-ish world_from_head pose: yaw, pitch about the neck pivot, small translation.

    Returns:
        (4,4) float64 rigid transform (world = the head's canonical frame at rest).
    """
    yaw = math.radians(rng.uniform(-cfg.yaw_deg, cfg.yaw_deg))
    pitch = math.radians(rng.uniform(-cfg.pitch_deg, cfg.pitch_deg))
    rot = axis_angle_to_matrix(np.array([0.0, yaw, 0.0])) @ axis_angle_to_matrix(np.array([pitch, 0.0, 0.0]))
    piv = np.asarray(PIVOT, np.float64)
    t = piv - rot @ piv
    t[:2] += rng.uniform(-cfg.translation_m, cfg.translation_m, 2)
    return make_transform(rot, t)


def view_camera(head: Any, distance: float, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The synthetic sequences' camera (512 px, head filling 0.6 of the height at 0.7 m) moved to
    ``distance`` with the same lens, its intrinsics scaled to a ``size`` x ``size`` sensor.

    Returns:
        (K (3,3), world_2_cam (4,4)) float64.
    """
    from vid2haircut.camera import look_at
    from vid2haircut.synth.sequence import make_camera

    ref = make_camera(head, 512, 512, 0.7, 0.6)
    K = ref.K.copy()
    K[:2] *= size / 512.0
    K[0, 2] = K[1, 2] = (size - 1) / 2.0
    yc = float(ref.center[1])                            # the reference camera aims at y = yc
    return K, look_at(np.array([0.0, yc, distance]), np.array([0.0, yc, 0.0]))


def relative_depth_quantile(z: np.ndarray, valid: np.ndarray, lo: float = 0.05, hi: float = 0.95) -> np.ndarray:
    """(H,W) camera z -> (H,W) float32 relative depth: the ``lo``/``hi`` quantiles inside ``valid``
    map to 0/1 (as the pipeline's depth targets); 0 outside ``valid``."""
    out = np.zeros(z.shape, np.float32)
    if valid.any():
        q0, q1 = np.quantile(z[valid], [lo, hi])
        out[valid] = (z[valid] - q0) / max(float(q1 - q0), 1e-6)
    return out


def render_view(points: np.ndarray, head: Any, world_from_head: np.ndarray, cfg: ViewConfig = ViewConfig(),
                seed: int = 0, distance: float | None = None) -> ViewMaps:
    """Render one training view of a hairstyle.

    Args:
        points: (N,P,3) strands in the head's canonical frame.
        head: head model (its mesh occludes the hair behind it).
        world_from_head: (4,4) head pose (e.g. :func:`random_pose`).
        cfg: rendering settings.
        seed: seed of the strand subset (and of the camera distance when ``distance`` is None).
        distance: camera distance, metres (None = drawn from ``cfg.distance_m``).

    Returns:
        :class:`ViewMaps` of size ``cfg.render_size``.
    """
    from vid2haircut.render import mesh_depth, render_strands

    pts = np.asarray(points, np.float64)
    if pts.ndim != 3 or pts.shape[-1] != 3 or pts.shape[0] == 0:
        raise ValueError(f"render_view: points must be (N,P,3) with N >= 1, got {pts.shape}")
    rng = np.random.default_rng(seed)
    if distance is None:
        distance = float(rng.uniform(*cfg.distance_m))
    n = min(cfg.render_strands, pts.shape[0])
    sel = np.sort(rng.choice(pts.shape[0], n, replace=False))
    stride = max(1, (pts.shape[1] - 1) // max(cfg.render_points - 1, 1))
    idx = np.unique(np.r_[np.arange(0, pts.shape[1], stride), pts.shape[1] - 1])
    world = apply_transform(world_from_head, pts[sel][:, idx])
    verts = apply_transform(world_from_head, np.asarray(head.vertices, np.float64))
    size = int(cfg.render_size)
    K, w2c = view_camera(head, distance, size)
    Kt, Wt = torch.as_tensor(K, dtype=torch.float32)[None], torch.as_tensor(w2c, dtype=torch.float32)[None]
    with torch.no_grad():
        hd = mesh_depth(torch.as_tensor(verts, dtype=torch.float32)[None],
                        torch.as_tensor(np.asarray(head.faces)), Kt, Wt, size, size)
        r = render_strands(torch.as_tensor(world, dtype=torch.float32)[None], Kt, Wt, size, size,
                           strand_width=cfg.strand_width, head_depth=hd, bins=8, compositing="bins")  # (the prior's training views)
    mask = r.mask[0].numpy()
    depth = relative_depth_quantile(r.depth[0].numpy(), mask)
    return ViewMaps(mask.astype(np.float32), r.angle[0].numpy().astype(np.float32), depth, mask.copy(), K, w2c)


def photo_view(points: np.ndarray, head: Any, world_from_head: np.ndarray, cfg: ViewConfig = ViewConfig(),
               colors: np.ndarray | None = None, distance: float = 0.7) -> ViewMaps:
    """A training view made like the pipeline's targets: a photo-like frame of the strands
    (:func:`vid2haircut.synth.photo.render_photo`, the synthetic sequences' camera moved to
    ``distance``), its hair coverage as the mask and the Gabor orientation of the photo
    (:func:`vid2haircut.front.targets.orientation.orientation_map`), relative depth of the hair.

    Args:
        points: (N,P,3) strands in the head's canonical frame (dense: the photo draws every one).
        head, world_from_head: head model and pose. cfg: uses ``photo_size``.
        colors: (N,3) linear-RGB strand albedo (None: the renderer's brown).
        distance: camera distance, metres.

    Returns:
        :class:`ViewMaps` of size ``cfg.photo_size``.
    """
    from vid2haircut.camera import Camera
    from vid2haircut.front.targets.orientation import orientation_map
    from vid2haircut.synth.photo import render_photo

    pts = np.asarray(points, np.float32)
    if pts.ndim != 3 or pts.shape[-1] != 3 or pts.shape[0] == 0:
        raise ValueError(f"photo_view: points must be (N,P,3) with N >= 1, got {pts.shape}")
    size = int(cfg.photo_size)
    K, w2c = view_camera(head, distance, size)
    fr = render_photo(Camera(K, w2c, size, size), head, world_from_head, pts, colors)
    mask = np.asarray(fr.hair, np.float32)
    om = orientation_map(fr.image, mask)
    valid = (mask >= 0.5) & np.isfinite(fr.hair_depth)
    depth = relative_depth_quantile(np.nan_to_num(fr.hair_depth), valid)
    return ViewMaps(mask, np.asarray(om.angle, np.float32), depth, valid, K, w2c)


def view_strands(points: np.ndarray, family: str, seed: int, cfg: ViewConfig, n_points: int,
                 head: Any) -> np.ndarray:
    """(N,P,3) strands that the views of one generated style draw: ``points`` themselves for direct
    renders, a dense copy of the style (family, seed) with ``cfg.photo_strands`` strands for photo
    views (a photo draws every strand, as the synthetic sequences' 10k-strand hair)."""
    if cfg.source != "photo":
        return points
    from vid2haircut.prior.corpus import generate_style

    return generate_style(family, int(seed), cfg.photo_strands, n_points, head).points


def training_view(points: np.ndarray, head: Any, world_from_head: np.ndarray, cfg: ViewConfig,
                  view_seed: int) -> ViewMaps:
    """One view as the prior is trained on it: :func:`photo_view` when ``cfg.source`` is "photo"
    (``points`` from :func:`view_strands`; the
    camera distance is drawn from ``cfg.distance_m`` with ``view_seed``), else :func:`render_view`
    (``view_seed`` also picks the strand subset)."""
    if cfg.source == "photo":
        dist = float(np.random.default_rng(view_seed).uniform(*cfg.distance_m))
        return photo_view(points, head, world_from_head, cfg, distance=dist)
    return render_view(points, head, world_from_head, cfg, seed=view_seed)
