"""A :class:`HeadModel` from an arbitrary triangle mesh (a posed FLAME head)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vid2haircut.head.meshcast import CentreRayCaster
from vid2haircut.head.model import HeadModel
from vid2haircut.head.safepickle import safe_load_pickle, to_array
from vid2haircut.head.sdf import SDFGrid, build_sdf_grid


def load_landmark_embedding(src) -> tuple[np.ndarray, np.ndarray]:
    """Landmark embedding -> (face_idx (68,) int64, bary (68, 3) float64).

    ``src`` is a (face_idx, bary) pair or a path to an ``.npz`` / ``.pkl`` file holding
    ``lmk_face_idx`` and ``lmk_b_coords`` (pickles go through the restricted unpickler).
    """
    if isinstance(src, (str, Path)):
        path = Path(src)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such landmark embedding file")
        if path.suffix == ".npz":
            try:
                with np.load(path, allow_pickle=False) as z:
                    data = {k: z[k] for k in z.files}
            except (OSError, ValueError, EOFError) as e:
                raise ValueError(f"{path}: not a readable .npz landmark embedding ({e})") from None
        else:
            data = safe_load_pickle(path)
        if not isinstance(data, dict) or "lmk_face_idx" not in data or "lmk_b_coords" not in data:
            raise ValueError(f"{path}: landmark embedding needs keys lmk_face_idx and lmk_b_coords")
        face_idx, bary = to_array(data["lmk_face_idx"]), to_array(data["lmk_b_coords"])
        where = str(path)
    else:
        face_idx, bary = (np.asarray(x) for x in src)
        where = "landmark embedding"
    face_idx = face_idx.astype(np.int64).reshape(-1)
    bary = bary.astype(np.float64)
    if face_idx.shape != (68,) or bary.shape != (68, 3):
        raise ValueError(f"{where}: need 68 face indices and (68, 3) barycentrics, "
                         f"got {face_idx.shape} and {bary.shape}")
    return face_idx, bary


def flame_head_model(vertices: np.ndarray, faces: np.ndarray, landmark_embedding=None,
                     center: np.ndarray | None = None, name: str = "flame", sdf_res: int = 64,
                     params: dict | None = None) -> HeadModel:
    """Wrap a triangle mesh as a HeadModel.

    Args:
        vertices: (V, 3) metres; faces: (F, 3).
        landmark_embedding: see :func:`load_landmark_embedding`, or None (landmarks None).
        center: (3,) ray centre for the scalp; default the bounding-box centre.
        sdf_res: SDF grid nodes per axis; the grid (sign from pseudo-normals) is built lazily.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"{name}: face indices out of range for {len(v)} vertices")
    lm = None
    if landmark_embedding is not None:
        face_idx, bary = load_landmark_embedding(landmark_embedding)
        if face_idx.max() >= len(f) or face_idx.min() < 0:
            raise ValueError(f"{name}: landmark face index out of range for {len(f)} faces")
        lm = np.einsum("lk,lkd->ld", bary, v[f[face_idx]]).astype(np.float32)
    c = (v.min(0) + v.max(0)) / 2 if center is None else np.asarray(center, np.float64).reshape(3)

    def make_sdf() -> SDFGrid:
        return build_sdf_grid(v, f, inside=None, res=sdf_res)

    return HeadModel(name=name, vertices=v.astype(np.float32), faces=f, landmarks=lm,
                     sdf_source=make_sdf, center=c.astype(np.float32),
                     caster=CentreRayCaster(v, f, c), params=dict(params or {}))
