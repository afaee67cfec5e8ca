"""Casting rays from a centre point onto a general triangle mesh (numpy, no external BVH).

Used for heads that are not star-shaped by construction (FLAME): the scalp root of a direction is
the FARTHEST hit of the ray from the centre, so inner parts (eyeballs, mouth bag) are skipped.
Candidate triangles per ray are found with a KD-tree over the triangles' unit directions seen
from the centre.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def ray_triangle_hits(origin: np.ndarray, dirs: np.ndarray, a: np.ndarray, b: np.ndarray,
                      c: np.ndarray, eps: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Moller-Trumbore intersection of rays ``origin + t * dirs`` with triangles, paired row-wise.

    Args:
        origin: (3,) ray origin; dirs: (N, 3); a, b, c: (N, 3) triangle corners.
    Returns:
        t: (N,) hit distance along the ray (NaN for a miss or t <= 0); bary: (N, 3) barycentrics.
    """
    e1, e2 = b - a, c - a
    pvec = np.cross(dirs, e2)
    det = (e1 * pvec).sum(1)
    ok = np.abs(det) > eps
    inv = 1.0 / np.where(ok, det, 1.0)
    tvec = origin - a
    u = (tvec * pvec).sum(1) * inv
    qvec = np.cross(tvec, e1)
    v = (dirs * qvec).sum(1) * inv
    t = (e2 * qvec).sum(1) * inv
    hit = ok & (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9) & (t > 0)
    return np.where(hit, t, np.nan), np.stack([1 - u - v, u, v], axis=1)


class CentreRayCaster:
    """Casts rays from a fixed centre onto a triangle mesh; callable as a ``RayCaster``."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, center: np.ndarray) -> None:
        """vertices (V, 3), faces (F, 3), center (3,) -- all in the same frame."""
        self.v = np.asarray(vertices, dtype=np.float64)
        self.f = np.asarray(faces, dtype=np.int64)
        self.center = np.asarray(center, dtype=np.float64)
        rel = self.v - self.center
        udir = rel / np.maximum(np.linalg.norm(rel, axis=1, keepdims=True), 1e-12)
        tri_dirs = udir[self.f]                                   # (F, 3, 3)
        cen = tri_dirs.mean(1)
        cen /= np.maximum(np.linalg.norm(cen, axis=1, keepdims=True), 1e-12)
        # chord radius of each triangle's direction cone, seen from the centre
        rad = np.linalg.norm(tri_dirs - cen[:, None], axis=-1).max(1)
        self.wide = np.nonzero(rad > 0.3)[0]          # huge ones (near the centre): test always
        narrow = np.nonzero(rad <= 0.3)[0]
        self.narrow = narrow
        self.radius = float(rad[narrow].max()) if len(narrow) else 0.0
        self.tree = cKDTree(cen[narrow]) if len(narrow) else None
        fn = np.cross(self.v[self.f[:, 1]] - self.v[self.f[:, 0]], self.v[self.f[:, 2]] - self.v[self.f[:, 0]])
        vn = np.zeros_like(self.v)
        for k in range(3):
            np.add.at(vn, self.f[:, k], fn)                       # area-weighted vertex normals
        self.vn = vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-30)
        self.udir = udir

    def __call__(self, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) unit directions -> (points (N, 3), unit normals (N, 3)) float64.

        A ray that misses the mesh (e.g. through an open neck) falls back to the vertex whose
        direction is closest to the ray's.
        """
        d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        best_t = np.full(len(d), -np.inf)
        best_f = np.zeros(len(d), dtype=np.int64)
        best_b = np.zeros((len(d), 3))
        cand_lists = self.tree.query_ball_point(d, self.radius + 1e-6) if self.tree is not None else [[]] * len(d)
        rays = np.concatenate([np.full(len(c) + len(self.wide), i) for i, c in enumerate(cand_lists)]).astype(np.int64)
        tris = np.concatenate([np.concatenate([self.narrow[np.asarray(c, dtype=np.int64)], self.wide])
                               for c in cand_lists]).astype(np.int64)
        for s in range(0, len(rays), 500_000):
            r, tr = rays[s:s + 500_000], tris[s:s + 500_000]
            corners = self.v[self.f[tr]]
            t, bary = ray_triangle_hits(self.center, d[r], corners[:, 0], corners[:, 1], corners[:, 2])
            t = np.where(np.isnan(t), -np.inf, t)
            order = np.lexsort((t, r))                 # per ray, the largest t comes last
            r_o = r[order]
            last = np.r_[r_o[1:] != r_o[:-1], True]
            sel = order[last]
            better = t[sel] > best_t[r[sel]]
            idx = r[sel][better]
            best_t[idx] = t[sel][better]
            best_f[idx] = tr[sel][better]
            best_b[idx] = bary[sel][better]
        hit = np.isfinite(best_t)
        pts = self.center + d * np.where(hit, best_t, 0.0)[:, None]
        nrm = (self.vn[self.f[best_f]] * best_b[:, :, None]).sum(1)
        if (~hit).any():
            nearest = np.argmax(d[~hit] @ self.udir.T, axis=1)
            pts[~hit] = self.v[nearest]
            nrm[~hit] = self.vn[nearest]
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
        return pts, nrm
