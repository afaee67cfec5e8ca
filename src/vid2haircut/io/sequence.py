"""Reader (and small writers) of one sequence folder in the NeRSemble-like format.

The layout is fixed by ``shared/spec/sequence-format.md``::

    <root>/<subject>/calibration/camera_params.json
    <root>/<subject>/sequences/<seq>/images/cam_<serial>.mp4 | images/cam_<serial>/frame_<t:05d>.(jpg|png)
    .../alpha_maps, hair_masks, depth_maps, landmarks, tracking, ground_truth  (all optional)

Every error raised here names the offending file and what is wrong with it.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vid2haircut.camera import Camera, load_cameras
from vid2haircut.checks import float_array, frame_numbers

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
_FRAME_RE = re.compile(r"^frame_(\d+)\.(jpg|jpeg|png)$", re.IGNORECASE)


def sequence_dir(dataset_root: str | Path, subject: str, seq_name: str) -> Path:
    """Path of ``<dataset_root>/<subject>/sequences/<seq_name>``."""
    return Path(dataset_root) / str(subject) / "sequences" / str(seq_name)


def calibration_path(dataset_root: str | Path, subject: str) -> Path:
    """Path of ``<dataset_root>/<subject>/calibration/camera_params.json``."""
    return Path(dataset_root) / str(subject) / "calibration" / "camera_params.json"


def frame_path(seq_root: str | Path, kind: str, serial: str, t: int, ext: str) -> Path:
    """``<seq_root>/<kind>/cam_<serial>/frame_<t:05d>.<ext>`` (kind: images, alpha_maps, ...)."""
    return Path(seq_root) / kind / f"cam_{serial}" / f"frame_{int(t):05d}.{ext.lstrip('.')}"


class _FrameSource:
    """Frames of one camera, from a folder of images or from a video (decoded with OpenCV)."""

    def __init__(self, seq_root: Path, kind: str, serial: str):
        self.folder = seq_root / kind / f"cam_{serial}"
        self.video = seq_root / kind / f"cam_{serial}.mp4"
        self.files: dict[int, Path] = {}
        self._cap = None
        self._next = 0
        self.n_video = 0
        if self.folder.is_dir():
            for p in self.folder.iterdir():
                m = _FRAME_RE.match(p.name)
                if m:
                    self.files.setdefault(int(m.group(1)), p)
        if not self.files and self.video.is_file():
            import cv2

            cap = cv2.VideoCapture(str(self.video))
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
            ok = cap.isOpened() and n > 0 and cap.read()[0]
            if not ok:
                cap.release()
                raise ValueError(f"{self.video}: unreadable video (OpenCV could not decode any frame)")
            cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            self._cap, self.n_video = cap, n

    @property
    def present(self) -> bool:
        return bool(self.files) or self._cap is not None

    def indices(self) -> list[int]:
        return sorted(self.files) if self.files else list(range(self.n_video))

    def read(self, t: int, grey: bool) -> tuple[np.ndarray, Path]:
        """Frame ``t`` as uint8 (H,W,3) RGB, or (H,W) when ``grey``; also the path it came from."""
        import cv2

        if self.files:
            p = self.files.get(int(t))
            if p is None:
                raise FileNotFoundError(f"{self.folder / f'frame_{int(t):05d}'}.(jpg|png): frame {t} not found")
            img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"{p}: unreadable image")
            return (img if grey else img[:, :, ::-1].copy()), p
        if self._cap is None:
            raise FileNotFoundError(f"{self.folder} / {self.video}: no frames")
        if not 0 <= t < self.n_video:
            raise ValueError(f"{self.video}: frame {t} out of range (video has {self.n_video} frames)")
        if t != self._next:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, int(t))
        ok, img = self._cap.read()
        if not ok:
            raise ValueError(f"{self.video}: unreadable video (frame {t} could not be decoded)")
        self._next = t + 1
        if grey:
            return (img[:, :, 0] if img.ndim == 3 else img), self.video
        return img[:, :, ::-1].copy(), self.video

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


def _load_npz(path: Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Load every array of ``path``; ValueError naming the file if unreadable or a key is missing."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as e:  # BadZipFile, OSError, EOFError, pickled objects ...
        raise ValueError(f"{path}: not a readable .npz file ({type(e).__name__}: {e})") from None
    missing = [k for k in keys if k not in data]
    if missing:
        raise ValueError(f"{path}: missing key(s) {missing} (has {sorted(data)})")
    return data


def _check_0_255(img: np.ndarray, path: Path, what: str) -> None:
    """Refuse an 8-bit mask whose largest value is 1 on more than 0.5% of its pixels: one written as
    0/1 instead of 0..255 would otherwise read as (almost) empty, and every stage after it would fit
    to nothing (a few 1s in an empty frame are compression noise, and pass)."""
    if img.dtype == np.uint8 and img.max(initial=0) == 1 and np.count_nonzero(img) > 0.005 * img.size:
        raise ValueError(f"{path}: values are only 0 and 1, but {what} are 0..255 (255 = hair / foreground); "
                         "multiply the mask by 255")


@dataclass
class Sequence:
    """One camera of one sequence folder (see the module docstring for the layout).

    Attributes:
        root: the sequence folder ``<dataset_root>/<subject>/sequences/<name>``.
        subject, name, serial: identifiers; ``serial`` is the camera used.
        camera: the calibrated :class:`~vid2haircut.camera.Camera` of ``serial``.
        frame_indices: sorted frame indices of the images.
    """

    root: Path
    subject: str
    name: str
    serial: str
    camera: Camera
    frame_indices: list[int]
    _images: _FrameSource = field(repr=False)
    _alpha: _FrameSource | None = field(default=None, repr=False)

    @property
    def num_frames(self) -> int:
        return len(self.frame_indices)

    # -- per-frame data --------------------------------------------------------------------
    def _check_size(self, img: np.ndarray, path: Path) -> None:
        h, w = img.shape[:2]
        if (w, h) != (self.camera.width, self.camera.height):
            raise ValueError(f"{path}: image size {w}x{h} does not match the calibration "
                             f"({self.camera.width}x{self.camera.height})")

    def read_image(self, t: int) -> np.ndarray:
        """Frame ``t`` -> (H, W, 3) uint8 RGB."""
        img, p = self._images.read(t, grey=False)
        self._check_size(img, p)
        return img

    def read_alpha(self, t: int) -> np.ndarray | None:
        """Foreground matte of frame ``t`` -> (H, W) float32 in [0, 1], or None if absent."""
        if self._alpha is None:
            src = _FrameSource(self.root, "alpha_maps", self.serial)
            if not src.present:
                return None
            self._alpha = src
        img, p = self._alpha.read(t, grey=True)
        self._check_size(img, p)
        _check_0_255(img, p, "foreground mattes")
        return img.astype(np.float32) / 255.0

    def read_hair_mask(self, t: int) -> np.ndarray | None:
        """Hair segmentation of frame ``t`` -> (H, W) float32 in [0, 1], or None if absent."""
        import cv2

        p = frame_path(self.root, "hair_masks", self.serial, t, "png")
        if not p.is_file():
            return None
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise ValueError(f"{p}: unreadable image")
        self._check_size(img, p)
        _check_0_255(img, p, "hair masks")
        return img.astype(np.float32) / 255.0

    def read_depth(self, t: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Relative depth of frame ``t`` -> (depth (H, W) float32, valid (H, W) bool), or None."""
        p = frame_path(self.root, "depth_maps", self.serial, t, "npz")
        if not p.is_file():
            return None
        z = _load_npz(p, ("depth", "valid"))
        depth, valid = z["depth"].astype(np.float32), z["valid"].astype(bool)
        if depth.ndim != 2 or depth.shape != valid.shape:
            raise ValueError(f"{p}: 'depth' {depth.shape} and 'valid' {valid.shape} must be equal (H, W)")
        self._check_size(depth, p)
        return depth, valid

    # -- per-sequence data -----------------------------------------------------------------
    def landmarks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """-> (frames (T,) int64, lmk68 (T, 68, 2) float32 pixels, valid (T,) bool), or None."""
        p = self.root / "landmarks" / f"cam_{self.serial}.npz"
        if not p.is_file():
            return None
        z = _load_npz(p, ("frames", "lmk68"))
        frames = frame_numbers(z["frames"], p)
        lmk = float_array(z["lmk68"], p, "lmk68", finite=False, dtype=np.float32)  # NaN: a missing landmark
        valid = z["valid"].astype(bool).reshape(-1) if "valid" in z else np.ones(len(frames), bool)
        if lmk.shape != (len(frames), 68, 2) or valid.shape != frames.shape:
            raise ValueError(f"{p}: expected lmk68 (T,68,2) and valid (T,) for T={len(frames)} frames, "
                             f"got {lmk.shape} and {valid.shape}")
        return frames, lmk, valid

    def tracking(self) -> dict[str, np.ndarray] | None:
        """World-from-head rigid pose per frame -> dict(frames (T,), rotation (T,3) axis-angle,
        translation (T,3) metres, scale (1,)), or None when ``tracking/head_tracking.npz`` is absent."""
        p = self.root / "tracking" / "head_tracking.npz"
        if not p.is_file():
            return None
        z = _load_npz(p, ("frames", "rotation", "translation"))
        frames = frame_numbers(z["frames"], p)
        out = {"frames": frames,
               **{k: float_array(z[k], p, k, (len(frames), 3)) for k in ("rotation", "translation")},
               "scale": float_array(z["scale"], p, "scale", finite=False).reshape(-1) if "scale" in z else np.ones(1)}
        if np.abs(out["translation"]).max(initial=0.0) > 1e3:
            raise ValueError(f"{p}: 'translation' is in metres; {np.abs(out['translation']).max():.3g} is not "
                             "a head position (more than 1 km from the world origin)")
        if out["scale"].shape != (1,) or not (np.isfinite(out["scale"]).all() and out["scale"][0] > 0):
            raise ValueError(f"{p}: 'scale' must be one positive number, got {out['scale'].tolist()}")
        return out

    @property
    def ground_truth_strands_path(self) -> Path | None:
        p = self.root / "ground_truth" / "strands.npz"
        return p if p.is_file() else None

    def meta(self) -> dict | None:
        """``ground_truth/meta.json`` as a dict, or None."""
        p = self.root / "ground_truth" / "meta.json"
        if not p.is_file():
            return None
        try:
            return json.loads(p.read_text())
        except json.JSONDecodeError as e:
            raise ValueError(f"{p}: not valid JSON ({e})") from None

    def close(self) -> None:
        """Release open video decoders."""
        self._images.close()
        if self._alpha is not None:
            self._alpha.close()


