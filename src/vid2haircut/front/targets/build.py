"""Per-keyframe targets (silhouette, orientation, depth) and their files.

``frame_<t:05d>.npz`` keys::

    mask        (H, W) float32 hair mask in [0, 1]
    angle       (H, W) float32 2D hair direction in [0, pi): vector (cos a, sin a) in pixel axes
                (x right, y down); see vid2haircut.front.targets.orientation
    confidence  (H, W) float32 in [0, 1], 0 outside the hair mask
    depth       (H, W) float32 relative depth, quantile-normalised inside the mask (0 near, 1 far)
    depth_valid (H, W) bool where ``depth`` is a target
    frame       () int64 frame index
    mask_source () str "hair_masks" | "fallback"

``targets.json``: {"frames": [...], "mask_source": {t: ...}, "depth_source": "maps" |
"triangulate" | "none", "serial": ..., "gabor": {...settings}}.
``orientation_<t:05d>.png``: the frame with its hair mask | orientation colour map.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from pathlib import Path
from typing import NamedTuple

import numpy as np

from vid2haircut.front.pose import HeadFit, project_landmarks, shape_axes
from vid2haircut.front.targets.depth import DepthConfig, depth_targets
from vid2haircut.front.targets.mask import MaskConfig, hair_mask_fallback
from vid2haircut.front.targets.orientation import GaborConfig, orientation_map
from vid2haircut.checks import float_array, frame_numbers

log = logging.getLogger(__name__)


class FrameTargets(NamedTuple):
    """Targets of one keyframe (arrays (H, W), see the module docstring)."""

    frame: int
    image: np.ndarray  # (H, W, 3) uint8, for the figure only
    mask: np.ndarray
    angle: np.ndarray
    confidence: np.ndarray
    depth: np.ndarray
    depth_valid: np.ndarray
    mask_source: str


def frame_landmarks(fit: HeadFit, i: int, camera, landmark_embedding: str | None = None) -> np.ndarray:
    """(68, 2) landmarks of fitted frame i: observed where finite, else the fitted projection."""
    from vid2haircut.front.headfile import base_landmarks

    obs = np.asarray(fit.landmarks_2d[i], np.float64)
    if np.isfinite(obs).all():
        return obs
    pts = base_landmarks(fit.head_model, landmark_embedding) * shape_axes(fit.shape)
    proj = project_landmarks(camera, fit.world_from_head[i:i + 1], pts)[0]
    return np.where(np.isfinite(obs), obs, proj)


def hair_mask(seq, t: int, lmk, source: str = "auto",
              cfg: MaskConfig = MaskConfig()) -> tuple[np.ndarray, str]:
    """Hair mask of frame t -> ((H, W) float32, "hair_masks" | "fallback").

    lmk: (68, 2) landmarks, or a callable returning them (only called for the fallback).
    source: "auto" (the sequence's hair_masks when present, else the fallback), "file", "fallback".
    """
    if source not in ("auto", "file", "fallback"):
        raise ValueError(f"mask source must be auto|file|fallback, got {source!r}")
    if source in ("auto", "file"):
        m = seq.read_hair_mask(t)
        if m is not None:
            return m.astype(np.float32), "hair_masks"
        if source == "file":
            raise FileNotFoundError(f"{seq.root / 'hair_masks' / f'cam_{seq.serial}'}: no hair mask for frame {t}")
    lmk = lmk() if callable(lmk) else lmk
    return hair_mask_fallback(seq.read_image(t), lmk, seq.read_alpha(t), cfg), "fallback"


def compute_targets(seq, fit: HeadFit, mask_source: str = "auto", depth_cfg: DepthConfig = DepthConfig(),
                    gabor_cfg: GaborConfig = GaborConfig(), mask_cfg: MaskConfig = MaskConfig(),
                    device: str | None = None,
                    landmark_embedding: str | None = None) -> tuple[list[FrameTargets], dict]:
    """Targets of every fitted keyframe of an open sequence.

    ``landmark_embedding`` is only needed for a FLAME head whose landmarks were not observed.

    Returns:
        (list of :class:`FrameTargets` in ``fit.frames`` order, summary dict for targets.json).
    """
    frames = [int(t) for t in fit.frames]
    masks, sources, images = {}, {}, {}
    for i, t in enumerate(frames):
        images[t] = seq.read_image(t)
        lmk = functools.partial(frame_landmarks, fit, i, seq.camera, landmark_embedding)
        masks[t], sources[t] = hair_mask(seq, t, lmk, mask_source, mask_cfg)
        if masks[t].max() < 0.5:
            log.warning("frame %d: empty hair mask (%s)", t, sources[t])
    depths, depth_src = depth_targets(seq, frames, fit.world_from_head, masks, depth_cfg)
    out = []
    for t in frames:
        om = orientation_map(images[t], masks[t], gabor_cfg, device=device)
        d, v = depths[t]
        out.append(FrameTargets(t, images[t], masks[t], om.angle, om.confidence, d, v, sources[t]))
    log.info("targets: %d keyframes, masks %s, depth %s", len(out), sorted(set(sources.values())), depth_src)
    summary = {"frames": frames, "mask_source": {str(t): s for t, s in sources.items()},
               "depth_source": depth_src, "serial": seq.serial, "gabor": dataclasses.asdict(gabor_cfg)}
    return out, summary


def write_targets(out_dir: str | Path, targets: list[FrameTargets], summary: dict) -> None:
    """Write ``frame_<t>.npz``, ``orientation_<t>.png`` and ``targets.json`` atomically."""
    from vid2haircut.front.figures import orientation_panel
    from vid2haircut.io.atomic import check_outputs, write_image, write_json, write_npz

    out = Path(out_dir)
    check_outputs([out / "targets.json"] + [out / f"{kind}_{ft.frame:05d}.{ext}" for ft in targets
                                            for kind, ext in (("frame", "npz"), ("orientation", "png"))])
    for ft in targets:
        write_npz(out / f"frame_{ft.frame:05d}.npz", mask=ft.mask.astype(np.float32),
                  angle=ft.angle.astype(np.float32), confidence=ft.confidence.astype(np.float32),
                  depth=ft.depth.astype(np.float32), depth_valid=ft.depth_valid.astype(bool),
                  frame=np.int64(ft.frame), mask_source=np.array(ft.mask_source))
        write_image(out / f"orientation_{ft.frame:05d}.png",
                    orientation_panel(ft.image, ft.mask, ft.angle, ft.confidence, f"t={ft.frame}"))
    write_json(out / "targets.json", summary)


def load_targets(path: str | Path) -> dict[str, np.ndarray]:
    """Read one ``frame_<t>.npz`` -> dict of arrays; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: targets file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except Exception as e:
        raise ValueError(f"{path}: not a readable .npz file ({type(e).__name__}: {e})") from None
    missing = [k for k in ("mask", "angle", "confidence", "depth", "depth_valid", "frame") if k not in d]
    if missing:
        raise ValueError(f"{path}: missing key(s) {missing}")
    mask = float_array(d["mask"], path, "mask", (None, None), dtype=np.float32)
    hw = mask.shape
    if mask.size and not (mask.min() >= 0.0 and mask.max() <= 1.0):
        raise ValueError(f"{path}: 'mask' must lie in [0, 1], got {mask.min():.3g}..{mask.max():.3g}")
    d["mask"] = mask
    for k in ("angle", "confidence"):
        d[k] = float_array(d[k], path, k, hw, dtype=np.float32)
    d["depth_valid"] = float_array(d["depth_valid"], path, "depth_valid", hw, finite=False) != 0
    d["depth"] = float_array(d["depth"], path, "depth", hw, finite=False, dtype=np.float32)
    if not np.isfinite(d["depth"][d["depth_valid"]]).all():
        raise ValueError(f"{path}: 'depth' has non-finite entries where 'depth_valid' is set")
    frame = frame_numbers(np.asarray(d["frame"]).reshape(-1), path, "frame")
    if frame.shape != (1,):
        raise ValueError(f"{path}: 'frame' must be one frame number, got {frame.tolist()}")
    if path.stem.startswith("frame_") and path.stem[6:].isdigit() and int(path.stem[6:]) != frame[0]:
        raise ValueError(f"{path}: 'frame' is {frame[0]}, not the frame of the file name")
    return d
