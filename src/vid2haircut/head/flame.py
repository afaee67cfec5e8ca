"""Loader for a user-supplied FLAME model file and its linear blend skinning (numpy).

The file (FLAME 2020/2023 ``generic_model.pkl``; not shipped) is read through the restricted
unpickler of :mod:`vid2haircut.head.safepickle`. Keys used: ``v_template`` (V,3), ``shapedirs``
(V,3,S) (first ``n_shape`` columns identity, the rest expression), ``posedirs`` (V,3,9(J-1)),
``J_regressor`` (J,V) sparse or dense, ``weights`` (V,J), ``kintree_table`` (2,J), ``f`` (F,3).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vid2haircut.geometry import axis_angle_to_matrix
from vid2haircut.head.safepickle import safe_load_pickle, to_array

_REQUIRED = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")


@dataclass(frozen=True)
class FlameModel:
    """A FLAME-style skinned head model (float64 arrays).

    Fields:
        v_template: (V, 3) template vertices.
        shapedirs: (V, 3, S) shape (first ``n_shape``) and expression blend shapes.
        posedirs: (9 (J-1), 3 V) pose-corrective blend shapes.
        j_regressor: (J, V) joint regressor.
        weights: (V, J) skinning weights.
        parents: (J,) int parent joint per joint, -1 for the root.
        faces: (F, 3) int64 triangles.
        n_shape: number of identity components (300 for FLAME when S = 400).
        source: the file it was loaded from.
    """

    v_template: np.ndarray
    shapedirs: np.ndarray
    posedirs: np.ndarray
    j_regressor: np.ndarray
    weights: np.ndarray
    parents: np.ndarray
    faces: np.ndarray
    n_shape: int
    source: str = ""

    @property
    def n_joints(self) -> int:
        return len(self.parents)

    @property
    def n_expression(self) -> int:
        return self.shapedirs.shape[2] - self.n_shape

    def _coeffs(self, shape: np.ndarray | None, expression: np.ndarray | None) -> np.ndarray:
        coeffs = np.zeros(self.shapedirs.shape[2])
        for vals, start, size, what in ((shape, 0, self.n_shape, "shape"),
                                         (expression, self.n_shape, self.n_expression, "expression")):
            if vals is None:
                continue
            vals = np.asarray(vals, dtype=np.float64).reshape(-1)
            if len(vals) > size:
                raise ValueError(f"{self.source}: {len(vals)} {what} parameters given, model has {size}")
            coeffs[start:start + len(vals)] = vals
        return coeffs

    def forward(self, shape: np.ndarray | None = None, expression: np.ndarray | None = None,
                pose: np.ndarray | None = None, translation: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """Posed vertices and joints.

        Args:
            shape: (<= n_shape,) identity coefficients (missing ones are zero).
            expression: (<= n_expression,) expression coefficients.
            pose: (J, 3) or (3 J,) axis-angle per joint (FLAME: global, neck, jaw, eye L, eye R).
            translation: (3,) added at the end.
        Returns:
            vertices (V, 3) and joints (J, 3), float64.
        """
        nj = self.n_joints
        pose = np.zeros((nj, 3)) if pose is None else np.asarray(pose, dtype=np.float64)
        if pose.size != nj * 3:
            raise ValueError(f"{self.source}: pose needs {nj} x 3 axis-angle values, got {pose.size}")
        rots = axis_angle_to_matrix(pose.reshape(nj, 3))                       # (J, 3, 3)
        v_shaped = self.v_template + self.shapedirs @ self._coeffs(shape, expression)
        joints = self.j_regressor @ v_shaped                                   # (J, 3)
        pose_feat = (rots[1:] - np.eye(3)).reshape(-1)
        v_posed = v_shaped + (pose_feat @ self.posedirs).reshape(-1, 3)
        glob = np.zeros((nj, 4, 4))
        for j in range(nj):
            local = np.eye(4)
            local[:3, :3] = rots[j]
            p = self.parents[j]
            local[:3, 3] = joints[j] - (joints[p] if p >= 0 else 0.0)
            glob[j] = glob[p] @ local if p >= 0 else local
        posed_joints = glob[:, :3, 3].copy()
        rel = glob.copy()
        rel[:, :3, 3] -= np.einsum("jab,jb->ja", glob[:, :3, :3], joints)     # remove rest pose
        per_vertex = np.einsum("vj,jab->vab", self.weights, rel)               # (V, 4, 4)
        verts = np.einsum("vab,vb->va", per_vertex[:, :3, :3], v_posed) + per_vertex[:, :3, 3]
        t = np.zeros(3) if translation is None else np.asarray(translation, dtype=np.float64).reshape(3)
        return verts + t, posed_joints + t

    def vertices(self, shape: np.ndarray | None = None, expression: np.ndarray | None = None,
                 pose: np.ndarray | None = None, translation: np.ndarray | None = None) -> np.ndarray:
        """(V, 3) float64 posed vertices (see :meth:`forward`)."""
        return self.forward(shape, expression, pose, translation)[0]

    def as_head_model(self, shape: np.ndarray | None = None, expression: np.ndarray | None = None,
                      pose: np.ndarray | None = None, landmark_embedding=None,
                      center: np.ndarray | None = None, name: str = "flame", sdf_res: int = 64):
        """A :class:`~vid2haircut.head.HeadModel` of this model in the given state.

        Args:
            shape, expression, pose: as in :meth:`forward`.
            landmark_embedding: None, a (face_idx (68,), bary (68, 3)) pair, or a path to an
                ``.npz`` / ``.pkl`` file with ``lmk_face_idx`` and ``lmk_b_coords`` (68 entries).
            center: (3,) centre of the scalp rays; default the centre of the vertices' bounding box.
            name: model name; sdf_res: SDF grid nodes per axis (built lazily).
        """
        from vid2haircut.head.flame_head import flame_head_model

        verts = self.vertices(shape, expression, pose)
        return flame_head_model(verts, self.faces, landmark_embedding, center, name, sdf_res,
                                params={"source": self.source})


def load_flame(path: str | Path, n_shape: int | None = None) -> FlameModel:
    """Load a FLAME model pickle safely (restricted unpickler, latin1).

    Args:
        path: the ``.pkl`` file.
        n_shape: identity components in ``shapedirs`` (default 300 when there are 400 columns,
            else all columns).
    Raises:
        FileNotFoundError, or ValueError naming the file and the problem (a disallowed class,
        a missing key, inconsistent shapes).
    """
    path = Path(path)
    data = safe_load_pickle(path)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a dict of arrays, got {type(data).__name__}")
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise ValueError(f"{path}: FLAME model is missing key(s) {', '.join(missing)}")
    arr = {k: to_array(data[k], f"{path}: {k}") for k in _REQUIRED}
    v = arr["v_template"].astype(np.float64)
    nv = len(v)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{path}: v_template must be (V, 3), got {v.shape}")
    sd = arr["shapedirs"].astype(np.float64)
    if sd.ndim != 3 or sd.shape[:2] != (nv, 3):
        raise ValueError(f"{path}: shapedirs must be (V, 3, S) with V={nv}, got {sd.shape}")
    jr = arr["J_regressor"].astype(np.float64)
    nj = jr.shape[0]
    if jr.shape != (nj, nv):
        raise ValueError(f"{path}: J_regressor must be (J, {nv}), got {jr.shape}")
    pd = arr["posedirs"].astype(np.float64)
    if pd.shape != (nv, 3, 9 * (nj - 1)):
        raise ValueError(f"{path}: posedirs must be ({nv}, 3, {9 * (nj - 1)}), got {pd.shape}")
    w = arr["weights"].astype(np.float64)
    if w.shape != (nv, nj):
        raise ValueError(f"{path}: weights must be ({nv}, {nj}), got {w.shape}")
    kt = arr["kintree_table"]
    if kt.shape != (2, nj):
        raise ValueError(f"{path}: kintree_table must be (2, {nj}), got {kt.shape}")
    parents = kt[0].astype(np.int64)
    parents[0] = -1
    if np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, nj)):
        raise ValueError(f"{path}: kintree_table parents must precede their children, got {parents}")
    f = arr["f"].astype(np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or f.min() < 0 or f.max() >= nv:
        raise ValueError(f"{path}: f must be (F, 3) indices below {nv}")
    ns = n_shape if n_shape is not None else (300 if sd.shape[2] == 400 else sd.shape[2])
    if not 0 <= ns <= sd.shape[2]:
        raise ValueError(f"{path}: n_shape={ns} exceeds the {sd.shape[2]} blend shapes")
    return FlameModel(v_template=v, shapedirs=sd, posedirs=pd.reshape(-1, pd.shape[2]).T.copy(),
                      j_regressor=jr, weights=w, parents=parents, faces=f, n_shape=ns,
                      source=str(path))
