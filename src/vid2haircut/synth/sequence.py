"""Write one synthetic head-motion sequence folder (the format of ``shared/spec/sequence-format.md``).

A procedural hairstyle on the proxy head turns frontal -> +yaw -> -yaw -> frontal in front of one
fixed, calibrated camera (:mod:`.motion`); every frame is rendered photo-like (:mod:`.photo`) and
written together with its alpha matte, visible-hair mask and relative hair depth; the sequence
gets projected iBUG-68 landmarks (+ Gaussian pixel noise), the rigid head tracking, the
calibration and the ground truth (rest strands + ``meta.json``, written last).

Images are JPEG (OpenCV quality 95) by default to keep the folder small (NeRSemble ships JPEGs);
``image_format="png"`` gives lossless frames. Masks are 8-bit PNGs; depth maps are ``.npz``.
"""

from __future__ import annotations

import logging
import math
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from vid2haircut import __version__
from vid2haircut.camera import Camera, load_cameras, look_at, save_cameras
from vid2haircut.geometry import apply_transform, matrix_to_axis_angle
from vid2haircut.io.atomic import write_image, write_json, write_npz, write_text
from vid2haircut.io.sequence import (calibration_path, frame_path, sequence_dir, write_depth,
                                     write_landmarks, write_mask, write_tracking)
from vid2haircut.synth.motion import MotionParams, sway_basis, sway_points, world_from_head
from vid2haircut.synth.photo import PhotoStyle, render_photo

log = logging.getLogger(__name__)

IMAGE_FORMATS = ("jpg", "png")


SYNTH_MARKER = ".vid2haircut-synthesized"
"""File the synthesiser writes first into a sequence folder it makes (``ground_truth/meta.json`` comes last)."""


@dataclass(frozen=True)
class SynthConfig:
    """Everything that defines a synthetic sequence (recorded in ``ground_truth/meta.json``)."""

    family: str = "shoulder_straight"
    """Hairstyle family (``vid2haircut.synth.hairstyles.FAMILIES``)."""
    seed: int = 0
    """Seed of the hairstyle, colour jitter and landmark noise."""
    n_frames: int = 48
    width: int = 512
    height: int = 512
    n_strands: int = 10000
    n_points: int = 100
    landmark_noise_px: float = 1.0
    """Standard deviation of the Gaussian noise added to the projected landmarks, pixels."""
    yaw_max_deg: float = 60.0
    pitch_max_deg: float = 15.0
    sway_max_m: float = 0.015
    """Bound of the hair sway offset, metres."""
    sway_gain: float = 0.012
    """Hair sway per (rad per sequence unit) of head rotation per metre of lever (see
    :class:`vid2haircut.synth.motion.MotionParams`); larger = hair lags the head more."""
    head_model: str = "proxy-v1"
    head_scale: float = 1.0
    head_width: float = 1.0
    head_depth: float = 1.0
    head_crown: float = 1.0
    image_format: str = "jpg"
    """``jpg`` (quality 95, small) or ``png`` (lossless)."""
    serial: str = "222200037"
    """Camera serial used in the file names and the calibration."""
    camera_distance_m: float = 0.7
    head_fill: float = 0.6
    """Fraction of the image height that the head model (crown to neck) fills."""
    color_jitter: float = 0.10
    """Per-strand log-normal brightness jitter (sigma) on top of the generator's colours."""
    save_frame_points: bool = False
    """Also store the moved hair of every frame as ``frame_points_<t:05d>`` in strands.npz."""
    depth_context: bool = False
    """Depth maps also cover the visible head (face, ears, neck), as a monocular depth network's
    do, not only the hair (:func:`relative_depth`)."""

    def motion(self) -> MotionParams:
        return MotionParams(n_frames=self.n_frames, yaw_max_deg=self.yaw_max_deg,
                            pitch_max_deg=self.pitch_max_deg, sway_max_m=self.sway_max_m,
                            sway_gain=self.sway_gain)

    def validate(self) -> None:
        if self.image_format not in IMAGE_FORMATS:
            raise ValueError(f"image_format must be one of {IMAGE_FORMATS}, got {self.image_format!r}")
        if self.n_frames < 2 or self.width < 16 or self.height < 16:
            raise ValueError(f"need n_frames >= 2 and an image of at least 16x16 "
                             f"(got {self.n_frames} frames, {self.width}x{self.height})")
        if self.n_strands < 1 or self.n_points < 2:
            raise ValueError(f"need n_strands >= 1 and n_points >= 2 (got {self.n_strands}, {self.n_points})")
        numbers = {k: getattr(self, k) for k in ("landmark_noise_px", "yaw_max_deg", "pitch_max_deg", "sway_max_m",
                                                  "sway_gain", "head_scale", "head_width", "head_depth", "head_crown",
                                                  "camera_distance_m", "head_fill", "color_jitter")}
        bad = [k for k, v in numbers.items() if not math.isfinite(v)]
        if bad:
            raise ValueError(f"{', '.join(bad)} must be finite numbers (got {[numbers[k] for k in bad]})")
        if self.sway_max_m < 0 or self.sway_gain < 0:
            raise ValueError(f"sway_max_m and sway_gain must be >= 0 (got {self.sway_max_m}, {self.sway_gain})")
        if self.landmark_noise_px < 0 or self.color_jitter < 0:
            raise ValueError(f"landmark_noise_px and color_jitter must be >= 0 "
                             f"(got {self.landmark_noise_px}, {self.color_jitter})")
        if not (0 <= self.yaw_max_deg <= 90 and 0 <= self.pitch_max_deg <= 60):
            raise ValueError(f"yaw_max_deg must be in [0, 90] and pitch_max_deg in [0, 60] "
                             f"(got {self.yaw_max_deg}, {self.pitch_max_deg})")
        shape = [self.head_scale, self.head_width, self.head_depth, self.head_crown]
        if min(shape) <= 0 or self.camera_distance_m <= 0 or not 0 < self.head_fill <= 1:
            raise ValueError(f"head factors and camera distance must be > 0 and head_fill in (0, 1] "
                             f"(got {shape}, {self.camera_distance_m}, {self.head_fill})")
        if not self.serial or not all(c.isalnum() or c in "-_." for c in self.serial) or self.serial in (".", ".."):
            raise ValueError(f"serial must be letters, digits, '-', '_' or '.' (a folder name part), "
                             f"got {self.serial!r}")


