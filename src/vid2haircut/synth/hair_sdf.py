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
        if grid is not None:
            vals = np.asarray(grid.values, np.float64)
            if vals.ndim == 3 and min(vals.shape) >= 2:
                lo = np.asarray(grid.bbox_min, np.float64)
                hi = np.asarray(grid.bbox_max, np.float64)
                self._grid = (vals.ravel(), np.array(vals.shape), lo, hi,
                              (np.array(vals.shape) - 1) / (hi - lo))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Signed distance (M,) float64 at points (M,3), metres, negative inside."""
        return self.value_and_grad(x, grad=False)[0]

    def value_and_grad(self, x: np.ndarray, grad: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Signed distance (M,) and its unit gradient (M,3) at points (M,3) (float64).

        Where the gradient vanishes the direction from the origin (head centre) is returned.
        With ``grad=False`` the second value is ``None``.
        """
        x = np.asarray(x, np.float64).reshape(-1, 3)
        if self._grid is None:
            return self._fallback(x, grad)
        flat, shape, lo, hi, inv = self._grid
        c = np.minimum(np.maximum(x, lo), hi)
        diff = x - c
        outside = np.sqrt((diff * diff).sum(-1))
        g = (c - lo) * inv
        i0 = np.clip(np.floor(g).astype(np.int64), 0, shape - 2)
        t = g - i0
        s1, s2 = int(shape[1]), int(shape[2])
        base = (i0[:, 0] * s1 + i0[:, 1]) * s2 + i0[:, 2]
        v = np.stack([flat[base + (dx * s1 + dy) * s2 + dz]
                      for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)], -1)     # (M,8)
        v = v.reshape(-1, 2, 2, 2)
        tx, ty, tz = t[:, 0, None, None], t[:, 1, None], t[:, 2]
        vx = v[:, 0] * (1 - tx) + v[:, 1] * tx                                     # (M,2,2)
        vxy = vx[:, 0] * (1 - ty) + vx[:, 1] * ty                                  # (M,2)
        d = vxy[:, 0] * (1 - tz) + vxy[:, 1] * tz + outside
        if not grad:
            return d, None
        gz = (vxy[:, 1] - vxy[:, 0]) * inv[2]
        vy = vx[:, 1] - vx[:, 0]                                                   # (M,2)
        gy = (vy[:, 0] * (1 - tz) + vy[:, 1] * tz) * inv[1]
        dxv = v[:, 1] - v[:, 0]                                                    # (M,2,2)
        dxy = dxv[:, 0] * (1 - ty) + dxv[:, 1] * ty
        gx = (dxy[:, 0] * (1 - tz) + dxy[:, 1] * tz) * inv[0]
        gr = np.stack([gx, gy, gz], -1)
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
