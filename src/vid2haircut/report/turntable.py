"""Turntable strip of a hairstyle: front, 3/4, side and back views of the strands on the head,
shaded with the photo-like renderer of the synthetic data (:func:`vid2haircut.synth.photo.render_photo`),
optionally with the ground truth as a second row rendered identically.

The head is turned in front of a fixed camera on the +z axis (the canonical face direction):
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

from vid2haircut.geometry import axis_angle_to_matrix, make_transform
from vid2haircut.io.atomic import write_image
from vid2haircut.report.common import label_tile, load_head
from vid2haircut.strands import StrandSet
from vid2haircut.synth.photo import PhotoFrame, PhotoStyle, render_photo

__all__ = ["VIEWS", "TurntableStyle", "view_pose", "prepare_strands", "render_views", "turntable_strip",
           "write_turntable"]

#: (label, yaw in degrees) of the default views.
VIEWS: tuple[tuple[str, float], ...] = (("front", 0.0), ("3/4", 45.0), ("side", 90.0), ("back", 180.0))


@dataclass(frozen=True)
class TurntableStyle:
    """Look of a turntable strip."""

    size: int = 256
    """Side of one square view, pixels."""
    fill: float = 0.55
    """Fraction of the image height taken by the head mesh's vertical extent."""
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


def render_views(strands: StrandSet | None, head, style: TurntableStyle = TurntableStyle()) -> list[PhotoFrame]:
    """Render one frame per view of ``strands`` (canonical head frame, metres) on ``head``.

    Args:
        strands: the hairstyle, or None for the bald head.
        head: head model (``vertices``, ``faces``, ``landmarks``, ``sdf_np``) of the strands' frame.
        style: sizes, views and colours.

    Returns:
        one :class:`~vid2haircut.synth.photo.PhotoFrame` per ``style.views`` entry
        (``image`` (size, size, 3) uint8, ``hair`` (size, size) coverage).
    """
    from vid2haircut.synth.sequence import make_camera

    if style.size < 16:
        raise ValueError(f"turntable view size must be at least 16 pixels, got {style.size}")
    if not style.views:
        raise ValueError("turntable: no views given")
    cam = make_camera(head, style.size, style.size, fill=style.fill)
    if strands is None or strands.n_strands == 0:
        pts = colors = occ = None
    else:
        pts, colors, occ = prepare_strands(strands, head, style)
    return [render_photo(cam, head, view_pose(yaw), pts, colors, style.photo, occ) for _, yaw in style.views]


def turntable_strip(strands: StrandSet, head, gt: StrandSet | None = None,
                    style: TurntableStyle = TurntableStyle(),
                    row_names: Sequence[str] = ("reconstruction", "ground truth")) -> np.ndarray:
    """The strip image: one row of labelled views per strand set (reconstruction, then ground truth).

    Returns:
        (R * size, V * size, 3) uint8 RGB, R = 1 or 2 rows, V = len(style.views); a 2-pixel white
        line separates the rows.
    """
    rows = []
    for name, s in zip(row_names, [strands] if gt is None else [strands, gt]):
        tiles = []
        for (view, _), frame in zip(style.views, render_views(s, head, style)):
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
