"""Keeping procedural hair out of the head: root lifting and SDF collision projection."""

from __future__ import annotations

import numpy as np

from .hair_sdf import HeadSDF

__all__ = ["lift_roots", "project_out", "follow_the_leader", "resolve_collisions"]


def lift_roots(sdf: HeadSDF, points: np.ndarray, normals: np.ndarray, clearance: float = 2e-4,
               iters: int = 4) -> np.ndarray:
    """Move surface points (N,3) along their normals (N,3) until the signed distance is >= ``clearance``
    (``sdf`` the head's signed distance; the SDF grid's interpolation error can put exact surface points slightly inside).

    Returns:
        (N,3) float64 points, each within a fraction of a millimetre of the input.
    """
    x = np.asarray(points, np.float64).copy()
    nrm = np.asarray(normals, np.float64)
    for _ in range(iters):
        d = sdf(x)
        need = d < clearance
        if not need.any():
            break
        x[need] += (clearance - d[need] + 1e-5)[:, None] * nrm[need]
    return x


def project_out(sdf: HeadSDF, x: np.ndarray, margin: float | np.ndarray) -> tuple[np.ndarray, int]:
    """Move points (M,3) closer than ``margin`` (scalar or (M,)) to the head out along the SDF
    gradient to that distance.

    Returns:
        (new points (M,3) float64, number of points moved).
    """
    out = np.asarray(x, np.float64).copy()
    m = np.broadcast_to(np.asarray(margin, np.float64), (len(out),))
    near, _ = sdf.near(out, float(m.max()) if len(m) else 0.0)
    if len(near):
        d, g = sdf.value_and_grad(out[near])
        push = m[near] - d
        keep = push > 0
        out[near[keep]] += push[keep, None] * g[keep]
        return out, int(keep.sum())
    return out, 0


def follow_the_leader(points: np.ndarray, seg_len: np.ndarray) -> np.ndarray:
    """Restore segment lengths (N,P-1) root to tip, keeping each segment's current direction.

    Args:
        points: (N,P,3) strands; the roots stay fixed.
        seg_len: (N,P-1) target segment lengths.

    Returns:
        (N,P,3) float64 strands with exactly those segment lengths.
    """
    x = np.asarray(points, np.float64).copy()
    for k in range(1, x.shape[1]):
        v = x[:, k] - x[:, k - 1]
        nv = np.linalg.norm(v, axis=-1, keepdims=True)
        x[:, k] = x[:, k - 1] + np.where(nv > 1e-12, v / np.maximum(nv, 1e-12), 0.0) * seg_len[:, k - 1:k]
    return x


def resolve_collisions(sdf: HeadSDF, points: np.ndarray, margin: float = 1e-3, iters: int = 3,
                       max_final: int = 8, root_slope: float = 0.5) -> np.ndarray:
    """Push strands (N,P,3) out of the head, keeping segment lengths roughly constant.

    ``iters`` rounds of (projection of all non-root points to their margin outside the head, then
    follow-the-leader length restoration), then projection alone until every non-root point has
    a signed distance >= 1e-5 (at most ``max_final`` rounds). Roots are not moved. The margin is
    ``margin`` except near the root, where it grows from 0.2 mm by ``root_slope`` per metre of
    arc length (a strand necessarily leaves the scalp gradually).

    Only points that may have come close are looked up again: a point whose distance at the
    last full evaluation, minus how far it has moved since, is still above its margin is skipped
    (the distance is 1-Lipschitz).

    Returns:
        (N,P,3) float64 strands.
    """
    x = np.asarray(points, np.float64).copy()
    n, p, _ = x.shape
    seg = np.linalg.norm(np.diff(x, axis=1), axis=-1)
    marg = np.minimum(margin, 2e-4 + root_slope * np.cumsum(seg, axis=1)).reshape(-1)  # (N*(P-1),)
    ref = x[:, 1:].reshape(-1, 3).copy()
    d_ref = sdf.lower_bound(ref)

    def project(final: bool) -> int:
        body = x[:, 1:].reshape(-1, 3)
        thr = np.full_like(marg, 1e-5) if final else marg
        moved_by = np.linalg.norm(body - ref, axis=-1)
        cand = np.nonzero(d_ref - moved_by < thr + 1e-6)[0]
        if len(cand) == 0:
            return 0
        if final:                                     # only points below the final threshold
            hit, _ = sdf.near(body[cand], 1e-5)
            cand = cand[hit]
        body[cand], moved = project_out(sdf, body[cand], marg[cand])
        x[:, 1:] = body.reshape(n, p - 1, 3)
        return moved

    for _ in range(iters):
        if project(False) == 0:
            return x
        x[:] = follow_the_leader(x, seg)
    for _ in range(max_final):
        if project(True) == 0:
            break
    return x
