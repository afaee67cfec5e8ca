"""Exact point-to-mesh distances (with pseudo-normal inside test) and the winding number (numpy)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

# Barycentric sample points per triangle used to pick candidate triangles with a KD-tree.
_SAMPLE_BARY = np.array([[1 / 3, 1 / 3, 1 / 3], [2 / 3, 1 / 6, 1 / 6],
                         [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])


def closest_point_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
                               ) -> tuple[np.ndarray, np.ndarray]:
    """Closest points on triangles (Voronoi-region case analysis), all arrays (N, 3).

    Returns:
        q: (N, 3) closest points.
        feature: (N,) int: 0 interior, 1/2/3 vertex a/b/c, 4/5/6 edge ab/bc/ca.
    """
    ab, ac, ap = b - a, c - a, p - a
    bp, cp = p - b, p - c
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        den = va + vb + vc
        den = np.where(np.abs(den) > 1e-30, den, 1e-30)
        q = a + ab * (vb / den)[:, None] + ac * (vc / den)[:, None]
        feat = np.zeros(len(p), dtype=np.int64)
        cases = []
        # edge bc
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        w = (d4 - d3) / np.where(m, (d4 - d3) + (d5 - d6), 1.0)
        cases.append((m, b + (c - b) * w[:, None], 5))
        # edge ca
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        w = d2 / np.where(m, d2 - d6, 1.0)
        cases.append((m, a + ac * w[:, None], 6))
        # vertex c
        cases.append(((d6 >= 0) & (d5 <= d6), c, 3))
        # edge ab
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        v = d1 / np.where(m, d1 - d3, 1.0)
        cases.append((m, a + ab * v[:, None], 4))
        # vertex b, vertex a (highest priority last)
        cases.append(((d3 >= 0) & (d4 <= d3), b, 2))
        cases.append(((d1 <= 0) & (d2 <= 0), a, 1))
    for m, pt, code in cases:
        q = np.where(m[:, None], pt, q)
        feat = np.where(m, code, feat)
    return q, feat


def _pseudo_normals(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Face normals (F,3), angle-weighted vertex normals (V,3), edge normals per face edge (F,3,3)."""
    tri = v[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
    vn = np.zeros_like(v)
    for k in range(3):
        e1 = tri[:, (k + 1) % 3] - tri[:, k]
        e2 = tri[:, (k + 2) % 3] - tri[:, k]
        cosang = (e1 * e2).sum(1) / np.maximum(np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-30)
        np.add.at(vn, f[:, k], fn * np.arccos(np.clip(cosang, -1, 1))[:, None])
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-30)
    # edges in the order ab, bc, ca
    e = np.stack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], axis=1).reshape(-1, 2)
    _, inv = np.unique(np.sort(e, axis=1), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    en = np.zeros((inv.max() + 1, 3))
    np.add.at(en, inv, np.repeat(fn, 3, axis=0))
    en /= np.maximum(np.linalg.norm(en, axis=1, keepdims=True), 1e-30)
    return fn, vn, en[inv].reshape(-1, 3, 3)


def closest_points_on_mesh(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                           k: int = 16, chunk: int = 20_000
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unsigned distance to a triangle mesh and an outside flag from pseudo-normals.

    Candidate triangles are those owning the ``k`` nearest of 4 sample points per triangle; the
    exact distance to each candidate is taken and the minimum kept.

    Args:
        vertices: (V, 3); faces: (F, 3); points: (N, 3).
    Returns:
        dist: (N,) float64 distances; outside: (N,) bool, True where the point lies on the outer
        side of the closest feature (exact for closed, consistently oriented meshes);
        closest: (N, 3) float64 closest surface points.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return np.zeros(0), np.zeros(0, dtype=bool), np.zeros((0, 3))
    tri = v[f]
    samples = np.einsum("sk,fkd->fsd", _SAMPLE_BARY, tri).reshape(-1, 3)
    owner = np.repeat(np.arange(len(f)), len(_SAMPLE_BARY))
    tree = cKDTree(samples)
    k = min(k, len(samples))
    fn, vn, en = _pseudo_normals(v, f)
    dist = np.empty(len(pts))
    outside = np.empty(len(pts), dtype=bool)
    closest = np.empty((len(pts), 3))
    for s in range(0, len(pts), chunk):
        p = pts[s:s + chunk]
        _, idx = tree.query(p, k=k)
        cand = owner[idx.reshape(len(p), -1)]                    # (n, k)
        pp = np.repeat(p, cand.shape[1], axis=0)
        cf = cand.reshape(-1)
        q, feat = closest_point_on_triangles(pp, tri[cf, 0], tri[cf, 1], tri[cf, 2])
        d = np.linalg.norm(pp - q, axis=1).reshape(len(p), -1)
        best = np.argmin(d, axis=1)
        rows = np.arange(len(p)) * cand.shape[1] + best
        bf, bfeat, bq = cf[rows], feat[rows], q[rows]
        normal = fn[bf].copy()
        for code in (1, 2, 3):
            m = bfeat == code
            normal[m] = vn[f[bf[m], code - 1]]
        for code in (4, 5, 6):
            m = bfeat == code
            normal[m] = en[bf[m], code - 4]
        dist[s:s + chunk] = d[np.arange(len(p)), best]
        outside[s:s + chunk] = ((p - bq) * normal).sum(1) >= 0.0
        closest[s:s + chunk] = bq
    return dist, outside, closest


def winding_number(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                   max_pairs: int = 2_000_000) -> np.ndarray:
    """Generalised winding number of a triangle mesh at points: (N, 3) -> (N,) float64.

    About 1 inside a closed outward-oriented mesh, 0 outside, smooth in between for open meshes.
    """
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[np.asarray(faces, dtype=np.int64)]                   # (F, 3, 3)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(len(pts))
    step = max(1, max_pairs // max(len(tri), 1))
    for s in range(0, len(pts), step):
        r = tri[None] - pts[s:s + step, None, None, :]          # (n, F, 3, 3)
        a, b, c = r[:, :, 0], r[:, :, 1], r[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        num = (a * np.cross(b, c)).sum(-1)
        den = la * lb * lc + (a * b).sum(-1) * lc + (a * c).sum(-1) * lb + (b * c).sum(-1) * la
        out[s:s + step] = np.arctan2(num, den).sum(-1) / (2 * np.pi)
    return out
