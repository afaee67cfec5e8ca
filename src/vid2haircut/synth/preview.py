"""Contact sheet of the hairstyle families: front and back view of each, labelled.

Uses the same photo renderer as the synthetic sequences (:mod:`.photo`), so the sheet shows what
the pipeline's input frames look like.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

import numpy as np

from vid2haircut.geometry import axis_angle_to_matrix, make_transform
from vid2haircut.io.atomic import write_image
from vid2haircut.synth.photo import PhotoStyle, render_photo
from vid2haircut.synth.sequence import hair_occlusion, jitter_colors, make_camera

log = logging.getLogger(__name__)


def _label(tile: np.ndarray, text: str) -> None:
    """Draw ``text`` in the top-left corner of an (H, W, 3) uint8 tile (in place), outlined."""
    import cv2

    scale = max(0.35, tile.shape[0] / 330.0)
    org = (int(4 + 2 * scale), int(14 * scale + 4))
    cv2.putText(tile, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), max(2, int(3 * scale)), cv2.LINE_AA)
    cv2.putText(tile, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), max(1, int(scale)), cv2.LINE_AA)


def render_views(family: str, seed: int, head, size: int, n_strands: int, n_points: int,
                 style: PhotoStyle = PhotoStyle()) -> tuple[np.ndarray, np.ndarray]:
    """Front and back view of one generated hairstyle -> two (size, size, 3) uint8 RGB images."""
    from vid2haircut.synth.hairstyles import generate_hairstyle

    hair = generate_hairstyle(family, seed, head=head, n_strands=n_strands, n_points=n_points)
    pts = np.asarray(hair.points, np.float32)
    colors = jitter_colors(np.asarray(hair.attributes["color"]), 0.10,
                           np.random.default_rng(np.random.SeedSequence([int(seed), 1729]).spawn(1)[0]))
    occ = hair_occlusion(head.sdf_np(pts))
    cam = make_camera(head, size, size, fill=0.5)
    front = make_transform(np.eye(3), np.zeros(3))
    back = make_transform(axis_angle_to_matrix(np.array([0.0, np.pi, 0.0])), np.zeros(3))
    return tuple(render_photo(cam, head, pose, pts, colors, style, occ).image.copy() for pose in (front, back))


def contact_sheet(path: str | Path, families: Sequence[str] | None = None, seed: int = 0, n_strands: int = 4000,
                  n_points: int = 64, size: int = 256, per_row: int = 5) -> Path:
    """Write a PNG contact sheet: for every family a front and a back view, labelled with its name.

    Args:
        path: output PNG.
        families: family names (default: all of ``FAMILIES``).
        seed: hairstyle seed used for every family.
        n_strands, n_points: hairstyle resolution (smaller than a sequence's, for speed).
        size: side of one view, pixels.
        per_row: families per row.
    Returns:
        The path written.
    """
    from vid2haircut.head import get_head
    from vid2haircut.synth.hairstyles import FAMILIES

    families = list(FAMILIES if families is None else families)
    if not families:
        raise ValueError("contact_sheet: no families given")
    head = get_head("proxy-v1")
    cols = max(1, min(per_row, len(families)))
    rows = -(-len(families) // cols)
    sheet = np.full((rows * size, cols * 2 * size, 3), 255, np.uint8)
    for i, fam in enumerate(families):
        log.info("contact sheet: %s", fam)
        front, back = render_views(fam, seed, head, size, n_strands, n_points)
        r, c = divmod(i, cols)
        _label(front, fam)
        _label(back, "back")
        sheet[r * size:(r + 1) * size, c * 2 * size:(c + 1) * 2 * size] = np.concatenate([front, back], axis=1)
        if c:
            sheet[r * size:(r + 1) * size, c * 2 * size:c * 2 * size + 2] = 255  # separator between families
    path = Path(path)
    write_image(path, sheet)
    return path
