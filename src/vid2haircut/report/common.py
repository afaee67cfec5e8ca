"""Small helpers shared by the report figures: tile labels, matplotlib figures to RGB arrays,
head models from a name or a fitted ``head.npz``."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def label_tile(tile: np.ndarray, text: str, line: int = 0) -> None:
    """Write ``text`` (white, black outline) on line ``line`` of the top-left corner of an
    (H, W, 3) uint8 RGB tile, in place. The font scales with the tile width."""
    import cv2

    scale = max(0.4, tile.shape[1] / 560.0)
    thick = max(1, int(round(scale)))
    step = int(round(26 * scale / 0.6))
    org = (int(4 + 2 * scale), int(round(20 * scale / 0.6)) + line * step)
    cv2.putText(tile, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
    cv2.putText(tile, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick, cv2.LINE_AA)


def figure_rgb(fig) -> np.ndarray:
    """Rasterise a ``matplotlib.figure.Figure`` (no pyplot state) -> (H, W, 3) uint8 RGB."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def trim_white(img: np.ndarray, margin: int = 8) -> np.ndarray:
    """Crop the uniform white border of an (H, W, 3) uint8 image, keeping ``margin`` pixels."""
    ink = (img < 250).any(-1)
    if not ink.any():
        return img
    rows, cols = np.flatnonzero(ink.any(1)), np.flatnonzero(ink.any(0))
    r0, r1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, img.shape[0])
    c0, c1 = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, img.shape[1])
    return np.ascontiguousarray(img[r0:r1, c0:c1])


def load_head(spec: str | os.PathLike | None, default: str | None = None):
    """Head model from ``spec``: a fitted ``head.npz`` (its model and shape factors), a built-in
    name (``"proxy-v1"``) or a FLAME ``.pkl`` path; None uses ``default`` (else ``"proxy-v1"``)."""
    from vid2haircut.front.headfile import load_head_fit, resolve_head

    if spec is None:
        return resolve_head(default or "proxy-v1")
    spec = str(spec)
    if spec.endswith(".npz"):
        fit, meta = load_head_fit(Path(spec))
        return resolve_head(fit.head_model, fit.shape, meta["landmark_embedding"])
    return resolve_head(spec)
