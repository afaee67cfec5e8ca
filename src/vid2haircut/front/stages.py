"""The three front stages as functions: read a sequence, write the stage's artifacts atomically.

- :func:`run_keyframes` -> ``<out>/keyframes.json`` + ``<out>/keyframes.png`` (contact sheet)
- :func:`run_fit_head`  -> ``<out>/head.npz`` + ``<out>/head_overlay.png``
- :func:`run_targets`   -> ``<out>/frame_<t:05d>.npz`` + ``<out>/orientation_<t:05d>.png`` per
  keyframe, and ``<out>/targets.json`` (which sources were used)

File formats: :mod:`vid2haircut.front.keyframes` (keyframes.json),
:mod:`vid2haircut.front.headfile` (head.npz), :mod:`vid2haircut.front.targets.build` (targets).
"""

from __future__ import annotations

import logging
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from vid2haircut.front.keyframes import KeyframeConfig, KeyframeSelection, load_keyframes, select_keyframes
from vid2haircut.front.pose import HeadFit, PoseFitConfig, fit_head_poses, shape_axes
from vid2haircut.io.atomic import check_outputs, write_image, write_json

log = logging.getLogger(__name__)


def _open(dataset_root, subject, sequence, serial):
    from vid2haircut.io.sequence import open_sequence

    return open_sequence(dataset_root, subject, sequence, serial)


def run_keyframes(dataset_root: str | Path, subject: str, sequence: str, out_dir: str | Path,
                  serial: str | None = None, head_model: str = "proxy-v1",
                  cfg: KeyframeConfig = KeyframeConfig(), landmark_embedding: str | None = None) -> KeyframeSelection:
    """Select keyframes of one sequence; write ``keyframes.json`` and ``keyframes.png``.

    ``head_model``: built-in name or FLAME ``.pkl`` (then ``landmark_embedding`` is needed)."""
    from vid2haircut.front.figures import contact_sheet
    from vid2haircut.front.headfile import base_landmarks

    out = Path(out_dir)
    check_outputs([out / "keyframes.png", out / "keyframes.json"])
    seq = _open(dataset_root, subject, sequence, serial)
    try:
        sel = select_keyframes(seq, base_landmarks(head_model, landmark_embedding), cfg)
        imgs = [seq.read_image(t) for t in sel.frames]
    finally:
        seq.close()
    labels = [f"t={t} yaw={sel.scores[t]['yaw_deg']:+.0f} pitch={sel.scores[t]['pitch_deg']:+.0f}"
              + (" REF" if t == sel.reference else "") for t in sel.frames]
    sheet = contact_sheet(imgs, labels, highlight=sel.frames.index(sel.reference))
    write_image(out / "keyframes.png", sheet)
    write_json(out / "keyframes.json", sel.to_json())
    return sel


def _fit_from_tracking(seq, frames: list[int], head_model: str, points: np.ndarray, lmk) -> HeadFit:
    from vid2haircut.geometry import axis_angle_to_matrix, make_transform
    from vid2haircut.front.pose import project_landmarks

    tr = seq.tracking()
    if tr is None:
        raise FileNotFoundError(f"{seq.root / 'tracking' / 'head_tracking.npz'}: tracking file not found "
                                "(use_tracking is set)")
    idx = []
    for t in frames:
        hit = np.flatnonzero(tr["frames"] == t)
        if hit.size == 0:
            raise ValueError(f"{seq.root / 'tracking' / 'head_tracking.npz'}: no pose for keyframe {t}")
        idx.append(int(hit[0]))
    poses = make_transform(axis_angle_to_matrix(tr["rotation"][idx]), tr["translation"][idx])
    scale = float(tr["scale"][0]) if len(tr["scale"]) else 1.0
    shape = np.array([scale, 1.0, 1.0])
    l2d = lmk.lmk68.astype(np.float32) if lmk is not None else np.full((len(frames), 68, 2), np.nan, np.float32)
    proj = project_landmarks(seq.camera, poses, points * shape_axes(shape))
    err = np.linalg.norm(proj - l2d, axis=-1)
    inl = np.isfinite(err)
    rep = np.array([float(e[k].mean()) if k.any() else np.nan for e, k in zip(err, inl)])
    return HeadFit(head_model, shape, np.asarray(frames, np.int64), poses, rep, inl, l2d)