def load_head(cfg: SynthConfig):
    from vid2haircut.head import get_head

    return get_head(cfg.head_model, scale=cfg.head_scale, width=cfg.head_width, depth=cfg.head_depth,
                    crown=cfg.head_crown)


def make_camera(head, width: int, height: int, distance: float = 0.7, fill: float = 0.6) -> Camera:
    """Fixed camera on the +z axis (in front of the face at rest) looking at the head.

    The focal length makes the head model's vertical extent fill ``fill`` of the image height;
    the camera aims at the middle of that extent. World frame = the head's canonical frame at rest.
    """
    v = np.asarray(head.vertices, dtype=np.float64)
    y_lo, y_hi = float(v[:, 1].min()), float(v[:, 1].max())
    yc = 0.5 * (y_lo + y_hi)
    f = fill * height * distance / (y_hi - y_lo)
    k = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    return Camera(k, look_at(np.array([0.0, yc, distance]), np.array([0.0, yc, 0.0])), width, height)


def hair_occlusion(rest_sdf: np.ndarray) -> np.ndarray:
    """(N, P) SDF of the rest strand points -> (N, P) light factor: dark at the scalp, 1 beyond 1.5 cm."""
    x = np.clip(np.asarray(rest_sdf, np.float64) / 0.015, 0.0, 1.0)
    return (0.35 + 0.65 * x * x * (3 - 2 * x)).astype(np.float32)


def jitter_colors(colors: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) linear RGB -> (N, 3): per-strand log-normal brightness and slight hue jitter."""
    n = colors.shape[0]
    gain = np.exp(rng.normal(0.0, sigma, (n, 1)) + rng.normal(0.0, 0.25 * sigma, (n, 3)))
    return np.clip(np.asarray(colors, np.float64) * gain, 0.0, 1.0).astype(np.float32)


def relative_depth(hair: np.ndarray, hair_depth: np.ndarray, head: np.ndarray | None = None,
                   head_depth: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Coverage (H, W) and camera z (H, W) -> (depth (H, W) float32 in [0, 1], valid (H, W) bool).

    As a monocular depth network would give it: larger is farther, min-max normalised over the
    valid pixels (at least half covered by visible hair; with ``head`` and ``head_depth``, the
    coverage and camera z of the head that no hair hides, also the pixels at least half covered by
    it), 0 elsewhere. Values are rounded to multiples of 2^-16 (float32 exact) so that the ``.npz``
    compresses well.
    """
    valid = (hair >= 0.5) & np.isfinite(hair_depth)
    z_all = np.where(valid, hair_depth, np.nan)
    if head is not None and head_depth is not None:
        face = ~valid & (head >= 0.5) & np.isfinite(head_depth)
        z_all = np.where(face, head_depth, z_all)
        valid = valid | face
    depth = np.zeros(hair.shape, np.float32)
    if valid.any():
        z = z_all[valid].astype(np.float64)
        lo, hi = float(z.min()), float(z.max())
        depth[valid] = np.round((z - lo) / max(hi - lo, 1e-9) * 65536.0) / 65536.0
    return depth, valid


