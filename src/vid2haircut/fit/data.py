"""Fitting inputs of one sequence as typed tensors: keyframes, head poses, targets, cameras.

Reads the front-stage files (``keyframes.json``, ``head.npz``, ``targets/frame_<t:05d>.npz``, see
:mod:`vid2haircut.front`) and the subject's calibration, and downsamples the targets to the fitting
resolution:

- mask, confidence: area average;
- direction: the confidence-weighted average of the doubled-angle vectors (cos 2a, sin 2a), the
  confidence multiplied by the length of that average (its coherence);
- depth: average over valid pixels; valid where at least half of the pixel was valid.

Keyframes are ordered reference first; when fewer than all are used, the others are picked by
farthest-point sampling in (yaw, pitch) from ``keyframes.json`` scores (file order without them).
Cameras are expressed per keyframe as ``cam_from_head = world_2_cam @ world_from_head`` so that
canonical (head-frame) strands are rendered directly.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

if TYPE_CHECKING:
    from vid2haircut.camera import Camera

__all__ = ["FitData", "load_fit_data", "load_fit_camera", "downsample_targets", "scale_intrinsics", "order_keyframes", "make_fit_data"]


@dataclass
class FitData:
    """Everything the fitting stages need about one sequence (M keyframes, fitting size H x W).

    Attributes:
        frames: (M,) keyframe indices, the reference first.
        K: (M,3,3) float32 intrinsics at the fitting resolution.
        cam_from_head: (M,4,4) float32 extrinsics of the canonical head frame (OpenCV camera).
        width, height: fitting image size.
        mask: (M,H,W) float32 target hair silhouette in [0,1].
        direction: (M,H,W,2) float32 target doubled-angle direction (cos 2a, sin 2a).
        confidence: (M,H,W) float32 orientation confidence in [0,1] (0 off the hair).
        depth: (M,H,W) float32 relative target depth (0 near, 1 far).
        depth_valid: (M,H,W) bool.
        head_depth: (M,H,W) float32 camera z of the head surface (+inf off the head) or None.
        head: the fitted head model (canonical frame of the output strands).
        head_model: name (or file) of the head model.
        world_from_head: (M,4,4) float64 head poses.
        reference_targets: full-resolution numpy targets of the reference keyframe (prior input).
        reference_camera: (K (3,3), world_2_cam (4,4)) full-resolution camera of the reference.
        outside: (M,H,W) float32 distance, in fitting pixels, from each pixel centre to the target
            hair silhouette (0 on it; from the full-resolution mask), or None.
    """

    frames: list[int]
    K: torch.Tensor
    cam_from_head: torch.Tensor
    width: int
    height: int
    mask: torch.Tensor
    direction: torch.Tensor
    confidence: torch.Tensor
    depth: torch.Tensor
    depth_valid: torch.Tensor
    head_depth: torch.Tensor | None
    head: Any
    head_model: str
    world_from_head: np.ndarray
    reference_targets: dict[str, np.ndarray] | None = None
    reference_camera: tuple[np.ndarray, np.ndarray] | None = None
    outside: torch.Tensor | None = None

    @property
    def n_frames(self) -> int:
        """Number of keyframes M."""
        return len(self.frames)

    def subset(self, index: list[int]) -> "FitData":
        """The keyframes ``index`` (positions into ``frames``; keep the reference first)."""
        ix = torch.as_tensor(index, dtype=torch.long)
        pick = (lambda t: None if t is None else t[ix.to(t.device)])
        return FitData([self.frames[i] for i in index], pick(self.K), pick(self.cam_from_head), self.width,
                       self.height, pick(self.mask), pick(self.direction), pick(self.confidence), pick(self.depth),
                       pick(self.depth_valid), pick(self.head_depth), self.head, self.head_model,
                       self.world_from_head[np.asarray(index)], self.reference_targets, self.reference_camera,
                       pick(self.outside))

    def to(self, device: torch.device | str) -> "FitData":
        """The data on another device."""
        mv = (lambda t: None if t is None else t.to(device))
        return FitData(self.frames, mv(self.K), mv(self.cam_from_head), self.width, self.height, mv(self.mask),
                       mv(self.direction), mv(self.confidence), mv(self.depth), mv(self.depth_valid),
                       mv(self.head_depth), self.head, self.head_model, self.world_from_head,
                       self.reference_targets, self.reference_camera, mv(self.outside))


def scale_intrinsics(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """(3,3) intrinsics of an image resized by (sx, sy), pixel centres at integer coordinates."""
    out = np.array(K, np.float64, copy=True)
    out[0, 0] *= sx
    out[0, 1] *= sx
    out[0, 2] = (out[0, 2] + 0.5) * sx - 0.5
    out[1, 1] *= sy
    out[1, 2] = (out[1, 2] + 0.5) * sy - 0.5
    return out


def downsample_targets(t: dict[str, np.ndarray], width: int, height: int) -> dict[str, np.ndarray]:
    """Targets of one frame (full-resolution ``mask``, ``angle``, ``confidence``, ``depth``,
    ``depth_valid`` (H0,W0)) -> ``mask``, ``direction`` (H,W,2), ``confidence``, ``depth``,
    ``depth_valid`` at (height, width) (see the module docstring), and ``outside`` (H,W): the distance,
    in output pixels, from each output pixel to the nearest full-resolution mask pixel (> 0.5), 0 on
    the mask (the silhouette term's distance field, :func:`vid2haircut.fit.image_terms.outside_loss`)."""
    import cv2

    def area(a: np.ndarray) -> np.ndarray:
        return cv2.resize(np.ascontiguousarray(a, np.float32), (width, height), interpolation=cv2.INTER_AREA)

    mask = np.clip(np.asarray(t["mask"], np.float32), 0.0, 1.0)
    conf = np.clip(np.asarray(t["confidence"], np.float32), 0.0, 1.0) * (mask > 0.5)
    ang = np.asarray(t["angle"], np.float64)
    w = conf.astype(np.float64) + 1e-6 * (mask > 0.5)
    cx, sx = area(w * np.cos(2 * ang)), area(w * np.sin(2 * ang))
    wsum = area(w)
    norm = np.sqrt(cx * cx + sx * sx)
    direction = np.stack([np.where(norm > 0, cx / np.maximum(norm, 1e-12), 1.0),
                          np.where(norm > 0, sx / np.maximum(norm, 1e-12), 0.0)], -1).astype(np.float32)
    coherence = np.where(wsum > 0, norm / np.maximum(wsum, 1e-12), 0.0)
    valid = np.asarray(t["depth_valid"], bool)
    vfrac = area(valid.astype(np.float32))
    dsum = area(np.where(valid, np.asarray(t["depth"], np.float32), 0.0))
    mask_lo = area(mask)
    off = (mask <= 0.5).astype(np.uint8)
    # an empty mask says nothing about where hair may not be: no distance field then
    dist = cv2.distanceTransform(off, cv2.DIST_L2, 5) if not off.all() else np.zeros(off.shape, np.float32)
    outside = area(dist) * (0.5 * (width / mask.shape[1] + height / mask.shape[0]))
    return {"mask": mask_lo, "direction": direction, "outside": outside.astype(np.float32),
            "confidence": (area(conf) * coherence * (mask_lo > 0.5)).astype(np.float32),
            "depth": np.where(vfrac > 0, dsum / np.maximum(vfrac, 1e-12), 0.0).astype(np.float32),
            "depth_valid": vfrac >= 0.5}


def order_keyframes(frames: list[int], reference: int, scores: dict[int, dict], n: int | None = None) -> list[int]:
    """Keyframes with the reference first, then farthest-point order in (yaw, pitch) degrees.

    Args:
        frames: keyframe indices; reference: one of them; scores: ``{t: {"yaw_deg", "pitch_deg"}}``
            (may be empty: then file order); n: how many to keep (None = all).
    """
    others = [t for t in frames if t != reference]
    have = all(t in scores and "yaw_deg" in scores[t] for t in frames)
    out = [reference]
    if have:
        pos = {t: np.array([scores[t]["yaw_deg"], scores[t].get("pitch_deg", 0.0)], np.float64) for t in frames}
        while others:
            d = [min(np.linalg.norm(pos[t] - pos[s]) for s in out) for t in others]
            out.append(others.pop(int(np.argmax(d))))
    else:
        out += others
    if n is not None:
        if n < 1:
            raise ValueError(f"n_keyframes must be >= 1, got {n}")
        out = out[:n]
    return out


def make_fit_data(frames: list[int], targets: list[dict[str, np.ndarray]], K: np.ndarray, world_2_cam: np.ndarray,
                  world_from_head: np.ndarray, head: Any, head_model: str, size: int,
                  occlude_head: bool = True, device: str | torch.device = "cpu") -> FitData:
    """Build :class:`FitData` from full-resolution numpy targets (reference = ``frames[0]``).

    Args:
        frames: (M,) keyframe indices; targets: M dicts of (H0,W0) arrays (``mask``, ``angle``,
            ``confidence``, ``depth``, ``depth_valid``); K: (3,3) and world_2_cam: (4,4) of the
            camera; world_from_head: (M,4,4) head poses; head: head model; size: longer side of
            the fitting resolution; occlude_head: render the head depth occluder.
    """
    from vid2haircut.render import mesh_depth

    h0, w0 = np.asarray(targets[0]["mask"]).shape
    s = float(size) / max(h0, w0)
    width, height = max(1, int(round(w0 * s))), max(1, int(round(h0 * s)))
    Ks = scale_intrinsics(K, width / w0, height / h0)
    lo = [downsample_targets(t, width, height) for t in targets]
    stack = (lambda k, dt=torch.float32: torch.as_tensor(np.stack([d[k] for d in lo]), dtype=dt, device=device))
    cfh = np.stack([np.asarray(world_2_cam, np.float64) @ np.asarray(p, np.float64) for p in world_from_head])
    K_t = torch.as_tensor(np.repeat(Ks[None], len(frames), 0), dtype=torch.float32, device=device)
    cfh_t = torch.as_tensor(cfh, dtype=torch.float32, device=device)
    head_depth = None
    if occlude_head:
        verts = torch.as_tensor(np.asarray(head.vertices, np.float32), device=device)
        faces = torch.as_tensor(np.asarray(head.faces, np.int64), device=device)
        head_depth = mesh_depth(verts[None].expand(len(frames), -1, -1), faces, K_t, cfh_t, width, height)
    ref = {k: np.asarray(targets[0][k]) for k in ("mask", "angle", "confidence", "depth", "depth_valid")}
    return FitData(list(frames), K_t, cfh_t, width, height, stack("mask"), stack("direction"), stack("confidence"),
                   stack("depth"), stack("depth_valid", torch.bool), head_depth, head, head_model,
                   np.asarray(world_from_head, np.float64), ref,
                   (np.asarray(K, np.float64), np.asarray(world_2_cam, np.float64)), stack("outside"))


def load_fit_camera(dataset_root: str | Path, subject: str, serial: str) -> Camera:
    """The calibrated camera ``serial`` of ``<subject>/calibration/camera_params.json``.

    Raises:
        ValueError naming the calibration file when it has no such camera.
    """
    from vid2haircut.camera import load_cameras
    from vid2haircut.io.sequence import calibration_path

    calib = calibration_path(dataset_root, subject)
    cams = load_cameras(calib)
    if str(serial) not in cams:
        raise ValueError(f"{calib}: camera serial '{serial}' not in the calibration (has {sorted(cams)})")
    return cams[str(serial)]


def load_fit_data(dataset_root: str | Path, subject: str, keyframes_json: str | Path, head_npz: str | Path,
                  targets_dir: str | Path, size: int = 160, n_keyframes: int | None = None,
                  serial: str | None = None, occlude_head: bool = True,
                  device: str | torch.device = "cpu") -> FitData:
    """Load one sequence's keyframes, head fit, targets and camera into :class:`FitData`.

    Args:
        dataset_root, subject: where ``<subject>/calibration/camera_params.json`` lives.
        keyframes_json: the keyframes stage's file; head_npz: the fit_head stage's file;
        targets_dir: folder of ``frame_<t:05d>.npz``.
        size: fitting resolution (longer side, px).
        n_keyframes: keyframes to use (None = all fitted ones).
        serial: camera serial (default: the one recorded in head.npz, else keyframes.json).
        occlude_head, device: see :func:`make_fit_data`.

    Raises:
        FileNotFoundError / ValueError naming the file that is missing or wrong.
    """
    from vid2haircut.front.headfile import load_head_fit, resolve_head
    from vid2haircut.front.keyframes import load_keyframes
    from vid2haircut.front.targets.build import load_targets
    from vid2haircut.io.sequence import calibration_path

    sel = load_keyframes(keyframes_json)
    fit, extra = load_head_fit(head_npz)
    fitted = [int(t) for t in fit.frames]
    if sel.reference not in fitted:
        raise ValueError(f"{head_npz}: the reference keyframe {sel.reference} of {keyframes_json} has no head pose "
                         f"(fitted frames {fitted})")
    order = order_keyframes([t for t in sel.frames if t in fitted], sel.reference, sel.scores, n_keyframes)
    cam = load_fit_camera(dataset_root, subject, str(serial or extra.get("serial") or sel.serial))
    targets = []
    for t in order:
        path = Path(targets_dir) / f"frame_{t:05d}.npz"
        d = load_targets(path)
        if np.asarray(d["mask"]).shape != (cam.height, cam.width):
            raise ValueError(f"{path}: target size {np.asarray(d['mask']).shape[::-1]} does not match the camera "
                             f"({cam.width}x{cam.height}) of {calibration_path(dataset_root, subject)}")
        targets.append(d)
    head = resolve_head(fit.head_model, fit.shape)
    poses = np.stack([fit.world_from_head[fitted.index(t)] for t in order])
    return make_fit_data(order, targets, cam.K, cam.world_2_cam, poses, head, fit.head_model, size, occlude_head,
                         device)
