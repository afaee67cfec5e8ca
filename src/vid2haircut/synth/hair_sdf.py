"""Fast numpy signed-distance queries with gradients for hair growth and collisions.

Reads the head's regular SDF grid (``head.sdf_grid``: values (R,R,R) indexed [x,y,z], node
(i,j,k) at ``bbox_min + (i,j,k)/(R-1) * (bbox_max - bbox_min)``) and evaluates the same trilinear
interpolation as ``head.sdf_np`` (outside the box: the value at the nearest box point plus the
distance to the box), together with its analytic gradient, in one gather. Heads without a grid
fall back to ``head.sdf_np`` and central differences.
"""

from __future__ import annotations

import numpy as np

__all__ = ["HeadSDF"]


class HeadSDF:
    """Signed distance to a head and its gradient, for numpy point arrays.

    Example::

        sdf = HeadSDF(head)
        d, g = sdf.value_and_grad(points)   # (M,3) -> (M,), (M,3) unit
    """

    def __init__(self, head) -> None:
        self.head = head
        grid = getattr(head, "sdf_grid", None)
        self._grid = None
        if grid is not None and np.ndim(grid.values) == 3 and min(np.shape(grid.values)) >= 2:
            self._grid = _packed_grid(grid)
        verts = getattr(head, "vertices", None)
        self._aabb = None
        if verts is not None and len(verts):
            v = np.asarray(verts, np.float64)
            self._aabb = (v.min(axis=0), v.max(axis=0))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Signed distance (M,) float64 at points (M,3), metres, negative inside."""
        return self.value_and_grad(x, grad=False)[0]

    def lower_bound(self, x: np.ndarray) -> np.ndarray:
        """(M,) signed distance at points (M,3) inside the mesh's bounding box, and for points
        outside it their distance to the box (a lower bound of the distance to the head)."""
        x = np.asarray(x, np.float64).reshape(-1, 3)
        if self._aabb is None:
            return self(x)
        lo, hi = self._aabb
        gap = np.maximum(np.maximum(lo - x, x - hi), 0.0)
        d = np.sqrt((gap * gap).sum(-1))
        inb = d == 0.0
        d[inb] = self(x[inb])
        return d

    def near(self, x: np.ndarray, margin: float) -> tuple[np.ndarray, np.ndarray]:
        """Points (M,3) closer to the head than ``margin``: (indices (K,), distances (K,)).

        Points farther than ``margin`` from the mesh's bounding box are skipped without a lookup
        (they cannot be that close to the mesh).
        """
        x = np.asarray(x, np.float64).reshape(-1, 3)
        idx = np.arange(len(x))
        if self._aabb is not None:
            lo, hi = self._aabb
            inb = ((x > lo - margin) & (x < hi + margin)).all(-1)
            idx = idx[inb]
        d = self(x[idx])
        keep = d < margin
        return idx[keep], d[keep]

    def value_and_grad(self, x: np.ndarray, grad: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Signed distance (M,) and its unit gradient (M,3) at points (M,3) (float64).

        Where the gradient vanishes the direction from the origin (head centre) is returned.
        With ``grad=False`` the second value is ``None``.
        """
        x = np.asarray(x, np.float64).reshape(-1, 3)
        if self._grid is None:
            return self._fallback(x, grad)
        corners, shape, lo, hi, inv = self._grid
        c = np.minimum(np.maximum(x, lo), hi)
        diff = x - c
        outside = np.sqrt((diff * diff).sum(-1))
        g = ((c - lo) * inv).astype(np.float32)
        i0 = np.minimum(g.astype(np.int32), shape - 2)           # g >= 0, so truncation = floor
        t = g - i0
        cell = (i0[:, 0] * (shape[1] - 1) + i0[:, 1]) * (shape[2] - 1) + i0[:, 2]
        v = corners[cell].reshape(-1, 2, 2, 2)                                     # (M,2,2,2)
        tx, ty, tz = t[:, 0, None, None], t[:, 1, None], t[:, 2]
        vx = v[:, 0] + (v[:, 1] - v[:, 0]) * tx                                    # (M,2,2)
        vxy = vx[:, 0] + (vx[:, 1] - vx[:, 0]) * ty                                # (M,2)
        d = (vxy[:, 0] + (vxy[:, 1] - vxy[:, 0]) * tz).astype(np.float64) + outside
        if not grad:
            return d, None
        gz = (vxy[:, 1] - vxy[:, 0]) * inv[2]
        vy = vx[:, 1] - vx[:, 0]                                                   # (M,2)
        gy = (vy[:, 0] + (vy[:, 1] - vy[:, 0]) * tz) * inv[1]
        dxv = v[:, 1] - v[:, 0]                                                    # (M,2,2)
        dxy = dxv[:, 0] + (dxv[:, 1] - dxv[:, 0]) * ty
        gx = (dxy[:, 0] + (dxy[:, 1] - dxy[:, 0]) * tz) * inv[0]
        gr = np.stack([gx, gy, gz], -1).astype(np.float64)
        out = outside > 0
        if out.any():
            gr[out] = diff[out] / outside[out, None]
        return d, self._normalise(gr, x)

    @staticmethod
    def _normalise(gr: np.ndarray, x: np.ndarray) -> np.ndarray:
        n = np.linalg.norm(gr, axis=-1, keepdims=True)
        radial = x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-9)
        return np.where(n > 1e-9, gr / np.maximum(n, 1e-12), radial)

    def _fallback(self, x: np.ndarray, grad: bool, h: float = 5e-4):
        d = np.asarray(self.head.sdf_np(x), np.float64).reshape(-1)
        if not grad:
            return d, None
        off = np.concatenate([np.eye(3), -np.eye(3)]) * h
        v = np.asarray(self.head.sdf_np((x[None] + off[:, None]).reshape(-1, 3)),
                       np.float64).reshape(6, len(x))
        return d, self._normalise((v[:3] - v[3:]).T / (2 * h), x)


_PACKED: dict[int, tuple] = {}


def _packed_grid(grid) -> tuple:
    """The grid's 8 cell-corner values stored contiguously per cell ((R-1)^3, 8) float32, so one
    row gather serves a trilinear lookup; cached per values array."""
    hit = _PACKED.get(id(grid.values))
    if hit is not None and hit[0] is grid.values:
        return hit[1]
    vals = np.asarray(grid.values, np.float32)
    r = np.array(vals.shape)
    corners = np.stack([vals[dx:r[0] - 1 + dx, dy:r[1] - 1 + dy, dz:r[2] - 1 + dz]
                        for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)], -1).reshape(-1, 8)
    lo = np.asarray(grid.bbox_min, np.float64)
    hi = np.asarray(grid.bbox_max, np.float64)
    packed = (np.ascontiguousarray(corners), r.astype(np.int32), lo, hi, (r - 1) / (hi - lo))
    if len(_PACKED) > 8:
        _PACKED.clear()
    _PACKED[id(grid.values)] = (grid.values, packed)
    return packed