def merged_calibration(path: Path, serial: str, cam: Camera, replace: bool = False) -> dict[str, Camera]:
    """The subject's cameras with ``serial`` set to ``cam``; checked before anything is written.

    Raises ValueError naming ``path`` when ``serial`` is already calibrated differently (unless
    ``replace``) or when the other cameras do not share ``cam``'s intrinsics and size (one
    ``camera_params.json`` holds one intrinsics matrix).
    """
    cams = load_cameras(path) if path.is_file() else {}
    old = cams.get(serial)
    if old is not None and not replace and not (
            np.allclose(old.K, cam.K) and np.allclose(old.world_2_cam, cam.world_2_cam)
            and (old.width, old.height) == (cam.width, cam.height)):
        raise ValueError(f"{path}: camera '{serial}' already calibrated differently "
                         "(a subject has one calibration; use another subject or serial, or overwrite)")
    others = {s: c for s, c in cams.items() if s != serial}
    for s, c in others.items():
        if not (np.allclose(c.K, cam.K) and (c.width, c.height) == (cam.width, cam.height)):
            raise ValueError(f"{path}: camera '{s}' has other intrinsics or image size than the new "
                             f"{cam.width}x{cam.height} camera '{serial}'; use another subject")
    return {**others, serial: cam}


def write_projected_landmarks(root: Path, serial: str, cam: Camera, head, poses: np.ndarray, noise_px: float,
                              rng: np.random.Generator) -> Path:
    """Project the head's 68 landmarks for every pose (T, 4, 4), add N(0, noise_px) noise, write them.

    Self-occluded landmarks are kept, as a 2D detector would still place them; a frame is marked
    invalid only when fewer than half of its landmarks fall inside the image.
    """
    lmk, _ = cam.project(np.stack([apply_transform(pose, head.landmarks) for pose in poses]))  # (T, 68, 2)
    lmk = lmk + rng.normal(0.0, noise_px, lmk.shape)
    inside = (lmk[..., 0] >= 0) & (lmk[..., 0] < cam.width) & (lmk[..., 1] >= 0) & (lmk[..., 1] < cam.height)
    return write_landmarks(root, serial, np.arange(len(poses)), lmk, inside.mean(1) >= 0.5)


def meta_record(cfg: SynthConfig, motion: MotionParams, style: PhotoStyle, strands_shape: tuple) -> dict:
    """The ``ground_truth/meta.json`` record: everything needed to regenerate the sequence."""
    return {
        "generator": "vid2haircut.synth", "software_version": __version__,
        "family": cfg.family, "seed": cfg.seed, "config": asdict(cfg),
        "head": {"model": cfg.head_model, "scale": cfg.head_scale, "width": cfg.head_width,
                 "depth": cfg.head_depth, "crown": cfg.head_crown},
        "motion": motion.to_dict(), "n_frames": cfg.n_frames, "image_size": [cfg.width, cfg.height],
        "landmark_noise_px": cfg.landmark_noise_px, "serial": cfg.serial, "image_format": cfg.image_format,
        "n_strands": int(strands_shape[0]), "n_points": int(strands_shape[1]), "style": asdict(style),
        "frame_points_saved": bool(cfg.save_frame_points),
    }


