"""Hair silhouette targets: the sequence's hair masks, or a GrabCut fallback.

Fallback (for real head-and-shoulders video without hair masks), per frame:
1. foreground F: the alpha matte (>= 0.5) when the sequence has one; otherwise GrabCut
   initialised with a head-and-shoulders rectangle built from the landmarks;
2. face: the polygon of the jaw contour closed over the brows; neck: below the jaw contour
   inside its x extent -> both definite non-hair (and the samples of the non-hair colours);
3. seed: F above the chin, at least ``seed_border`` inside F and ``seed_face_gap`` away from the
   face and from the forehead band (``forehead`` face heights above the brows) -> definite hair
   (the samples of the hair colours);
4. candidates -> probable hair: the rest of F; below the chin only the columns the seed reaches
   (hair hanging down), so the body elsewhere is dropped;
5. GrabCut (colour GMMs + contrast-sensitive smoothness) refines the labels; it only sees F:
   pixels outside F are painted with the median non-hair colour, so its background model
   describes skin and body rather than the scenery;
6. the result is cleaned by a small morphological opening and restricted to the connected
   components reaching above the brows.
Output: (H, W) float32 mask in {0, 1}. Deterministic (OpenCV's RNG is seeded).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

JAW = list(range(0, 17))
BROWS = list(range(17, 27))


@dataclass(frozen=True)
class MaskConfig:
    """Settings of the GrabCut hair-mask fallback."""

    forehead: float = 0.45
    """height of the forehead band above the brows, in face heights (brow-to-chin)."""
    head_top: float = 1.1
    """how far above the brows the head may reach, in face heights (foreground rectangle)."""
    head_width: float = 2.2
    """width of the foreground rectangle, in face widths."""
    seed_border: float = 0.04
    """definite-hair seed: at least this far (face widths) inside the foreground ..."""
    seed_face_gap: float = 0.12
    """... and at least this far (face widths) from the face and forehead."""
    below_chin: float = 1.0
    """how far below the chin the foreground rectangle reaches, in face heights."""
    iterations: int = 5
    """GrabCut iterations."""
    seed: int = 0
    """seed of OpenCV's RNG (GrabCut's k-means initialisation)."""


def _face_geometry(lmk: np.ndarray) -> tuple[np.ndarray, float, float, float]:
    """-> (face polygon (K, 2), face width, face height, brow y)."""
    jaw = lmk[JAW]
    brows = lmk[BROWS]
    brow_y = float(np.median(brows[:, 1]))
    chin_y = float(jaw[:, 1].max())
    height = max(chin_y - brow_y, 1.0)
    width = max(float(np.ptp(lmk[:, 0])), 1.0)
    top = brows[np.argsort(brows[:, 0])[::-1]]  # right -> left so the polygon closes over the brows
    poly = np.concatenate([jaw, top])
    return poly, width, height, brow_y


def _poly_mask(poly: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    import cv2

    m = np.zeros(shape, np.uint8)
    hull = cv2.convexHull(np.round(poly).astype(np.int32))
    cv2.fillConvexPoly(m, hull, 1)
    return m.astype(bool)


def _grabcut(image: np.ndarray, labels: np.ndarray, cfg: MaskConfig) -> np.ndarray:
    """Run GrabCut from a label map (cv2.GC_* values) -> (H, W) bool foreground."""
    import cv2

    h, w = labels.shape
    out = np.zeros((h, w), bool)
    fg_lab = (labels == cv2.GC_PR_FGD) | (labels == cv2.GC_FGD)
    if not fg_lab.any() or fg_lab.all():
        return fg_lab
    # work on the bounding box of the undecided labels plus a margin of definite background
    ys, xs = np.nonzero(labels != cv2.GC_BGD)
    pad = max(8, int(0.15 * max(np.ptp(ys), np.ptp(xs))))
    y0, y1 = max(0, ys.min() - pad), min(h, ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(w, xs.max() + pad + 1)
    lab = np.ascontiguousarray(labels[y0:y1, x0:x1], dtype=np.uint8)
    if not ((lab == cv2.GC_BGD) | (lab == cv2.GC_PR_BGD)).any():
        return fg_lab
    cv2.setRNGSeed(cfg.seed)
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    bgr = np.ascontiguousarray(image[y0:y1, x0:x1, ::-1])
    cv2.grabCut(bgr, lab, None, bgd, fgd, cfg.iterations, cv2.GC_INIT_WITH_MASK)
    out[y0:y1, x0:x1] = (lab == cv2.GC_FGD) | (lab == cv2.GC_PR_FGD)
    return out


def foreground_from_landmarks(image: np.ndarray, lmk: np.ndarray, cfg: MaskConfig = MaskConfig()) -> np.ndarray:
    """GrabCut foreground (person) from a head-and-shoulders rectangle around the landmarks.

    Args:
        image: (H, W, 3) uint8 RGB; lmk: (68, 2) pixels.
    Returns:
        (H, W) bool.
    """
    import cv2

    h, w = image.shape[:2]
    _, fw, fh, brow_y = _face_geometry(lmk)
    cx = float(np.mean(lmk[:, 0]))
    x0 = int(np.clip(cx - 0.5 * cfg.head_width * fw, 1, w - 2))
    x1 = int(np.clip(cx + 0.5 * cfg.head_width * fw, x0 + 1, w - 1))
    y0 = int(np.clip(brow_y - cfg.head_top * fh, 1, h - 2))
    labels = np.full((h, w), cv2.GC_BGD, np.uint8)
    chin_y = float(lmk[JAW, 1].max())
    y1 = int(np.clip(chin_y + cfg.below_chin * fh, y0 + 1, h))
    labels[y0:y1, x0:x1] = cv2.GC_PR_FGD
    face = _poly_mask(_face_geometry(lmk)[0], (h, w))
    labels[face] = cv2.GC_FGD
    return _grabcut(image, labels, cfg)


def hair_mask_fallback(image: np.ndarray, lmk: np.ndarray, alpha: np.ndarray | None = None,
                       cfg: MaskConfig = MaskConfig()) -> np.ndarray:
    """Hair mask of one frame without a hair segmentation (see the module docstring).

    Args:
        image: (H, W, 3) uint8 RGB.
        lmk: (68, 2) iBUG landmarks in pixels.
        alpha: optional (H, W) float foreground matte in [0, 1].
    Returns:
        (H, W) float32 in {0, 1}.
    """
    import cv2

    image = np.asarray(image)
    h, w = image.shape[:2]
    lmk = np.asarray(lmk, dtype=np.float64)
    if lmk.shape != (68, 2) or not np.isfinite(lmk).all():
        raise ValueError(f"hair mask fallback needs (68, 2) finite landmarks, got {lmk.shape}")
    if alpha is not None:
        if alpha.shape != (h, w):
            raise ValueError(f"alpha shape {alpha.shape} does not match image shape {(h, w)}")
        fg = np.asarray(alpha) >= 0.5
    else:
        fg = foreground_from_landmarks(image, lmk, cfg)
    poly, fw, fh, brow_y = _face_geometry(lmk)
    face = _poly_mask(poly, (h, w))
    yy = np.mgrid[0:h, 0:w][0]
    # forehead band: the brows' x extent, from the brows up by `forehead` face heights
    top_pts = poly[len(JAW):].copy()
    forehead = _poly_mask(np.concatenate([top_pts, top_pts[::-1] - [0.0, cfg.forehead * fh]]), (h, w))
    # jaw line over the jaw's x extent; the neck is below it
    jaw = lmk[JAW]
    order = np.argsort(jaw[:, 0])
    jaw_y = np.interp(np.arange(w), jaw[order, 0], jaw[order, 1], left=np.inf, right=np.inf)
    neck = yy > jaw_y[None, :]
    chin_y = float(jaw[:, 1].max())
    below_chin = yy > chin_y

    def disk(radius: float) -> np.ndarray:
        r = max(1, int(round(radius)))
        return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))

    # seed: foreground above the chin, away from its border and away from the face -> hair
    inner = cv2.erode(fg.astype(np.uint8), disk(cfg.seed_border * fw)).astype(bool)
    near_face = cv2.dilate((face | forehead).astype(np.uint8), disk(cfg.seed_face_gap * fw)).astype(bool)
    seed = inner & ~near_face & ~below_chin & ~neck
    nonhair = fg & (face | neck)
    if not seed.any():
        return np.zeros((h, w), np.float32)
    # candidates: the rest of F; below the chin only in the columns the seed hair reaches
    widen = np.ones((1, 2 * max(1, int(0.05 * fw)) + 1), np.uint8)
    cols = cv2.dilate(seed.any(axis=0).astype(np.uint8)[None], widen)[0] > 0
    cand = fg & ~seed & ~face & ~neck & (~below_chin | cols[None, :])
    labels = np.full((h, w), cv2.GC_BGD, np.uint8)
    labels[cand] = cv2.GC_PR_FGD
    labels[seed] = cv2.GC_FGD
    # GrabCut only sees F: outside it paint the face colour, so its background model describes
    # skin and body rather than the scenery (a dark backdrop would otherwise explain dark hair)
    painted = image.copy()
    painted[~fg] = np.median(image[nonhair], axis=0) if nonhair.any() else 0
    hair = _grabcut(painted, labels, cfg) & fg & ~face & ~neck

    hair = cv2.morphologyEx(hair.astype(np.uint8), cv2.MORPH_OPEN, disk(0.02 * fw)).astype(bool)
    # keep the components that reach above the brows (hair grows from the scalp)
    n, comp = cv2.connectedComponents(hair.astype(np.uint8), connectivity=8)
    if n > 1:
        keep = np.unique(comp[(yy < brow_y) & hair])
        hair = np.isin(comp, keep[keep > 0])
    return hair.astype(np.float32)


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two (H, W) masks thresholded at 0.5 (1.0 when both are empty)."""
    a, b = np.asarray(a) >= 0.5, np.asarray(b) >= 0.5
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0
