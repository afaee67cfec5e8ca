"""Signed distance grid of a head mesh and its differentiable trilinear lookup.

The grid stores the exact distance to the triangle mesh at every node near the surface (closest
point on the nearest candidate triangles) and, further away, the distance to the closest surface
point of the nearest near-surface node, signed by an inside test: the proxy's exact
radial test, or for general meshes angle-weighted pseudo-normals near the surface, propagated
outwards.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from vid2haircut.head.meshdist import closest_points_on_mesh


class SDFGrid(NamedTuple):
    """Regular signed distance grid.

    Fields:
        values: (R, R, R) float32 signed distances in metres (negative inside), indexed [x, y, z];
            node (i, j, k) lies at ``bbox_min + (i, j, k) / (R - 1) * (bbox_max - bbox_min)``.
        bbox_min: (3,) float32 corner of the grid (metres).
        bbox_max: (3,) float32 opposite corner.
    """

    values: np.ndarray
    bbox_min: np.ndarray
    bbox_max: np.ndarray


def grid_nodes(bbox_min: np.ndarray, bbox_max: np.ndarray, res: int) -> np.ndarray:
    """(R, R, R, 3) float64 node positions of a grid (indexing [x, y, z])."""
    axes = [np.linspace(bbox_min[k], bbox_max[k], res) for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def build_sdf_grid(vertices: np.ndarray, faces: np.ndarray,
                   inside: Callable[[np.ndarray], np.ndarray] | None = None,
                   res: int = 80, margin: float = 0.05) -> SDFGrid:
    """Precompute the signed distance of a triangle mesh on a regular grid.

    Nodes in a band around the surface (about one node diagonal) get the exact
    point-triangle distance; every other node takes the distance to the closest surface point of
    its nearest band node (Euclidean feature transform), which is exact up to a tiny error far
    away where it does not matter.

    Args:
        vertices: (V, 3) mesh vertices in metres.
        faces: (F, 3) triangle indices.
        inside: optional exact inside test, (N, 3) points -> (N,) bool. Without it the sign comes
            from angle-weighted pseudo-normals in the band and is propagated outwards from the
            nearest band node (robust for closed meshes, a best effort for open ones).
        res: nodes per axis R.
        margin: the grid extends this far (metres) beyond the mesh bounding box.
    Returns:
        the :class:`SDFGrid`.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"SDF needs (V,3) vertices and (F,3) faces, got {v.shape} and {f.shape}")
    lo = v.min(axis=0) - margin
    hi = v.max(axis=0) + margin
    spacing = (hi - lo) / (res - 1)
    nodes = grid_nodes(lo, hi, res).reshape(-1, 3)
    edge = np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1).max()
    band = float(np.linalg.norm(spacing)) + 0.6 * float(edge)
    dist_v, _ = cKDTree(v).query(nodes, k=1, distance_upper_bound=band)
    near = np.isfinite(dist_v)
    near_idx = np.nonzero(near)[0]
    near_dist, near_out, near_q = closest_points_on_mesh(v, f, nodes[near_idx], k=8)
    # Feature transform: every node -> its nearest band node (in metres, anisotropic spacing).
    _, ft = distance_transform_edt(~near.reshape(res, res, res), sampling=spacing,
                                   return_indices=True)
    src = np.ravel_multi_index(tuple(ft.reshape(3, -1)), (res, res, res))
    slot = np.full(len(nodes), -1, dtype=np.int64)
    slot[near_idx] = np.arange(len(near_idx))
    src_slot = slot[src]
    q = near_q[src_slot]
    dist = np.linalg.norm(nodes - q, axis=1)
    dist[near_idx] = near_dist
    if inside is not None:
        is_in = np.asarray(inside(nodes), dtype=bool)
    else:
        is_in = ~near_out[src_slot]
    values = np.where(is_in, -dist, dist).reshape(res, res, res).astype(np.float32)
    return SDFGrid(values, lo.astype(np.float32), hi.astype(np.float32))


# (id of values, device, dtype) -> (the values array itself, values, bbox_min, bbox_max tensors)
_TORCH_CACHE: dict[tuple[int, str, torch.dtype], tuple] = {}


def _grid_tensors(grid: SDFGrid, device: torch.device, dtype: torch.dtype
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The grid as tensors on ``device``/``dtype``, cached per grid array."""
    key = (id(grid.values), str(device), dtype)
    hit = _TORCH_CACHE.get(key)
    if hit is None or hit[0] is not grid.values:
        hit = (grid.values,
               torch.as_tensor(grid.values, dtype=dtype, device=device),
               torch.as_tensor(grid.bbox_min, dtype=dtype, device=device),
               torch.as_tensor(grid.bbox_max, dtype=dtype, device=device))
        if len(_TORCH_CACHE) > 32:
            _TORCH_CACHE.clear()
        _TORCH_CACHE[key] = hit
    return hit[1], hit[2], hit[3]


def sdf_lookup(grid: SDFGrid, points: torch.Tensor) -> torch.Tensor:
    """Differentiable trilinear lookup of a grid.

    Args:
        grid: the :class:`SDFGrid` (any scalar field on a grid).
        points: (..., 3) tensor on any device, float dtype (float64 keeps float64).
    Returns:
        (...,) tensor, same device/dtype: the interpolated value; outside the grid the value at
        the nearest box point plus the distance to the box (so far points are positive).
    """
    if not torch.is_floating_point(points):
        points = points.to(torch.get_default_dtype())
    values, lo, hi = _grid_tensors(grid, points.device, points.dtype)
    clamped = torch.minimum(torch.maximum(points, lo), hi)
    outside = torch.linalg.vector_norm(points - clamped, dim=-1)
    # one fused trilinear gather (C++/CUDA kernels with their own backward): values[i, j, k] is
    # grid_sample's input[d=i, h=j, w=k], whose sampling coordinates are ordered (w, h, d) in [-1, 1]
    g = (clamped - lo) / (hi - lo) * 2.0 - 1.0
    flat = g.reshape(1, 1, 1, -1, 3).flip(-1)
    out = F.grid_sample(values[None, None], flat, mode="bilinear", padding_mode="border", align_corners=True)
    return out.reshape(points.shape[:-1]) + outside


def sdf_lookup_np(grid: SDFGrid, points: np.ndarray) -> np.ndarray:
    """Numpy version of :func:`sdf_lookup`: (..., 3) points -> (...,) float32."""
    with torch.no_grad():
        p = torch.as_tensor(np.asarray(points, dtype=np.float32))
        return sdf_lookup(grid, p).numpy().astype(np.float32)