def run_fit_head(dataset_root: str | Path, subject: str, sequence: str, keyframes_json: str | Path,
                 out_dir: str | Path, serial: str | None = None, head_model: str = "proxy-v1",
                 use_tracking: bool = False, landmark_source: str = "auto",
                 cfg: PoseFitConfig = PoseFitConfig(), min_frames: int = 1,
                 landmark_embedding: str | None = None) -> HeadFit:
    """Fit the head to the keyframes; write ``head.npz`` and ``head_overlay.png``.

    ``serial`` defaults to the one recorded in ``keyframes.json``. With ``use_tracking`` the poses
    come from ``tracking/head_tracking.npz`` instead of the landmark fit.
    """
    from vid2haircut.front.figures import grid, head_overlay
    from vid2haircut.front.headfile import base_landmarks, resolve_head, save_head_fit
    from vid2haircut.front.landmarks import sequence_landmarks

    sel = load_keyframes(keyframes_json)
    out = Path(out_dir)
    check_outputs([out / "head_overlay.png", out / "head.npz"])
    seq = _open(dataset_root, subject, sequence, serial or sel.serial)
    try:
        have = set(seq.frame_indices)
        missing = [t for t in sel.frames if t not in have]
        if missing:
            raise ValueError(f"{keyframes_json}: keyframes {missing} are not in the sequence "
                             f"({seq.num_frames} frames, {min(have)}..{max(have)})")
        points = base_landmarks(head_model, landmark_embedding)
        if use_tracking:
            lmk = None
            try:
                lmk = sequence_landmarks(seq, sel.frames, landmark_source)
            except FileNotFoundError:
                pass
            fit = _fit_from_tracking(seq, sel.frames, head_model, points, lmk)
            source = "tracking"
        else:
            lmk = sequence_landmarks(seq, sel.frames, landmark_source)
            fit = fit_head_poses(points, lmk.lmk68, lmk.valid, lmk.frames, seq.camera, head_model, cfg, min_frames)
            source = "landmarks"
        log.info("head fit (%s): shape %s, reprojection error px %s", source, np.round(fit.shape, 4),
                 np.round(fit.reprojection_error_px, 2))
        base = resolve_head(head_model, landmark_embedding=landmark_embedding)
        # the shape factors are a per-axis linear map of the head frame (exact for the proxy head)
        head = SimpleNamespace(vertices=np.asarray(base.vertices, np.float64) * shape_axes(fit.shape),
                               faces=base.faces)
        pts = points * shape_axes(fit.shape)
        tiles = [head_overlay(seq.read_image(int(t)), seq.camera, fit.world_from_head[i], head,
                              fit.landmarks_2d[i], pts) for i, t in enumerate(fit.frames)]
        labels = [f"t={int(t)} err={fit.reprojection_error_px[i]:.2f}px" for i, t in enumerate(fit.frames)]
    finally:
        seq.close()
    write_image(out / "head_overlay.png", grid(tiles, labels=labels))
    save_head_fit(out / "head.npz", fit, seq.serial, source, landmark_embedding)
    return fit


def run_targets(dataset_root: str | Path, subject: str, sequence: str, head_npz: str | Path,
                out_dir: str | Path, serial: str | None = None, mask_source: str = "auto",
                depth_source: str = "auto", device: str | None = None, depth_context: bool = False) -> dict:
    """Compute mask / orientation / depth targets of every fitted keyframe and write them
    (``depth_context``: keep the depth of the visible head too, :class:`DepthConfig`)."""
    from vid2haircut.front.headfile import load_head_fit
    from vid2haircut.front.targets.build import compute_targets, write_targets
    from vid2haircut.front.targets.depth import DepthConfig

    fit, extra = load_head_fit(head_npz)
    seq = _open(dataset_root, subject, sequence, serial or extra["serial"] or None)
    try:
        targets, summary = compute_targets(seq, fit, mask_source=mask_source,
                                           depth_cfg=DepthConfig(source=depth_source, context=depth_context),
                                           device=device,
                                           landmark_embedding=extra["landmark_embedding"])
    finally:
        seq.close()
    write_targets(out_dir, targets, summary)
    return summary
