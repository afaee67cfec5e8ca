"""``head.npz``: the fitted head of a sequence, and how to resolve a head-model name.

``head.npz`` keys::

    head_model            () str    head model name ("proxy-v1") or FLAME file path
    shape_names           (3,) str  ("scale", "width", "depth")
    shape                 (3,) float64 the shape factors (landmarks scaled per axis by
                                     (scale*width, scale, scale*depth); for "proxy-v1" they are
                                     get_head()'s arguments of the same names)
    frames                (M,) int64 keyframe indices (frames without a face are left out)
    world_from_head       (M, 4, 4) float64 rigid head pose per frame (x_world = R x_head + t)
    reprojection_error_px (M,) float64 mean landmark reprojection error (inlier landmarks)
    landmarks_2d          (M, 68, 2) float32 observed landmarks (NaN if unknown)
    inliers               (M, 68) bool landmarks used by the fit
    source                () str    "landmarks" (fitted) or "tracking" (tracking/head_tracking.npz)
    serial                () str    camera serial
    landmark_embedding    () str    FLAME landmark embedding path ("" for built-in heads)
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from vid2haircut.front.pose import SHAPE_NAMES, HeadFit
from vid2haircut.checks import float_array, frame_numbers, rigid


def resolve_head(spec: str, shape: np.ndarray | None = None, landmark_embedding: str | None = None):
    """Head model from a name ("proxy-v1") or a user-supplied FLAME model file path.

    Args:
        spec: built-in head name, or the path of a FLAME ``.pkl`` (used at its template shape).
        shape: optional (scale, width, depth) factors, passed on to the built-in proxy.
        landmark_embedding: FLAME only: the ``.npz`` / ``.pkl`` landmark embedding giving its 68
            iBUG landmarks (``lmk_face_idx``, ``lmk_b_coords``).
    """
    from vid2haircut.head import HEAD_NAMES, get_head

    if spec in HEAD_NAMES:
        if landmark_embedding:
            raise ValueError(f"{landmark_embedding}: a landmark embedding is for a FLAME model; the built-in head "
                             f"{spec!r} has its own landmarks (leave --landmark-embedding out, or give the FLAME .pkl)")
        if shape is None:
            return get_head(spec)
        s, w, d = (float(v) for v in shape)
        return get_head(spec, scale=s, width=w, depth=d)
    p = Path(spec)
    if p.suffix == ".pkl" or p.is_file():
        if not p.is_file():
            raise FileNotFoundError(f"{p}: FLAME model file not found")
        return _flame_head(str(p), landmark_embedding or None)
    raise ValueError(f"unknown head model {spec!r} (known: {', '.join(HEAD_NAMES)}, or a FLAME .pkl path)")


@functools.lru_cache(maxsize=4)
def _flame_head(path: str, landmark_embedding: str | None):
    from vid2haircut.head import load_flame

    return load_flame(path).as_head_model(landmark_embedding=landmark_embedding)


def base_landmarks(spec: str, landmark_embedding: str | None = None) -> np.ndarray:
    """(68, 3) float64 landmarks of the head model at shape factors 1 (head frame, metres)."""
    lm = resolve_head(spec, landmark_embedding=landmark_embedding).landmarks
    if lm is None:
        raise ValueError(f"{spec}: the head model has no landmarks (a FLAME model needs its landmark "
                         "embedding file, e.g. --landmark-embedding landmark_embedding.npz)")
    return np.asarray(lm, dtype=np.float64)


def save_head_fit(path: str | Path, fit: HeadFit, serial: str, source: str = "landmarks",
                  landmark_embedding: str | None = None) -> None:
    """Write ``head.npz`` atomically (keys in the module docstring)."""
    from vid2haircut.io.atomic import write_npz

    write_npz(path, head_model=np.array(fit.head_model), shape_names=np.array(SHAPE_NAMES),
              shape=np.asarray(fit.shape, np.float64), frames=np.asarray(fit.frames, np.int64),
              world_from_head=np.asarray(fit.world_from_head, np.float64),
              reprojection_error_px=np.asarray(fit.reprojection_error_px, np.float64),
              landmarks_2d=np.asarray(fit.landmarks_2d, np.float32),
              inliers=np.asarray(fit.inliers, bool), source=np.array(source), serial=np.array(str(serial)),
              landmark_embedding=np.array(str(landmark_embedding or "")))


def load_head_fit(path: str | Path) -> tuple[HeadFit, dict]:
    """Read ``head.npz`` -> (HeadFit, {"source", "serial", "landmark_embedding"}); errors name the file."""
    from vid2haircut.head import HEAD_NAMES

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: head fit file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except Exception as e:
        raise ValueError(f"{path}: not a readable .npz file ({type(e).__name__}: {e})") from None
    need = ("head_model", "shape", "frames", "world_from_head", "reprojection_error_px")
    missing = [k for k in need if k not in d]
    if missing:
        raise ValueError(f"{path}: missing key(s) {missing}")
    frames = frame_numbers(d["frames"], path)
    m = len(frames)
    if m == 0:
        raise ValueError(f"{path}: no frames (the head fit kept no keyframe)")
    poses = float_array(d["world_from_head"], path, "world_from_head", (m, 4, 4))
    ok = rigid(poses)
    if not ok.all():
        raise ValueError(f"{path}: world_from_head of frames {frames[~ok][:5].tolist()} is not a rigid "
                         "transform (rotation and translation, last row 0 0 0 1)")
    shape = d["shape"]
    if shape.shape != (3,) or shape.dtype.kind not in "fiu" or not (np.isfinite(shape).all() and (shape > 0).all()):
        raise ValueError(f"{path}: shape must be 3 positive factors {SHAPE_NAMES}, got {shape.tolist()}")
    head_model = str(d["head_model"])
    if not (head_model in HEAD_NAMES or head_model.endswith(".pkl") or Path(head_model).is_file()):
        raise ValueError(f"{path}: unknown head model {head_model!r} (built-in: {', '.join(HEAD_NAMES)}, "
                         "or a FLAME .pkl path)")
    err = float_array(d["reprojection_error_px"], path, "reprojection_error_px", (m,), finite=False)
    inliers = d.get("inliers", np.ones((m, 68), bool))
    if inliers.shape != (m, 68):
        raise ValueError(f"{path}: 'inliers' must have shape ({m}, 68), got {inliers.shape}")
    l2d = d.get("landmarks_2d", np.full((m, 68, 2), np.nan, np.float32))
    l2d = float_array(l2d, path, "landmarks_2d", (m, 68, 2), finite=False, dtype=np.float32)
    fit = HeadFit(head_model=head_model, shape=d["shape"].astype(np.float64), frames=frames, world_from_head=poses,
                  reprojection_error_px=err, inliers=inliers.astype(bool), landmarks_2d=l2d)
    return fit, {"source": str(d.get("source", "landmarks")), "serial": str(d.get("serial", "")),
                 "landmark_embedding": str(d.get("landmark_embedding", "")) or None}
