"""Turntable strip of a hairstyle: front, 3/4, side and back views of the strands on the head,
shaded with the photo-like renderer of the synthetic data (:func:`vid2haircut.synth.photo.render_photo`),
optionally with the ground truth as a second row rendered identically.

The head is turned in front of a fixed camera on the +z axis (the canonical face direction) that
frames the head and all hair of the strip at every yaw (one camera for both rows):
view yaw a rotates the head by a about +y, so 90 degrees shows the subject's right side and 180
degrees the back of the head. Both rows use the same colour, lighting and strand cap, so the
rows differ only in the strands.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from vid2haircut.camera import Camera, look_at
from vid2haircut.geometry import axis_angle_to_matrix, make_transform
from vid2haircut.io.atomic import write_image
from vid2haircut.report.common import label_tile, load_head
from vid2haircut.strands import StrandSet
from vid2haircut.synth.photo import PhotoFrame, PhotoStyle, render_photo

__all__ = ["VIEWS", "TurntableStyle", "view_pose", "framing_camera", "prepare_strands", "render_views", "turntable_strip",
           "write_turntable"]

#: (label, yaw in degrees) of the default views.
VIEWS: tuple[tuple[str, float], ...] = (("front", 0.0), ("3/4", 45.0), ("side", 90.0), ("back", 180.0))


@dataclass(frozen=True)
class TurntableStyle:
    """Look of a turntable strip."""

    size: int = 256
    """Height of one view, pixels (the width follows the framed extent, at most the height)."""
    margin: float = 0.06
    """Free border around the framed head and hair, as a fraction of the image side."""
    distance: float = 1.0
    """Camera distance from the head centre, metres."""
    views: tuple[tuple[str, float], ...] = VIEWS
    """(label, yaw degrees) per column."""
    max_strands: int = 20000
    """Strand sets above this are randomly thinned (``default_rng(seed)``) for speed."""
    color: tuple[float, float, float] = (0.11, 0.058, 0.028)
    """Linear-RGB hair albedo used for every row (brown)."""
    color_jitter: float = 0.12
    """Per-strand log-normal brightness jitter (sigma), so single strands stay visible."""
    seed: int = 0
    """Seed of the strand thinning and the colour jitter."""
    photo: PhotoStyle = field(default_factory=PhotoStyle)
    """Lighting and shading of the renderer."""


def view_pose(yaw_deg: float) -> np.ndarray:
    """(4, 4) world_from_head turning the head by ``yaw_deg`` about +y (no translation)."""
    return make_transform(axis_angle_to_matrix(np.array([0.0, np.deg2rad(yaw_deg), 0.0])), np.zeros(3))


def framing_camera(head, point_sets: Sequence[np.ndarray], style: TurntableStyle) -> Camera:
    """Camera on the +z axis that frames the head and every point set at every yaw.

    The image is ``style.size`` pixels high and at most as wide (narrower for long hair).

    Args:
        head: head model (``vertices`` (V,3)).
        point_sets: arrays (..., 3) of strand points (canonical frame) that must stay in view.
        style: image size, margin and camera distance.
    Returns:
        a :class:`~vid2haircut.camera.Camera` looking at the middle of the vertical extent along -z.
    """
    pts = np.concatenate([np.asarray(head.vertices, np.float64).reshape(-1, 3)]
                         + [np.asarray(p, np.float64).reshape(-1, 3) for p in point_sets])
    radius = float(np.hypot(pts[:, 0], pts[:, 2]).max())          # reach of the turning head
    y_lo, y_hi = float(pts[:, 1].min()), float(pts[:, 1].max())
    yc = 0.5 * (y_lo + y_hi)
    d = max(style.distance, 2.0 * radius)
    near = d - radius                                              # closest a point gets to the camera
    half = max(0.5 * (y_hi - y_lo), radius)
    f = (0.5 - style.margin) * style.size * near / half
    width = int(min(style.size, 2 * np.ceil(f * radius / near + style.margin * style.size)))
    k = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (style.size - 1) / 2.0], [0.0, 0.0, 1.0]])
    return Camera(k, look_at(np.array([0.0, yc, d]), np.array([0.0, yc, 0.0])), width, style.size)


def prepare_strands(strands: StrandSet, head, style: TurntableStyle) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Thin, colour and occlusion-shade a strand set for rendering.

    Returns:
        points (N', P, 3) float32, colors (N', 3) float32 linear RGB, occlusion (N', P) float32 in
        [0, 1] (darker close to the scalp); N' = min(N, max_strands).
    """
    from vid2haircut.synth.sequence import hair_occlusion, jitter_colors

    pts = np.asarray(strands.points, np.float32)
    rng = np.random.default_rng(style.seed)
    if len(pts) > style.max_strands:
        pts = pts[np.sort(rng.choice(len(pts), style.max_strands, replace=False))]
    base = np.tile(np.asarray(style.color, np.float32), (len(pts), 1))
    colors = jitter_colors(base, style.color_jitter, rng) if style.color_jitter > 0 else base
    occ = hair_occlusion(head.sdf_np(pts))
    return pts, colors, occ


