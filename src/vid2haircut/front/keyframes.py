"""Keyframe selection: the most frontal sharp frame plus frames that spread the head-pose coverage.

Algorithm (:func:`select_keyframes`):
1. candidates: every frame (evenly thinned to ``max_candidates`` for long videos); landmarks from
   the sequence's landmark file or MediaPipe; frames without a face (or whose PnP fails) are
   dropped with a warning;
2. quick pose: robust PnP of the head model's landmarks per frame -> the camera's direction seen
   from the head (yaw, pitch) and its angle off the face direction;
3. sharpness: variance of the Laplacian of the grey image inside the face's bounding box
   (enlarged 1.5x); frames below ``blur_ratio`` x the median are rejected (unless fewer than M
   frames would remain, then the sharpest are kept);
4. reference = among the frames within ``frontal_tolerance_deg`` of the smallest off-frontal angle,
   the one where the head has been stillest over the preceding ``still_frames`` frames (hair lags
   the head: just after a turn the head is frontal but the hair still swings, and the reference
   keyframe defines the canonical hair that Stage 1 fits and Stage 2 pins its deformation to);
   then greedy farthest-point sampling in (yaw, pitch) degrees until M frames are chosen (ties ->
   sharper, then earlier).

``keyframes.json`` format::

    {"frames": [t, ...],              # sorted ascending, len M (fewer if the video is shorter)
     "reference": t,                  # the canonical (most frontal) frame, one of "frames"
     "scores": {"<t>": {"yaw_deg", "pitch_deg", "off_frontal_deg", "sharpness",
                        "reprojection_px"}},   # every candidate with a face
     "serial": "<camera serial>", "num_frames": T, "landmark_source": "file" | "mediapipe",
     "rejected": {"no_face": [t...], "blurred": [t...]}}
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vid2haircut.checks import as_whole
from vid2haircut.front.pose import PoseFitConfig, pnp_pose, project_landmarks, view_angles

log = logging.getLogger(__name__)

SPEED_STEP = 0.5
"""Head speeds (degrees per frame) closer than this count as equally still when picking the reference."""


@dataclass(frozen=True)
class KeyframeConfig:
    """Settings of the keyframe selection."""

    num_keyframes: int = 6
    """M, the number of keyframes (>= 1)."""
    max_candidates: int = 300
    """at most this many frames are scored (evenly spaced over the video)."""
    blur_ratio: float = 0.35
    """frames with sharpness < blur_ratio * median sharpness are rejected."""
    landmark_source: str = "auto"
    """"auto" (file, else MediaPipe), "file" or "detect"."""
    still_frames: int = 3
    """Head motion before a frame is measured over this many preceding frames (:func:`head_speed`);
    0 = the reference is simply the most frontal frame. On the generated sequences the hair lags
    the head by about 3 frames: the frontal frames at the end of a turn (46, 47 of 48) carry 2-3 mm
    of mean tip sway, the first frames none."""
    frontal_tolerance_deg: float = 3.0
    """Frames within this many degrees of the most frontal one may be the reference (the stillest wins)."""


@dataclass
class KeyframeSelection:
    """Chosen keyframes (see the module docstring for the JSON form)."""

    frames: list[int]
    reference: int
    scores: dict[int, dict[str, float]]
    serial: str
    num_frames: int = 0
    landmark_source: str = ""
    rejected: dict[str, list[int]] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"frames": [int(t) for t in self.frames], "reference": int(self.reference),
                "scores": {str(t): {k: float(v) for k, v in s.items()} for t, s in sorted(self.scores.items())},
                "serial": self.serial, "num_frames": int(self.num_frames),
                "landmark_source": self.landmark_source,
                "rejected": {k: [int(t) for t in v] for k, v in self.rejected.items()}}


def _is_frame(t) -> bool:
    """Whether a JSON value is a frame number: a whole number >= 0 (not a bool, not 1.5)."""
    v = as_whole(t)
    return v is not None and v >= 0


def load_keyframes(path: str | Path) -> KeyframeSelection:
    """Read ``keyframes.json``; errors name the file."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: keyframes file not found") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(d, dict):
        raise ValueError(f"{path}: expected a JSON object with 'frames', 'reference' and 'serial', "
                         f"got {type(d).__name__}")
    for k in ("frames", "reference", "serial"):
        if k not in d:
            raise ValueError(f"{path}: missing key '{k}'")
    if not isinstance(d["frames"], list) or not all(_is_frame(t) for t in d["frames"]):
        raise ValueError(f"{path}: 'frames' must be a list of frame numbers (whole numbers >= 0), "
                         f"got {d['frames']!r:.80}")
    frames = [int(t) for t in d["frames"]]
    if len(set(frames)) != len(frames):
        raise ValueError(f"{path}: 'frames' lists frames {sorted({t for t in frames if frames.count(t) > 1})} "
                         "more than once")
    if not _is_frame(d["reference"]) or not frames or int(d["reference"]) not in frames:
        raise ValueError(f"{path}: 'reference' {d['reference']!r} must be one of 'frames' {frames}")
    scores = d.get("scores", {})
    if not (isinstance(scores, dict) and all(k.isdigit() and isinstance(v, dict) for k, v in scores.items())
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) for v in scores.values()
                    for x in v.values())):
        raise ValueError(f"{path}: 'scores' must map frame numbers to {{name: number}}, got {scores!r:.80}")
    rejected = d.get("rejected", {})
    if not (isinstance(rejected, dict) and all(isinstance(v, list) and all(_is_frame(t) for t in v)
                                               for v in rejected.values())):
        raise ValueError(f"{path}: 'rejected' must map reasons to lists of frame numbers, got {rejected!r:.80}")
    if not _is_frame(d.get("num_frames", 0)):
        raise ValueError(f"{path}: 'num_frames' must be a whole number >= 0, got {d['num_frames']!r:.40}")
    return KeyframeSelection(frames=frames, reference=int(d["reference"]),
                             scores={int(t): s for t, s in scores.items()},
                             serial=str(d["serial"]), num_frames=int(d.get("num_frames", 0)),
                             landmark_source=str(d.get("landmark_source", "")),
                             rejected={str(k): [int(t) for t in v] for k, v in rejected.items()})


