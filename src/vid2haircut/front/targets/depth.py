"""Relative depth targets: from the sequence's depth maps, by sparse triangulation, or none.

Normalisation (all sources): depth inside the hair mask is mapped by its 5% and 95% quantiles to
[0, 1] (0 = the near hair, 1 = the far hair; values outside the quantiles extend past 0 / 1):
only order and relative spacing are meaningful, as with a monocular depth network.

Sparse triangulation (no depth maps): for each pair of keyframes adjacent in time, corners
(Shi-Tomasi) inside the first frame's hair mask are tracked with pyramidal Lucas-Kanade through
the video frames between the two keyframes and back (forward-backward check, 1 px); the surviving
matches are triangulated (linear DLT, then a check of reprojection error and parallax) with the
cameras of the fitted head poses, expressed in the head frame. Each triangulated point gives a
depth sample (camera z) at its pixel in both keyframes; ``valid`` is True only at those pixels.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DepthConfig:
    """Settings of the depth targets."""

    source: str = "auto"
    """"auto" (maps, else triangulation, else none), "maps", "triangulate" or "none"."""
    quantiles: tuple[float, float] = (0.05, 0.95)
    """quantiles of the hair depth mapped to 0 and 1."""
    max_corners: int = 800
    """corners detected per keyframe for triangulation."""
    fb_threshold_px: float = 1.0
    """forward-backward tracking consistency threshold, pixels."""
    reproj_threshold_px: float = 2.0
    """maximum reprojection error of a triangulated point, pixels."""
    min_parallax_deg: float = 2.0
    """minimum angle between the two viewing rays of a triangulated point."""
    context: bool = False
    """Keep the depth maps' valid pixels outside the hair mask (the visible head) as targets too,
    in the same normalisation (the hair's quantiles), so the fit can place the hair against the
    head (:func:`vid2haircut.fit.scene.image_losses`); False: the hair only."""


def normalise_depth(depth: np.ndarray, valid: np.ndarray, mask: np.ndarray,
                    quantiles: tuple[float, float] = (0.05, 0.95),
                    context: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Quantile-normalise depth by its quantiles inside the hair mask.

    Args:
        depth: (H, W) larger = farther; valid: (H, W) bool; mask: (H, W) hair mask in [0, 1].
        context: also keep the valid pixels outside the mask (same normalisation).
    Returns:
        (depth (H, W) float32 normalised, valid (H, W) bool = valid & mask >= 0.5 & finite, or
        valid & finite with ``context``). When fewer than 2 valid hair pixels exist, depth is 0 and
        valid all False.
    """
    d = np.asarray(depth, dtype=np.float64)
    finite = np.asarray(valid, bool) & np.isfinite(d)
    ok = finite & (np.asarray(mask) >= 0.5)
    if ok.sum() < 2:
        return np.zeros(d.shape, np.float32), np.zeros(d.shape, bool)
    lo, hi = np.quantile(d[ok], quantiles)
    if hi - lo < 1e-12:
        hi = lo + 1.0
    keep = finite if context else ok
    out = np.where(keep, (d - lo) / (hi - lo), 0.0)
    return out.astype(np.float32), keep


def triangulate_dlt(p_a: np.ndarray, p_b: np.ndarray, P_a: np.ndarray, P_b: np.ndarray) -> np.ndarray:
    """Linear two-view triangulation.

    Args:
        p_a, p_b: (N, 2) pixel observations; P_a, P_b: (3, 4) projection matrices.
    Returns:
        (N, 3) points in the frame the projection matrices map from.
    """
    rows = np.stack([p_a[:, 0:1] * P_a[2] - P_a[0], p_a[:, 1:2] * P_a[2] - P_a[1],
                     p_b[:, 0:1] * P_b[2] - P_b[0], p_b[:, 1:2] * P_b[2] - P_b[1]], axis=1)  # (N, 4, 4)
    _, _, vt = np.linalg.svd(rows)
    X = vt[:, -1]
    return X[:, :3] / X[:, 3:4]


def _track(frames: list[np.ndarray], pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """LK-track (N, 2) points through grey frames -> (end points (N, 2), ok (N,) bool)."""
    import cv2

    p = pts.astype(np.float32).reshape(-1, 1, 2)
    ok = np.ones(len(pts), bool)
    for f0, f1 in zip(frames[:-1], frames[1:]):
        q, st, _ = cv2.calcOpticalFlowPyrLK(f0, f1, p, None, winSize=(15, 15), maxLevel=3,
                                            criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
        ok &= st.reshape(-1).astype(bool)
        p = q
    return p.reshape(-1, 2), ok


def triangulated_depth(seq, keyframes: list[int], world_from_head: np.ndarray, masks: dict[int, np.ndarray],
                       cfg: DepthConfig = DepthConfig()) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Sparse camera-z depth samples per keyframe by triangulating hair tracks (module docstring).

    Args:
        seq: open Sequence; keyframes: (M,) frame indices; world_from_head: (M, 4, 4) poses;
        masks: {t: (H, W) hair mask}.
    Returns:
        {t: (depth (H, W) float32 camera z in metres (0 where not valid), valid (H, W) bool)}.
    """
    import cv2

    cam = seq.camera
    h, w = cam.height, cam.width
    out = {t: (np.zeros((h, w), np.float32), np.zeros((h, w), bool)) for t in keyframes}
    order = np.argsort(keyframes)
    P = {}
    for k in order:
        cam_from_head = cam.world_2_cam @ world_from_head[k]
        P[keyframes[k]] = (cam.K @ cam_from_head[:3], cam_from_head)
    all_frames = set(seq.frame_indices)
    for ia, ib in zip(order[:-1], order[1:]):
        ta, tb = keyframes[ia], keyframes[ib]
        between = [t for t in range(ta, tb + 1) if t in all_frames]
        grey = [cv2.cvtColor(seq.read_image(t), cv2.COLOR_RGB2GRAY) for t in between]
        m = (masks[ta] >= 0.5).astype(np.uint8)
        corners = cv2.goodFeaturesToTrack(grey[0], cfg.max_corners, 0.005, 3, mask=m)
        if corners is None or len(corners) < 4:
            continue
        pa = corners.reshape(-1, 2)
        pb, ok_f = _track(grey, pa)
        pa2, ok_b = _track(grey[::-1], pb)
        ok = ok_f & ok_b & (np.linalg.norm(pa2 - pa, axis=1) < cfg.fb_threshold_px)
        if ok.sum() < 4:
            continue
        pa, pb = pa[ok].astype(np.float64), pb[ok].astype(np.float64)
        (Pa, ca), (Pb, cb) = P[ta], P[tb]
        X = triangulate_dlt(pa, pb, Pa, Pb)
        good = np.ones(len(X), bool)
        zs = []
        for Pm, c, p in ((Pa, ca, pa), (Pb, cb, pb)):
            xc = X @ c[:3, :3].T + c[:3, 3]
            z = xc[:, 2]
            uv = xc[:, :2] / np.where(np.abs(z) > 1e-9, z, 1e-9)[:, None] @ cam.K[:2, :2].T + cam.K[:2, 2]
            good &= (z > 0) & (np.linalg.norm(uv - p, axis=1) < cfg.reproj_threshold_px)
            zs.append(z)
        ca_c = -ca[:3, :3].T @ ca[:3, 3]
        cb_c = -cb[:3, :3].T @ cb[:3, 3]
        ra, rb = X - ca_c, X - cb_c
        cosang = (ra * rb).sum(1) / np.maximum(np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1), 1e-12)
        good &= np.degrees(np.arccos(np.clip(cosang, -1, 1))) >= cfg.min_parallax_deg
        for t, p, z in ((ta, pa, zs[0]), (tb, pb, zs[1])):
            d, v = out[t]
            ij = np.round(p[good]).astype(int)
            inside = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
            ij, zz = ij[inside], z[good][inside]
            keep = masks[t][ij[:, 1], ij[:, 0]] >= 0.5
            d[ij[keep, 1], ij[keep, 0]] = zz[keep]
            v[ij[keep, 1], ij[keep, 0]] = True
        log.info("depth: keyframes %d-%d: %d of %d tracks triangulated", ta, tb, int(good.sum()), len(good))
    return out


def depth_targets(seq, keyframes: list[int], world_from_head: np.ndarray, masks: dict[int, np.ndarray],
                  cfg: DepthConfig = DepthConfig()) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], str]:
    """Normalised depth targets of every keyframe and the source used.

    Returns:
        ({t: (depth (H, W) float32, valid (H, W) bool)}, source in {"maps", "triangulate", "none"}).
    """
    if cfg.source not in ("auto", "maps", "triangulate", "none"):
        raise ValueError(f"depth source must be auto|maps|triangulate|none, got {cfg.source!r}")
    h, w = seq.camera.height, seq.camera.width
    none = {t: (np.zeros((h, w), np.float32), np.zeros((h, w), bool)) for t in keyframes}
    if cfg.source == "none":
        log.info("depth: no depth target (source 'none'); the fit sets its weight to 0")
        return none, "none"
    if cfg.source in ("auto", "maps"):
        raw = {t: seq.read_depth(t) for t in keyframes}
        if all(r is not None for r in raw.values()):
            log.info("depth: from depth_maps/cam_%s", seq.serial)
            return {t: normalise_depth(raw[t][0], raw[t][1], masks[t], cfg.quantiles, cfg.context)
                    for t in keyframes}, "maps"
        if cfg.source == "maps":
            missing = [t for t, r in raw.items() if r is None]
            folder = seq.root / "depth_maps" / f"cam_{seq.serial}"
            raise FileNotFoundError(f"{folder}: no depth map for frames {missing}")
    if len(keyframes) >= 2:
        sparse = triangulated_depth(seq, keyframes, world_from_head, masks, cfg)
        if any(v.sum() >= 2 for _, v in sparse.values()):
            log.info("depth: sparse triangulation of hair tracks across keyframes")
            return {t: normalise_depth(d, v, masks[t], cfg.quantiles) for t, (d, v) in sparse.items()}, "triangulate"
    log.info("depth: no depth maps and nothing triangulated -> no depth target; the fit sets its weight to 0")
    return none, "none"
