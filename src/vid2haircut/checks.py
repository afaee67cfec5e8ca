"""Value checks shared by the file readers and the Python API.

Readers of ``.npz`` inputs (landmarks, tracking, head fits, targets) call :func:`frame_numbers` and
:func:`float_array` instead of a bare ``astype``, which would turn a float frame number 3.6 into
frame 3, or a string array into a "could not convert string to float" error that names no file;
each error names the file and the key. :func:`as_whole` is the one test of "a whole number" that
sizes, counts and frame numbers use (callers raise their own error, naming the argument).
"""

from __future__ import annotations

import operator
from pathlib import Path

import numpy as np


def as_whole(value) -> int | None:
    """``value`` as an int when it is a whole number (an int, a numpy integer, a 0-d integer tensor,
    or a finite float with no fractional part such as 64.0), else None (bools and strings included)."""
    if isinstance(value, (bool, str, bytes)):
        return None
    try:
        return operator.index(value)
    except TypeError:
        pass
    try:
        f = float(value)
    except (TypeError, ValueError):
        return None
    return int(f) if f.is_integer() else None


def frame_numbers(values, path: str | Path, key: str = "frames") -> np.ndarray:
    """``values`` as (T,) int64 frame numbers: a 1-D array of whole, non-negative, distinct numbers.

    Raises:
        ValueError naming ``path`` and ``key`` otherwise.
    """
    a = np.asarray(values)
    if a.ndim != 1:
        raise ValueError(f"{path}: '{key}' must be a 1-D array of frame numbers, got shape {a.shape}")
    if a.dtype.kind not in "iuf":
        raise ValueError(f"{path}: '{key}' must hold frame numbers, got {a.dtype} values")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise ValueError(f"{path}: '{key}' has non-finite frame numbers")
    if a.dtype.kind == "f" and (a != np.round(a)).any():
        bad = a[a != np.round(a)][:3].tolist()
        raise ValueError(f"{path}: '{key}' must hold whole frame numbers, got {bad}")
    if (a < 0).any():
        raise ValueError(f"{path}: '{key}' has negative frame numbers {a[a < 0][:3].tolist()}")
    out = a.astype(np.int64)
    uniq, counts = np.unique(out, return_counts=True)
    if (counts > 1).any():
        raise ValueError(f"{path}: '{key}' lists frames {uniq[counts > 1][:5].tolist()} more than once")
    return out


def float_array(values, path: str | Path, key: str, shape: tuple | None = None, finite: bool = True,
                dtype=np.float64) -> np.ndarray:
    """``values`` as a float array of ``shape`` (None entries: any size), finite when ``finite``.

    Raises:
        ValueError naming ``path`` and ``key`` for non-numeric values, another shape, or
        non-finite entries.
    """
    a = np.asarray(values)
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{path}: '{key}' must be numeric, got {a.dtype} values")
    if shape is not None and (a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape))):
        want = str(tuple("N" if s is None else s for s in shape)).replace("'", "")
        raise ValueError(f"{path}: '{key}' must have shape {want}, got {a.shape}")
    if finite and a.dtype.kind == "f" and not np.isfinite(a).all():
        raise ValueError(f"{path}: '{key}' has non-finite entries")
    return a.astype(dtype)


def rigid(poses: np.ndarray, tol: float = 1e-2) -> np.ndarray:
    """Which of the (..., 4, 4) matrices ``poses`` are rigid transforms: an orthonormal rotation
    (R^T R = I to ``tol``: loose enough for calibrations rounded to 3 decimals and the head poses
    computed from them, tight enough to refuse a scale, a shear or a zero matrix) with determinant
    +1, and a last row of 0 0 0 1. Returns a bool array of shape (...)."""
    R = poses[..., :3, :3]
    ortho = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-2, -1)) < tol
    return ortho & (np.linalg.det(R) > 0) & (np.abs(poses[..., 3, :] - [0.0, 0.0, 0.0, 1.0]).max(axis=-1) < 1e-6)
