"""Scalp texel grids of a head model: texel centres in scalp UV, their root points, cached per res.

Texel ``[row, col]`` of a ``res x res`` map has its centre at ``uv = ((col+0.5)/res,
(row+0.5)/res)`` (rows follow v, columns follow u, as in ``HeadModel.scalp_mask``). Flat texel
indices are row-major: ``row * res + col``.

The scalp UV convention (head contract): for a point seen from the head centre (``head.center``, the
origin of the canonical frame for the proxy head) with polar angle theta from +y and azimuth phi = atan2(x, z),
``rho = theta / (2*pi/3)``, ``u = 0.5 + 0.5 rho sin(phi)``, ``v = 0.5 + 0.5 rho cos(phi)``.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

__all__ = ["ScalpGrid", "scalp_grid", "scalp_mask_cached", "points_to_scalp_uv", "uv_area_weight",
           "texel_centres"]

_THETA_MAX = 2.0 * math.pi / 3.0
_GRID_CACHE: dict[tuple[int, int], tuple[Any, "ScalpGrid"]] = {}
_MASK_CACHE: dict[tuple[int, int], tuple[Any, np.ndarray]] = {}
_CACHE_MAX = 16


class ScalpGrid(NamedTuple):
    """Scalp texels of one head at one resolution.

    Attributes:
        res: map resolution H = W.
        valid: (H,W) bool, texel centre on the hair-bearing scalp.
        uv: (H,W,2) float32 texel-centre UVs.
        roots: (H,W,3) float32 surface points at the texel centres (all texels, valid or not).
        normals: (H,W,3) float32 unit outward normals there.
        index: (Nv,) int64 row-major flat indices of the valid texels (ascending).
    """

    res: int
    valid: np.ndarray
    uv: np.ndarray
    roots: np.ndarray
    normals: np.ndarray
    index: np.ndarray


def texel_centres(res: int) -> np.ndarray:
    """(res,res,2) float32 UV of texel centres, ``[row, col] -> ((col+.5)/res, (row+.5)/res)``."""
    c = (np.arange(res, dtype=np.float64) + 0.5) / res
    u, v = np.meshgrid(c, c, indexing="xy")                             # u varies along columns
    return np.stack([u, v], axis=-1).astype(np.float32)


def _remember(cache: dict, key: tuple[int, int], head: Any, value: Any) -> None:
    if len(cache) >= _CACHE_MAX:
        cache.pop(next(iter(cache)))
    cache[key] = (head, value)  # keep the head alive so that id(head) cannot be reused


def scalp_mask_cached(head: Any, res: int) -> np.ndarray:
    """``head.scalp_mask(res)`` as (res,res) bool, cached per (head object, res)."""
    key = (id(head), int(res))
    hit = _MASK_CACHE.get(key)
    if hit is not None and hit[0] is head:
        return hit[1]
    mask = np.asarray(head.scalp_mask(int(res)), dtype=bool)
    if mask.shape != (res, res):
        raise ValueError(f"head {getattr(head, 'name', head)!r}: scalp_mask({res}) has shape {mask.shape}")
    _remember(_MASK_CACHE, key, head, mask)
    return mask


def scalp_grid(head: Any, res: int) -> ScalpGrid:
    """Texel centres, validity and root points of a ``res x res`` scalp map (cached).

    Args:
        head: a head model (``scalp_mask``, ``scalp_uv_to_root``; see the head contract).
        res: map resolution, >= 2.

    Returns:
        The :class:`ScalpGrid`; the same object for repeated calls with the same head and res.
    """
    res = int(res)
    if res < 2:
        raise ValueError(f"scalp_grid: res must be >= 2, got {res}")
    key = (id(head), res)
    hit = _GRID_CACHE.get(key)
    if hit is not None and hit[0] is head:
        return hit[1]
    valid = scalp_mask_cached(head, res)
    uv = texel_centres(res)
    roots, normals = head.scalp_uv_to_root(uv.reshape(-1, 2))
    grid = ScalpGrid(res, valid, uv, np.asarray(roots, np.float32).reshape(res, res, 3),
                     np.asarray(normals, np.float32).reshape(res, res, 3),
                     np.flatnonzero(valid.ravel()).astype(np.int64))
    _remember(_GRID_CACHE, key, head, grid)
    return grid


def points_to_scalp_uv(points: np.ndarray, center: np.ndarray | None = None) -> np.ndarray:
    """Scalp UV of points in the canonical head frame (inverse of the UV -> root direction).

    Args:
        points: (...,3) points (e.g. strand roots), not at ``center``.
        center: (3,) centre the scalp rays start from (``head.center``; default the origin).

    Returns:
        (...,2) float32 UV. Points beyond 120 deg from the crown get rho > 1 (UV outside the disk).
    """
    p = np.asarray(points, np.float64)
    if center is not None:
        p = p - np.asarray(center, np.float64).reshape(3)
    r = np.linalg.norm(p, axis=-1)
    theta = np.arccos(np.clip(p[..., 1] / np.maximum(r, 1e-12), -1.0, 1.0))
    phi = np.arctan2(p[..., 0], p[..., 2])
    rho = theta / _THETA_MAX
    return np.stack([0.5 + 0.5 * rho * np.sin(phi), 0.5 + 0.5 * rho * np.cos(phi)], -1).astype(np.float32)


def uv_area_weight(uv: np.ndarray) -> np.ndarray:
    """Relative surface area per unit UV area of the polar scalp projection, ``sin(theta)/theta``.

    Used to sample roots uniformly on the scalp surface rather than uniformly in UV (for a
    sphere-like head the area element is ``r^2 sin(theta) dtheta dphi`` while UV area is
    ``~ theta dtheta dphi``).

    Args:
        uv: (...,2) UV.

    Returns:
        (...,) float64 weights in (0, 1], 1 at the crown.
    """
    uv = np.asarray(uv, np.float64)
    rho = 2.0 * np.linalg.norm(uv - 0.5, axis=-1)
    theta = rho * _THETA_MAX
    return np.where(theta > 1e-6, np.sin(theta) / np.maximum(theta, 1e-6), 1.0)
