"""Keeping procedural hair out of the head: root lifting and SDF collision projection."""

from __future__ import annotations

import numpy as np

from .hair_sdf import HeadSDF

__all__ = ["lift_roots", "project_out", "resolve_collisions"]


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


def resolve_collisions(sdf: HeadSDF, points: np.ndarray, margin: float = 1e-3,
                       root_slope: float = 0.5, max_final: int = 8) -> np.ndarray:
    """Push strands (N,P,3) out of the head, keeping segment lengths (follow-the-leader).

    Strands are rebuilt from root to tip, all at once: each point is put at its original segment
    length from the (already fixed) previous point, in the direction of its original position;
    if that lands closer than the margin to the head it is pushed out along the SDF gradient and
    the segment length restored. As each step starts outside the head and moves by one segment,
    a strand can never tunnel through thin parts (neck, ears). A final projection (without length
    restoration) makes every non-root point's signed distance >= 1e-5. Roots are not moved.

    The margin is ``margin`` except near the root, where it grows from 0.2 mm by ``root_slope``
    per metre of arc length (a strand leaves the scalp gradually).

    Returns:
        (N,P,3) float64 strands.
    """
    x = np.asarray(points, np.float64)
    n, p, _ = x.shape
    seg = np.linalg.norm(np.diff(x, axis=1), axis=-1)                       # (N,P-1)
    marg = np.minimum(margin, 2e-4 + root_slope * np.cumsum(seg, axis=1))   # (N,P-1)
    out = np.empty_like(x)
    out[:, 0] = x[:, 0]
    for k in range(1, p):
        prev = out[:, k - 1]
        v = x[:, k] - prev
        nv = np.linalg.norm(v, axis=-1, keepdims=True)
        cand = prev + np.where(nv > 1e-12, v / np.maximum(nv, 1e-12), 0.0) * seg[:, k - 1:k]
        hit, _ = sdf.near(cand, margin)
        if len(hit):
            d, g = sdf.value_and_grad(cand[hit])
            push = marg[hit, k - 1] - d
            sel = push > 0
            hit, push, g = hit[sel], push[sel], g[sel]
            moved = cand[hit] + push[:, None] * g
            w = moved - prev[hit]
            nw = np.linalg.norm(w, axis=-1, keepdims=True)
            cand[hit] = prev[hit] + w / np.maximum(nw, 1e-12) * seg[hit, k - 1:k]
        out[:, k] = cand
    for _ in range(max_final):
        body = out[:, 1:].reshape(-1, 3)
        hit, _ = sdf.near(body, 1e-5)
        if len(hit) == 0:
            break
        body[hit], _ = project_out(sdf, body[hit], np.minimum(marg.reshape(-1)[hit], 1e-4) + 1e-5)
        out[:, 1:] = body.reshape(n, p - 1, 3)
    return out