def render_views(strands: StrandSet | None, head, style: TurntableStyle = TurntableStyle(),
                 camera: Camera | None = None) -> list[PhotoFrame]:
    """Render one frame per view of ``strands`` (canonical head frame, metres) on ``head``.

    Args:
        strands: the hairstyle, or None for the bald head.
        head: head model (``vertices``, ``faces``, ``landmarks``, ``sdf_np``) of the strands' frame.
        style: sizes, views and colours.
        camera: the camera (default :func:`framing_camera` of the head and these strands).

    Returns:
        one :class:`~vid2haircut.synth.photo.PhotoFrame` per ``style.views`` entry
        (``image`` (size, W, 3) uint8, ``hair`` (size, W) coverage, W <= size).
    """
    if style.size < 16:
        raise ValueError(f"turntable view size must be at least 16 pixels, got {style.size}")
    if not style.views:
        raise ValueError("turntable: no views given")
    if strands is None or strands.n_strands == 0:
        pts = colors = occ = None
    else:
        pts, colors, occ = prepare_strands(strands, head, style)
    cam = camera if camera is not None else framing_camera(head, [] if pts is None else [pts], style)
    return [render_photo(cam, head, view_pose(yaw), pts, colors, style.photo, occ) for _, yaw in style.views]


def turntable_strip(strands: StrandSet, head, gt: StrandSet | None = None,
                    style: TurntableStyle = TurntableStyle(),
                    row_names: Sequence[str] = ("reconstruction", "ground truth")) -> np.ndarray:
    """The strip image: one row of labelled views per strand set (reconstruction, then ground truth).

    Returns:
        (R * size, V * W, 3) uint8 RGB, R = 1 or 2 rows, V = len(style.views), W <= size the view
        width of :func:`framing_camera`; a 2-pixel white line separates the rows.
    """
    sets = [strands] if gt is None else [strands, gt]
    cam = framing_camera(head, [s.points for s in sets], style)
    rows = []
    for name, s in zip(row_names, sets):
        tiles = []
        for (view, _), frame in zip(style.views, render_views(s, head, style, cam)):
            tile = frame.image.copy()
            label_tile(tile, view)
            tiles.append(tile)
        label_tile(tiles[0], name, line=1)
        rows.append(np.concatenate(tiles, axis=1))
    if len(rows) == 2:
        rows[1][:2] = 255
    return np.concatenate(rows, axis=0)


def write_turntable(out: str | os.PathLike, strands_path: str | os.PathLike,
                    gt_path: str | os.PathLike | None = None, head: str | os.PathLike | None = None,
                    style: TurntableStyle = TurntableStyle()) -> Path:
    """Load strand files (any supported format), render :func:`turntable_strip` and write the PNG
    atomically.

    Args:
        out: output image path (.png).
        strands_path: reconstruction (e.g. ``results/stage2/.../strands.npz``).
        gt_path: optional ground truth (``ground_truth/strands.npz``), shown as the second row.
        head: fitted ``head.npz``, a head model name, or None for the strands' own head model
            (``proxy-v1`` when the file does not say).
    Returns:
        ``out`` as a Path.
    """
    from vid2haircut.io.strand_formats import load_strands

    pred = load_strands(strands_path)
    gt = load_strands(gt_path) if gt_path is not None else None
    head_model = load_head(head, default=pred.head_model)
    out = Path(out)
    write_image(out, turntable_strip(pred, head_model, gt, style))
    return out