def sharpness(image: np.ndarray, box: tuple[int, int, int, int] | None = None) -> float:
    """Variance of the Laplacian of the grey image (inside ``box`` = (x0, y0, x1, y1) if given).

    Args:
        image: (H, W, 3) uint8 RGB.
    """
    import cv2

    grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    if box is not None:
        x0, y0, x1, y1 = box
        grey = grey[y0:y1, x0:x1]
    if grey.size == 0:
        return 0.0
    return float(cv2.Laplacian(grey, cv2.CV_64F, ksize=3).var())


def face_box(lmk: np.ndarray, shape: tuple[int, int], grow: float = 1.5) -> tuple[int, int, int, int]:
    """(68, 2) landmarks -> (x0, y0, x1, y1) box around them enlarged by ``grow``, clipped to the image."""
    h, w = shape
    lo, hi = np.nanmin(lmk, axis=0), np.nanmax(lmk, axis=0)
    c, half = (lo + hi) / 2, (hi - lo) / 2 * grow
    x0, y0 = np.floor(c - half).astype(int)
    x1, y1 = np.ceil(c + half).astype(int) + 1
    return max(0, x0), max(0, y0), min(w, x1), min(h, y1)


def head_speed(frames: np.ndarray, yaw: np.ndarray, pitch: np.ndarray, window: int) -> np.ndarray:
    """Mean head rotation speed (degrees per frame) over the ``window`` frames before each candidate.

    The path length in (yaw, pitch) through the candidates in ``[t - window, t]`` divided by its
    span in frames. A candidate with no other candidate in its window (the first frame, or a video
    thinned to fewer candidates) takes the speed to its nearest earlier candidate, or, for the
    first one, to the next.

    Args:
        frames: (N,) frame indices, strictly increasing.
        yaw, pitch: (N,) head view angles, degrees.
        window: frames looked back (0: all speeds 0).
    Returns:
        (N,) float64 speeds, degrees per frame (0 for a single candidate).
    """
    n = len(frames)
    speed = np.zeros(n)
    if window <= 0 or n < 2:
        return speed
    pose = np.stack([yaw, pitch], axis=1).astype(np.float64)
    step = np.linalg.norm(np.diff(pose, axis=0), axis=1)                       # (N-1,) i-1 -> i
    gap = np.diff(frames).astype(np.float64)
    for i in range(n):
        lo = int(np.searchsorted(frames, frames[i] - window, side="left"))
        if lo < i:
            speed[i] = step[lo:i].sum() / max(float(frames[i] - frames[lo]), 1.0)
        elif i > 0:
            speed[i] = step[i - 1] / gap[i - 1]
        else:
            speed[i] = step[0] / gap[0]
    return speed


