"""Figures of the front stages: keyframe contact sheet, fitted-head overlays, orientation maps.

All functions return (H, W, 3) uint8 RGB arrays; the stage runners write them with
:func:`vid2haircut.io.atomic.write_image`.
"""

from __future__ import annotations

import numpy as np

from vid2haircut.front.targets.orientation import orientation_colour


def _label(img: np.ndarray, text: str, colour=(255, 255, 255)) -> None:
    """Write ``text`` in the top-left corner (white on a black outline), in place."""
    import cv2

    scale = max(0.4, img.shape[1] / 640.0)
    th = max(1, int(round(scale)))
    y = int(round(16 * scale / 0.4))
    cv2.putText(img, text, (4, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), th + 2, cv2.LINE_AA)
    cv2.putText(img, text, (4, y), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, th, cv2.LINE_AA)


def grid(tiles: list[np.ndarray], columns: int | None = None, tile_width: int = 256,
         labels: list[str] | None = None) -> np.ndarray:
    """Lay out RGB tiles (resized to ``tile_width`` wide, the first tile's aspect) on a grid, each
    with its optional label -> (H, W, 3) uint8."""
    import cv2

    if not tiles:
        raise ValueError("no tiles to lay out")
    h0, w0 = tiles[0].shape[:2]
    tw, th = int(tile_width), max(1, int(round(tile_width * h0 / w0)))
    cols = columns or int(np.ceil(np.sqrt(len(tiles))))
    rows = int(np.ceil(len(tiles) / cols))
    sheet = np.zeros((rows * th, cols * tw, 3), np.uint8)
    for k, t in enumerate(tiles):
        r, c = divmod(k, cols)
        tile = np.ascontiguousarray(cv2.resize(t, (tw, th), interpolation=cv2.INTER_AREA))
        if labels is not None and labels[k]:
            _label(tile, labels[k])
        sheet[r * th:(r + 1) * th, c * tw:(c + 1) * tw] = tile
    return sheet


def contact_sheet(images: list[np.ndarray], labels: list[str], highlight: int | None = None,
                  tile_width: int = 256) -> np.ndarray:
    """Keyframe contact sheet: one labelled tile per image; tile ``highlight`` framed in yellow."""
    import cv2

    tiles = []
    for k, img in enumerate(images):
        t = np.ascontiguousarray(img[..., :3]).copy()
        s = max(1, t.shape[1] // tile_width)
        if k == highlight:
            cv2.rectangle(t, (0, 0), (t.shape[1] - 1, t.shape[0] - 1), (255, 220, 0), 3 * s)
        tiles.append(t)
    return grid(tiles, tile_width=tile_width, labels=labels)


def head_overlay(image: np.ndarray, camera, world_from_head: np.ndarray, head, landmarks_2d: np.ndarray | None,
                 landmarks_head: np.ndarray, crop: bool = True) -> np.ndarray:
    """Fitted head over one frame: mesh wireframe (front-facing edges), observed landmarks (red),
    projected model landmarks (green).

    Args:
        image: (H, W, 3) uint8; camera: the Camera; world_from_head: (4, 4);
        head: object with ``vertices`` (V, 3), ``faces`` (F, 3); landmarks_2d: (68, 2) or None;
        landmarks_head: (68, 3) fitted model landmarks in the head frame.
        crop: crop to a square around the projected head (1.3x its extent).
    """
    import cv2

    out = np.ascontiguousarray(image[..., :3]).copy()
    verts = np.asarray(head.vertices, np.float64) @ world_from_head[:3, :3].T + world_from_head[:3, 3]
    uv, z = camera.project(verts)
    f = np.asarray(head.faces)
    tri = uv[f]
    # front-facing faces in image space (counter-clockwise model winding -> clockwise on screen)
    area = (tri[:, 1, 0] - tri[:, 0, 0]) * (tri[:, 2, 1] - tri[:, 0, 1]) - \
           (tri[:, 2, 0] - tri[:, 0, 0]) * (tri[:, 1, 1] - tri[:, 0, 1])
    front = (area < 0) & (z[f] > 0).all(axis=1)
    layer = out.copy()
    polys = np.round(tri[front] * 4).astype(np.int32)
    cv2.polylines(layer, list(polys), True, (90, 200, 255), 1, cv2.LINE_AA, shift=2)
    out = (0.55 * out + 0.45 * layer).astype(np.uint8)
    r = max(1, out.shape[1] // 256)
    proj = camera.project(landmarks_head @ world_from_head[:3, :3].T + world_from_head[:3, 3])[0]
    for p in proj:
        if np.isfinite(p).all():
            cv2.circle(out, tuple(np.round(p).astype(int)), r + 1, (0, 255, 0), -1, cv2.LINE_AA)
    if landmarks_2d is not None:
        for p in landmarks_2d:
            if np.isfinite(p).all():
                cv2.circle(out, tuple(np.round(p).astype(int)), r, (255, 0, 0), -1, cv2.LINE_AA)
    if crop:
        ok = np.isfinite(uv).all(axis=1) & (z > 0)
        if ok.any():
            lo, hi = uv[ok].min(axis=0), uv[ok].max(axis=0)
            c, half = (lo + hi) / 2, 0.65 * float((hi - lo).max())
            x0, y0 = np.clip(np.floor(c - half).astype(int), 0, None)
            x1 = int(min(out.shape[1], np.ceil(c[0] + half)))
            y1 = int(min(out.shape[0], np.ceil(c[1] + half)))
            if x1 - x0 > 8 and y1 - y0 > 8:
                out = np.ascontiguousarray(out[y0:y1, x0:x1])
    return out


def orientation_panel(image: np.ndarray, mask: np.ndarray, angle: np.ndarray, confidence: np.ndarray,
                      label: str = "") -> np.ndarray:
    """Side by side: image with the hair mask tinted | orientation in colour (hue = angle,
    brightness = confidence) -> (H, 2W, 3) uint8."""
    img = np.ascontiguousarray(image[..., :3]).astype(np.float32)
    m = (np.asarray(mask) >= 0.5)[..., None]
    tinted = np.where(m, 0.6 * img + 0.4 * np.array([0, 255, 0], np.float32), img).astype(np.uint8)
    col = orientation_colour(angle, np.where(m[..., 0], confidence, 0.0))
    if label:
        _label(tinted, label)
    return np.concatenate([tinted, col], axis=1)