def synthesize_sequence(dataset_root: str | Path, subject: str, seq_name: str, cfg: SynthConfig = SynthConfig(),
                        style: PhotoStyle = PhotoStyle(), workers: int = 2, overwrite: bool = False) -> Path:
    """Generate a hairstyle, animate it and write the full sequence folder.

    Args:
        dataset_root: dataset root; the folder written is ``<root>/<subject>/sequences/<seq_name>``.
        subject, seq_name: identifiers.
        cfg: the sequence definition (deterministic: same config -> identical files).
        style: look of the rendered frames.
        workers: frames rendered in parallel (threads); the output does not depend on it.
        overwrite: replace an existing, non-empty sequence folder (and this serial's calibration
            entry); without it such a folder raises FileExistsError and nothing is touched.
    Returns:
        Path of the sequence folder.
    """
    from vid2haircut.io.strand_formats import save_strands
    from vid2haircut.strands import StrandSet
    from vid2haircut.synth.hairstyles import generate_hairstyle

    cfg.validate()
    t0 = time.perf_counter()
    root = sequence_dir(dataset_root, subject, seq_name)
    exists = root.is_dir() and any(root.iterdir())
    if exists and not overwrite:
        raise FileExistsError(f"{root}: sequence folder exists and is not empty (use overwrite / --overwrite)")
    head = load_head(cfg)
    hair = generate_hairstyle(cfg.family, cfg.seed, head=head, n_strands=cfg.n_strands, n_points=cfg.n_points)
    rest = np.asarray(hair.points, np.float32)
    basis = sway_basis(rest, head)
    rng_color, rng_lmk = (np.random.default_rng(s) for s in np.random.SeedSequence([int(cfg.seed), 1729]).spawn(2))
    colors = jitter_colors(np.asarray(hair.attributes["color"]), cfg.color_jitter, rng_color)
    occlusion = hair_occlusion(basis.rest_sdf)
    cam = make_camera(head, cfg.width, cfg.height, cfg.camera_distance_m, cfg.head_fill)
    calib = calibration_path(dataset_root, subject)
    cameras = merged_calibration(calib, cfg.serial, cam, replace=overwrite)
    if exists:  # everything is validated: only now replace the old folder
        shutil.rmtree(root)
    # written first: a folder the synthesiser began (meta.json comes last) is known as its own even
    # when the run was interrupted (the workflow's config check, vid2haircut.workflow_support)
    write_text(root / SYNTH_MARKER, f"vid2haircut {__version__} synthesize\n")
    motion = cfg.motion()
    poses = world_from_head(motion, np.arange(cfg.n_frames))
    log.info("%s/%s: hairstyle %s seed %d (%d x %d) in %.1fs", subject, seq_name, cfg.family, cfg.seed,
             rest.shape[0], rest.shape[1], time.perf_counter() - t0)

    def one_frame(t: int) -> np.ndarray | None:
        moved = sway_points(basis, motion, t, head)
        fr = render_photo(cam, head, poses[t], moved, colors, style, occlusion)
        write_image(frame_path(root, "images", cfg.serial, t, cfg.image_format), fr.image)
        write_mask(root, "alpha_maps", cfg.serial, t, fr.alpha)
        write_mask(root, "hair_masks", cfg.serial, t, fr.hair)
        context = (fr.head, fr.head_depth) if cfg.depth_context else (None, None)
        write_depth(root, cfg.serial, t, *relative_depth(fr.hair, fr.hair_depth, *context))
        return moved if cfg.save_frame_points else None

    # frames are independent: two threads keep both cores busy (numpy releases the GIL)
    with ThreadPoolExecutor(max_workers=max(1, int(workers))) as pool:
        moved_all = list(pool.map(one_frame, range(cfg.n_frames)))
    frame_points = {f"frame_points_{t:05d}": m for t, m in enumerate(moved_all) if m is not None}

    write_projected_landmarks(root, cfg.serial, cam, head, poses, cfg.landmark_noise_px, rng_lmk)
    write_tracking(root, np.arange(cfg.n_frames), matrix_to_axis_angle(poses[:, :3, :3]), poses[:, :3, 3], 1.0)
    save_cameras(calib, cameras)

    gt = StrandSet(rest, {"color": colors, "uv": np.asarray(hair.attributes["uv"], np.float32)},
                   head_model=cfg.head_model)
    if frame_points:
        write_npz(root / "ground_truth" / "strands.npz", points=gt.points, head_model=np.array(cfg.head_model),
                  color=colors, uv=gt.attributes["uv"], **frame_points)
    else:
        save_strands(root / "ground_truth" / "strands.npz", gt)
    write_json(root / "ground_truth" / "meta.json", meta_record(cfg, motion, style, rest.shape))
    log.info("%s/%s: %d frames written to %s in %.1fs", subject, seq_name, cfg.n_frames, root,
             time.perf_counter() - t0)
    return root
