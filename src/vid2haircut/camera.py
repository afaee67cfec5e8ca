"""Pinhole camera in the OpenCV convention (x right, y down, z forward), metres.

This is the one camera type of the project: the synthesiser writes it, the renderer and the
front stages read it. ``calibration/camera_params.json`` (see the sequence-format spec) maps to
one :class:`Camera` per serial.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vid2haircut.checks import as_whole, rigid


@dataclass(frozen=True)
class Camera:
    """One calibrated camera.

    Attributes:
        K: (3, 3) float64 intrinsics.
        world_2_cam: (4, 4) float64 extrinsics, world -> camera (OpenCV).
        width, height: image size in pixels.
    """

    K: np.ndarray
    world_2_cam: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        E = np.asarray(self.world_2_cam, dtype=np.float64)
        if K.shape != (3, 3) or not np.isfinite(K).all() or not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ValueError(f"Camera: K must be a finite 3x3 matrix with positive focal lengths, got {K.tolist()}")
        if E.shape != (4, 4) or not np.isfinite(E).all():
            raise ValueError(f"Camera: world_2_cam must be a finite 4x4 matrix, got shape {E.shape}")
        size = []
        for name in ("width", "height"):
            v = as_whole(getattr(self, name))
            if v is None or v <= 0:
                raise ValueError(f"Camera: {name} must be a positive whole number of pixels, got {getattr(self, name)!r}")
            size.append(v)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "world_2_cam", E)
        object.__setattr__(self, "width", size[0])
        object.__setattr__(self, "height", size[1])

    @property
    def cam_2_world(self) -> np.ndarray:
        return np.linalg.inv(self.world_2_cam)

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        return self.cam_2_world[:3, 3]

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> (..., 3) camera-frame points."""
        p = np.asarray(points, dtype=np.float64)
        return p @ self.world_2_cam[:3, :3].T + self.world_2_cam[:3, 3]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(..., 3) world points -> ((..., 2) pixel coordinates, (...,) camera depth z).

        Pixel centres are at integer coordinates (OpenCV): pixel (0, 0) covers [-0.5, 0.5]^2.
        """
        pc = self.to_camera(points)
        z = pc[..., 2]
        zs = np.where(np.abs(z) > 1e-12, z, 1e-12)
        uv = pc[..., :2] / zs[..., None]
        uv = uv @ self.K[:2, :2].T + self.K[:2, 2]
        return uv, z

    def with_pose(self, world_2_cam: np.ndarray) -> "Camera":
        return Camera(self.K, np.asarray(world_2_cam, dtype=np.float64), self.width, self.height)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 1.0, 0.0])) -> np.ndarray:
    """World->camera (4, 4) for an OpenCV camera at ``eye`` looking at ``target`` (world y up)."""
    eye = np.asarray(eye, dtype=np.float64)
    fwd = np.asarray(target, dtype=np.float64) - eye
    if not np.linalg.norm(fwd) > 0:
        raise ValueError(f"look_at: eye and target are the same point {eye.tolist()}")
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    if not np.linalg.norm(right) > 1e-9:
        raise ValueError(f"look_at: the view direction {fwd.tolist()} is parallel to up {np.asarray(up).tolist()}; "
                         "give another up vector")
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    rot = np.stack([right, down, fwd])  # rows: camera axes in world coordinates
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = -rot @ eye
    return out


def intrinsics_from_fov(width: int, height: int, fov_y_deg: float) -> np.ndarray:
    """(3, 3) intrinsics with square pixels and the principal point at the image centre."""
    if not 0.0 < fov_y_deg < 180.0:
        raise ValueError(f"intrinsics_from_fov: fov_y_deg must be in (0, 180), got {fov_y_deg}")
    f = 0.5 * height / np.tan(np.radians(fov_y_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def load_cameras(path: str | Path) -> dict[str, Camera]:
    """Read ``calibration/camera_params.json`` -> {serial: Camera}. Errors name the file."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: calibration file not found") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object with 'intrinsics', 'world_2_cam', 'width' and "
                         f"'height', got {type(data).__name__}")
    for key in ("intrinsics", "world_2_cam", "width", "height"):
        if key not in data:
            raise ValueError(f"{path}: missing key '{key}'")
    K = _finite_matrix(path, "'intrinsics'", data["intrinsics"], (3, 3))
    if not (K[0, 0] > 0 and K[1, 1] > 0 and K[1, 0] == 0 and np.allclose(K[2], [0.0, 0.0, 1.0])):
        raise ValueError(f"{path}: 'intrinsics' must be a pinhole matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] "
                         f"with fx, fy > 0 (pixels, OpenCV convention), got {K.tolist()}")
    if not isinstance(data["world_2_cam"], dict):
        raise ValueError(f"{path}: 'world_2_cam' must map camera serials to 4x4 matrices, "
                         f"got {type(data['world_2_cam']).__name__}")
    size = []
    for key in ("width", "height"):
        v = as_whole(data[key])
        if v is None or v <= 0:
            raise ValueError(f"{path}: '{key}' must be a positive whole number of pixels, got {data[key]!r}")
        size.append(v)
    cams = {}
    for serial, m in data["world_2_cam"].items():
        m = _finite_matrix(path, f"world_2_cam['{serial}']", m, (4, 4))
        if not rigid(m):
            raise ValueError(f"{path}: world_2_cam['{serial}'] must be a rigid transform (a rotation, a "
                             "translation in metres, last row 0 0 0 1)")
        cams[str(serial)] = Camera(K, m, size[0], size[1])
    if not cams:
        raise ValueError(f"{path}: 'world_2_cam' lists no camera")
    return cams


def _finite_matrix(path: Path, name: str, value, shape: tuple[int, int]) -> np.ndarray:
    """``value`` as a float64 matrix of ``shape`` with finite entries; errors name the file and the entry."""
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: {name} must be a {shape[0]}x{shape[1]} matrix of numbers, got {value!r:.80}") from None
    if m.shape != shape:
        raise ValueError(f"{path}: {name} must be {shape[0]}x{shape[1]}, got shape {m.shape}")
    if not np.isfinite(m).all():
        raise ValueError(f"{path}: {name} has non-finite entries")
    return m


def save_cameras(path: str | Path, cameras: dict[str, Camera]) -> None:
    """Write ``camera_params.json`` (all cameras must share intrinsics and size, as in NeRSemble)."""
    from vid2haircut.io.atomic import write_json

    cams = list(cameras.values())
    first = cams[0]
    for c in cams[1:]:
        if not (np.allclose(c.K, first.K) and c.width == first.width and c.height == first.height):
            raise ValueError("all cameras written to one camera_params.json must share intrinsics and size")
    write_json(path, {
        "intrinsics": first.K.tolist(),
        "world_2_cam": {s: c.world_2_cam.tolist() for s, c in cameras.items()},
        "width": first.width,
        "height": first.height,
    })
