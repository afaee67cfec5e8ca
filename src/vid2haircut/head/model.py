"""The head model type shared by the built-in proxy and user-supplied FLAME heads."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from vid2haircut.head import scalp as _scalp
from vid2haircut.head.sdf import SDFGrid, sdf_lookup, sdf_lookup_np

_SDF_LOCK = threading.Lock()

# (N, 3) unit directions from the head centre -> ((N, 3) surface points, (N, 3) unit normals)
RayCaster = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(eq=False)
class HeadModel:
    """A head surface in the canonical head frame (metres; y up, face towards +z, x to the
    subject's left; origin at the head centre for the proxy).

    Fields:
        name: model name, e.g. ``"proxy-v1"``.
        vertices: (V, 3) float32 mesh vertices.
        faces: (F, 3) int64 triangles, outward (counter-clockwise) winding.
        landmarks: (68, 3) float32 iBUG-68 points on the surface, or None when unknown.
        sdf_source: the :class:`SDFGrid` of the mesh, or a function building it (called once, on
            first use of :attr:`sdf_grid`, :meth:`sdf` or :meth:`sdf_np`).
        center: (3,) float32 centre the scalp rays start from.
        caster: casts (N, 3) unit directions from ``center`` onto the surface -> (points, normals).
        params: the shape parameters the model was built with.
        ears_deg: optional ear regions excluded from the scalp mask (see ``scalp_mask_angles``).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    landmarks: np.ndarray | None
    sdf_source: SDFGrid | Callable[[], SDFGrid] = field(repr=False)
    center: np.ndarray
    caster: RayCaster = field(repr=False)
    params: dict = field(default_factory=dict)
    ears_deg: tuple[float, float, float, float] | None = None

    @property
    def sdf_grid(self) -> SDFGrid:
        """The precomputed signed distance grid (built on first access, then kept)."""
        if not isinstance(self.sdf_source, SDFGrid):
            with _SDF_LOCK:
                if not isinstance(self.sdf_source, SDFGrid):
                    self.sdf_source = self.sdf_source()
        return self.sdf_source

    def scalp_uv_to_root(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scalp uv (..., 2) in [0, 1]^2 -> (points (..., 3), normals (..., 3)) float32.

        Points lie on the head surface where the ray from the head centre in the uv's direction
        leaves it; normals are unit and outward.
        """
        uv = np.asarray(uv, dtype=np.float64)
        if uv.shape[-1] != 2:
            raise ValueError(f"scalp uv must have shape (..., 2), got {uv.shape}")
        dirs = _scalp.uv_to_dirs(uv).reshape(-1, 3)
        pts, nrm = self.caster(dirs)
        shape = uv.shape[:-1] + (3,)
        return (np.asarray(pts, np.float32).reshape(shape),
                np.asarray(nrm, np.float32).reshape(shape))

    def scalp_mask(self, res: int) -> np.ndarray:
        """(res, res) bool: True where the texel centre ((i + 0.5) / res) is on the hair-bearing
        scalp; index [row=v, col=u]."""
        return _scalp.scalp_mask(res, ears_deg=self.ears_deg)

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Signed distance, differentiable: (..., 3) tensor -> (...,) metres, negative inside;
        any device/dtype (result matches the input's)."""
        return sdf_lookup(self.sdf_grid, points)

    def sdf_np(self, points: np.ndarray) -> np.ndarray:
        """Signed distance: (..., 3) numpy -> (...,) float32 (same values as :meth:`sdf`)."""
        return sdf_lookup_np(self.sdf_grid, points)

    def to_trimesh(self):
        """The mesh as a ``trimesh.Trimesh`` (no processing)."""
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)