def open_sequence(dataset_root: str | Path, subject: str, seq_name: str, serial: str | None = None) -> Sequence:
    """Open ``<dataset_root>/<subject>/sequences/<seq_name>`` for camera ``serial``.

    ``serial=None`` picks the first serial (sorted) of the calibration that has images.
    Raises FileNotFoundError / ValueError naming the file when something is missing or wrong.
    """
    root = sequence_dir(dataset_root, subject, seq_name)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: sequence folder not found")
    calib = calibration_path(dataset_root, subject)
    cams = load_cameras(calib)
    if serial is None:
        for s in sorted(cams):
            if (root / "images" / f"cam_{s}").is_dir() or (root / "images" / f"cam_{s}.mp4").is_file():
                serial = s
                break
        else:
            raise FileNotFoundError(f"{root / 'images'}: no images for any camera of {calib} "
                                    f"(serials {sorted(cams)})")
    serial = str(serial)
    if serial not in cams:
        raise ValueError(f"{calib}: camera serial '{serial}' not in the calibration (has {sorted(cams)})")
    src = _FrameSource(root, "images", serial)
    if not src.present:
        raise FileNotFoundError(f"{root / 'images'}: neither cam_{serial}/frame_*.jpg|png nor cam_{serial}.mp4")
    return Sequence(root=root, subject=str(subject), name=str(seq_name), serial=serial,
                    camera=cams[serial], frame_indices=src.indices(), _images=src)