def choose_keyframes(frames: np.ndarray, yaw: np.ndarray, pitch: np.ndarray, off_frontal: np.ndarray,
                     sharp: np.ndarray, m: int, blur_ratio: float = 0.35, still_frames: int = 0,
                     frontal_tolerance: float = 3.0) -> tuple[list[int], int, list[int]]:
    """Pure selection step.

    Args:
        frames, yaw, pitch, off_frontal, sharp: (N,) per candidate, frames increasing (angles in degrees).
        m: number of keyframes.
        blur_ratio: frames sharper than this fraction of the median are kept.
        still_frames: look-back window of :func:`head_speed` (0: the reference is the most frontal).
        frontal_tolerance: degrees above the smallest off-frontal angle that still count as frontal.
    Returns:
        (chosen frames sorted ascending, reference frame, frames rejected as blurred).
    """
    if m < 1:
        raise ValueError(f"number of keyframes must be >= 1, got {m}")
    n = len(frames)
    if n == 0:
        raise ValueError("no candidate frame has a face")
    ok = sharp >= blur_ratio * np.median(sharp)
    if ok.sum() < min(m, n):  # too strict: keep the sharpest
        ok = np.zeros(n, bool)
        ok[np.argsort(-sharp, kind="stable")[: min(m, n)]] = True
    blurred = [int(t) for t in frames[~ok]]
    idx = np.flatnonzero(ok)
    # reference: the stillest of the frontal frames, speeds compared in steps of SPEED_STEP (the
    # quick pose is noisy at about that level); ties -> more frontal, sharper, then earlier
    order = np.argsort(frames, kind="stable")
    speed = np.empty(n)
    speed[order] = head_speed(frames[order], yaw[order], pitch[order], still_frames)
    front = idx[off_frontal[idx] <= off_frontal[idx].min() + (frontal_tolerance if still_frames > 0 else 0.0)]
    ref = front[np.lexsort((frames[front], -sharp[front], np.round(off_frontal[front], 6),
                            np.floor(speed[front] / SPEED_STEP)))[0]]
    chosen = [int(ref)]
    pose = np.stack([yaw, pitch], axis=1)
    rel = sharp / max(float(np.median(sharp[idx])), 1e-12)
    while len(chosen) < min(m, len(idx)):
        rest = np.array([i for i in idx if i not in chosen])
        d = np.linalg.norm(pose[rest][:, None] - pose[chosen][None], axis=-1).min(axis=1)
        key = np.lexsort((frames[rest], -rel[rest], -np.round(d, 3)))
        chosen.append(int(rest[key[0]]))
    return sorted(int(frames[i]) for i in chosen), int(frames[ref]), blurred


def select_keyframes(seq, points_head: np.ndarray, cfg: KeyframeConfig = KeyframeConfig(),
                     pose_cfg: PoseFitConfig = PoseFitConfig()) -> KeyframeSelection:
    """Score the frames of a sequence and pick keyframes (see the module docstring).

    Args:
        seq: an open :class:`vid2haircut.io.sequence.Sequence`.
        points_head: (68, 3) head-model landmarks (head frame, metres).
    """
    from vid2haircut.front.landmarks import sequence_landmarks

    all_frames = list(seq.frame_indices)
    if not all_frames:
        raise ValueError(f"{seq.root}: the sequence has no frames")
    if len(all_frames) > cfg.max_candidates:
        pick = np.unique(np.round(np.linspace(0, len(all_frames) - 1, cfg.max_candidates)).astype(int))
        all_frames = [all_frames[i] for i in pick]
    lm = sequence_landmarks(seq, all_frames, cfg.landmark_source)
    rows, scores, no_face = [], {}, []
    for i, t in enumerate(all_frames):
        if not lm.valid[i]:
            log.warning("frame %d: no face, not a keyframe candidate", t)
            no_face.append(t)
            continue
        try:
            pose, inl = pnp_pose(points_head, lm.lmk68[i].astype(np.float64), seq.camera, pose_cfg)
        except ValueError as e:
            log.warning("frame %d: %s, not a keyframe candidate", t, e)
            no_face.append(t)
            continue
        img = seq.read_image(t)
        sh = sharpness(img, face_box(lm.lmk68[i], img.shape[:2]))
        yaw, pitch, off = view_angles(seq.camera, pose)
        err = np.linalg.norm(project_landmarks(seq.camera, pose[None], points_head)[0] - lm.lmk68[i], axis=-1)
        scores[t] = {"yaw_deg": yaw, "pitch_deg": pitch, "off_frontal_deg": off, "sharpness": sh,
                     "reprojection_px": float(np.mean(err[inl]))}
        rows.append(t)
    if not rows:
        raise ValueError(f"{seq.root}: no frame of camera {seq.serial} shows a face "
                         f"({len(all_frames)} frames checked)")
    fr = np.array(rows)
    col = {k: np.array([scores[t][k] for t in rows]) for k in ("yaw_deg", "pitch_deg", "off_frontal_deg", "sharpness")}
    chosen, ref, blurred = choose_keyframes(fr, col["yaw_deg"], col["pitch_deg"], col["off_frontal_deg"],
                                            col["sharpness"], cfg.num_keyframes, cfg.blur_ratio,
                                            cfg.still_frames, cfg.frontal_tolerance_deg)
    if len(chosen) < cfg.num_keyframes:
        log.warning("only %d keyframes available (asked for %d)", len(chosen), cfg.num_keyframes)
    log.info("keyframes %s, reference %d (%s landmarks)", chosen, ref, lm.source)
    return KeyframeSelection(frames=chosen, reference=ref, scores=scores, serial=seq.serial,
                             num_frames=seq.num_frames, landmark_source=lm.source,
                             rejected={"no_face": no_face, "blurred": blurred})