# -- writers (used by the synthesiser; every write is atomic) ------------------------------------
def write_mask(seq_root: str | Path, kind: str, serial: str, t: int, mask: np.ndarray) -> Path:
    """Write a (H, W) float mask in [0, 1] as an 8-bit PNG under ``<kind>/cam_<serial>/``."""
    from vid2haircut.io.atomic import write_image

    p = frame_path(seq_root, kind, serial, t, "png")
    write_image(p, np.clip(np.rint(np.asarray(mask, np.float64) * 255.0), 0, 255).astype(np.uint8))
    return p


def write_depth(seq_root: str | Path, serial: str, t: int, depth: np.ndarray, valid: np.ndarray) -> Path:
    """Write ``depth_maps/cam_<serial>/frame_<t>.npz`` with depth (H, W) float32, valid (H, W) bool."""
    from vid2haircut.io.atomic import write_npz

    p = frame_path(seq_root, "depth_maps", serial, t, "npz")
    write_npz(p, depth=np.asarray(depth, np.float32), valid=np.asarray(valid, bool))
    return p


def write_landmarks(seq_root: str | Path, serial: str, frames: np.ndarray, lmk68: np.ndarray,
                    valid: np.ndarray) -> Path:
    """Write ``landmarks/cam_<serial>.npz``: frames (T,), lmk68 (T, 68, 2), valid (T,)."""
    from vid2haircut.io.atomic import write_npz

    p = Path(seq_root) / "landmarks" / f"cam_{serial}.npz"
    write_npz(p, frames=np.asarray(frames, np.int64), lmk68=np.asarray(lmk68, np.float32),
              valid=np.asarray(valid, bool))
    return p


def write_tracking(seq_root: str | Path, frames: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
                   scale: float = 1.0) -> Path:
    """Write ``tracking/head_tracking.npz``: world_from_head per frame (axis-angle, metres)."""
    from vid2haircut.io.atomic import write_npz

    p = Path(seq_root) / "tracking" / "head_tracking.npz"
    write_npz(p, frames=np.asarray(frames, np.int64), rotation=np.asarray(rotation, np.float64),
              translation=np.asarray(translation, np.float64), scale=np.array([scale], np.float64))
    return p
