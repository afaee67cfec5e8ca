"""Polyline operations on strand arrays: arc-length resampling, tangents, length variation, cutting
and tip scatter.

Plain numpy on (N,P,3) arrays (root first, metres) or lists of (P_i,3) polylines; the strand-set
type :class:`vid2haircut.strands.StrandSet` builds on them. Resampling is uniform in arc length
with root and tip kept exactly.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from vid2haircut.checks import as_whole

__all__ = ["resample_polylines", "resample_polyline_list", "polyline_tangents", "scatter_strands",
           "vary_lengths", "cut_strands"]


def resample_polylines(points: np.ndarray, n_points: int) -> np.ndarray:
    """Resample polylines uniformly by arc length (vectorised over strands).

    Args:
        points: (N,P,3) float polylines, P >= 2, root first.
        n_points: points per output polyline, >= 2.

    Returns:
        (N,n_points,3) array of the input's floating dtype (float64 for integer input). The first
        and last points equal the input's root and tip exactly; the others lie on the input
        polyline at arc lengths ``k / (n_points-1) * L``. Zero-length strands stay at their root.
    """
    pts = np.asarray(points)
    if pts.ndim != 3 or pts.shape[2] != 3:
        raise ValueError(f"resample_polylines: points must be (N,P,3), got {pts.shape}")
    if pts.shape[1] < 2:
        raise ValueError(f"resample_polylines: need at least 2 points per strand, got {pts.shape[1]}")
    count = as_whole(n_points)
    if count is None or count < 2:
        raise ValueError(f"resample_polylines: n_points must be a whole number >= 2, got {n_points!r}")
    n_points = count
    out_dtype = pts.dtype if np.issubdtype(pts.dtype, np.floating) else np.float64
    n, p = pts.shape[:2]
    if n == 0:
        return np.zeros((0, n_points, 3), out_dtype)
    x = pts.astype(np.float64)
    cum = _cumulative_arc(x)                                             # (N,P)
    total = cum[:, -1]                                                   # (N,)
    degenerate = total <= 0.0
    # normalised arc length in [0,1]; degenerate strands get a dummy monotone parameter
    u = np.where(degenerate[:, None], np.linspace(0.0, 1.0, p)[None, :],
                 cum / np.where(degenerate, 1.0, total)[:, None])
    t = np.linspace(0.0, 1.0, n_points)                                  # (n_points,)
    res = _points_at_arclength(x, u, np.broadcast_to(t, (n, n_points)))
    res[degenerate] = x[degenerate, :1]
    out = res.astype(out_dtype)
    out[:, 0] = pts[:, 0]
    out[:, -1] = pts[:, -1]
    return out


def _cumulative_arc(x: np.ndarray) -> np.ndarray:
    """(N,P,3) polylines -> (N,P) arc length from the root at each vertex."""
    seg = np.linalg.norm(np.diff(x, axis=1), axis=-1)
    return np.concatenate([np.zeros((len(x), 1)), np.cumsum(seg, axis=1)], axis=1)


def _checked_strands(points: np.ndarray, func: str, name: str, value: float, high: float) -> np.ndarray:
    """``points`` as an (N,P,3) array with P >= 2, and ``value`` finite in [0, high); else ValueError."""
    pts = np.asarray(points)
    if pts.ndim != 3 or pts.shape[2] != 3 or pts.shape[1] < 2:
        raise ValueError(f"{func}: points must be (N,P,3) with P >= 2, got {pts.shape}")
    if not (np.isfinite(value) and 0.0 <= value < high):
        raise ValueError(f"{func}: {name} must be in [0, {high:.4g}), got {value}")
    return pts


def _points_at_arclength(x: np.ndarray, cum: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points of polylines at given arc-length parameters (linear interpolation, vectorised).

    Args:
        x: (N,Q,3) float64 polylines.
        cum: (N,Q) non-decreasing arc-length parameter of each vertex (repeats allowed).
        s: (N,M) parameters to sample, each row within its row's [cum[:,0], cum[:,-1]].

    Returns:
        (N,M,3) float64 points.
    """
    n, q = cum.shape
    # one global searchsorted: shift row i so that rows do not interleave
    offs = (float(np.max(cum[:, -1] - cum[:, 0], initial=0.0)) + 1.0) * np.arange(n, dtype=np.float64)
    flat_c = (cum - cum[:, :1] + offs[:, None]).ravel()
    flat_s = (s - cum[:, :1] + offs[:, None]).ravel()
    idx = np.searchsorted(flat_c, flat_s, side="right").reshape(s.shape) - np.arange(n)[:, None] * q
    j = np.clip(idx - 1, 0, q - 2)                                       # segment index (N,M)
    rows = np.arange(n)[:, None]
    c0, c1 = cum[rows, j], cum[rows, j + 1]
    dc = c1 - c0
    frac = np.clip(np.divide(s - c0, dc, out=np.zeros_like(dc), where=dc > 0), 0.0, 1.0)
    return x[rows, j] + frac[..., None] * (x[rows, j + 1] - x[rows, j])


def vary_lengths(points: np.ndarray, rel_std: float, seed: int = 0) -> np.ndarray:
    """Give each strand its own length: real hair ends are uneven, a strand decoded from a few
    guides is not.

    Each strand's length is multiplied by ``f = 1 + rel_std * g`` (g standard normal, clipped to
    +-3, one draw per strand from ``seed``). A shorter strand is cut at that arc length; a longer one
    is continued straight along its tip direction (the mean of its last three segments). Either
    way it is resampled to its P points uniformly by arc length, and the root is kept exactly.

    Args:
        points: (N,P,3) float strands, root first, P >= 2.
        rel_std: relative standard deviation of the length (0 returns the input unchanged).
        seed: seed of the per-strand draws.

    Returns:
        (N,P,3) array of the input's dtype.
    """
    pts = _checked_strands(points, "vary_lengths", "rel_std", rel_std, 1.0 / 3.0)
    if rel_std == 0.0 or len(pts) == 0:
        return pts.copy()
    n, p = pts.shape[:2]
    x = pts.astype(np.float64)
    cum = _cumulative_arc(x)
    length = cum[:, -1]
    g = np.clip(np.random.default_rng([int(seed), 0x1E46]).standard_normal(n), -3.0, 3.0)
    target = length * (1.0 + float(rel_std) * g)                         # (N,)
    back = max(p - 4, 0)
    tip_dir = x[:, -1] - x[:, back]
    norm = np.linalg.norm(tip_dir, axis=-1, keepdims=True)
    tip_dir = np.divide(tip_dir, norm, out=np.zeros_like(tip_dir), where=norm > 0)
    extra = np.maximum(target - length, 0.0)
    ext = np.concatenate([x, (x[:, -1] + tip_dir * extra[:, None])[:, None]], axis=1)   # (N,P+1,3)
    ext_cum = np.concatenate([cum, (length + extra)[:, None]], axis=1)
    out = _points_at_arclength(ext, ext_cum, target[:, None] * np.linspace(0.0, 1.0, p)[None, :])
    out = out.astype(pts.dtype if np.issubdtype(pts.dtype, np.floating) else np.float64)
    out[:, 0] = pts[:, 0]
    return out


def cut_strands(points: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Cut each strand after its first ``keep[i]`` points and resample it to its P points.

    Args:
        points: (N,P,3) float strands, root first.
        keep: (N,) int in [2, P]: points kept; the strand ends at point ``keep[i] - 1`` and is
            resampled uniformly by arc length over what is left (``keep[i] == P``: unchanged).

    Returns:
        (N,P,3) array of the input's dtype; uncut strands are bit-for-bit the input.

    Raises:
        ValueError when the shapes disagree or a count is outside [2, P].
    """
    pts = np.asarray(points)
    if pts.ndim != 3 or pts.shape[-1] != 3:
        raise ValueError(f"cut_strands: points must be (N,P,3), got {pts.shape}")
    n, p = pts.shape[:2]
    k = np.asarray(keep).astype(np.int64).reshape(-1)
    if k.shape != (n,):
        raise ValueError(f"cut_strands: keep must be ({n},), got {np.asarray(keep).shape}")
    if n and (k.min() < min(2, p) or k.max() > p):
        raise ValueError(f"cut_strands: keep must lie in [2, {p}], got [{k.min()}, {k.max()}]")
    out = pts.copy()
    cut = np.nonzero(k < p)[0]
    if len(cut):
        x = pts[cut].astype(np.float64)
        cum = _cumulative_arc(x)
        length = cum[np.arange(len(cut)), k[cut] - 1]
        res = _points_at_arclength(x, cum, length[:, None] * np.linspace(0.0, 1.0, p)[None, :])
        res[:, 0] = x[:, 0]
        out[cut] = res.astype(out.dtype)
    return out


def scatter_strands(points: np.ndarray, tip_std: float, seed: int = 0) -> np.ndarray:
    """Let strands fan out around their path: the hairs a guide stands for are not one sheet.

    Each strand is moved by its own random vector (3 independent normal components of standard
    deviation ``tip_std``, one draw per strand from ``seed``), weighted by ``sqrt(s / L)`` along its
    arc length s: the root stays, the tip moves by the whole vector.

    Args:
        points: (N,P,3) float strands, root first, P >= 2.
        tip_std: per-axis standard deviation of the tip's displacement, metres (0 = unchanged).
        seed: seed of the per-strand draws.

    Returns:
        (N,P,3) array of the input's dtype.
    """
    pts = _checked_strands(points, "scatter_strands", "tip_std", tip_std, 0.05)
    if tip_std == 0.0 or len(pts) == 0:
        return pts.copy()
    x = pts.astype(np.float64)
    cum = _cumulative_arc(x)
    frac = np.divide(cum, cum[:, -1:], out=np.zeros_like(cum), where=cum[:, -1:] > 0)
    shift = np.random.default_rng([int(seed), 0x5CA7]).standard_normal((len(x), 3)) * float(tip_std)
    out = x + np.sqrt(frac)[..., None] * shift[:, None, :]
    return out.astype(pts.dtype if np.issubdtype(pts.dtype, np.floating) else np.float64)

def resample_polyline_list(polylines: Sequence[np.ndarray], n_points: int | None = None) -> np.ndarray:
    """Bring polylines of different lengths to a common point count.

    Args:
        polylines: sequence of N arrays (P_i,3), each P_i >= 2.
        n_points: common count; default the largest P_i.

    Returns:
        (N,n_points,3) float32. Polylines that already have ``n_points`` points are copied
        bit-exactly; the others are resampled by arc length (grouped by length, vectorised).
    """
    if len(polylines) == 0:
        return np.zeros((0, int(n_points or 2), 3), np.float32)
    for i, pl in enumerate(polylines):
        if np.ndim(pl) != 2 or np.shape(pl)[1] != 3:
            raise ValueError(f"resample_polyline_list: polyline {i} must be (P, 3), got shape {np.shape(pl)}")
    counts = np.array([len(pl) for pl in polylines])
    if counts.min() < 2:
        raise ValueError(f"resample_polyline_list: a polyline has {counts.min()} point(s), need >= 2")
    n_points = int(counts.max() if n_points is None else n_points)
    out = np.empty((len(polylines), n_points, 3), np.float32)
    for c in np.unique(counts):
        sel = np.flatnonzero(counts == c)
        group = np.stack([np.asarray(polylines[i], np.float32).reshape(c, 3) for i in sel])
        out[sel] = group if c == n_points else resample_polylines(group, n_points)
    return out


def polyline_tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents of polylines by central differences (one-sided at root and tip).

    Args:
        points: (N,P,3) float, P >= 2.

    Returns:
        (N,P,3) float32 unit vectors pointing from root to tip. Where the difference vanishes
        (repeated points), the nearest valid tangent along the same strand is used; a strand with
        no valid tangent at all gets zeros.
    """
    x = np.asarray(points, np.float64)
    if x.ndim != 3 or x.shape[2] != 3 or x.shape[1] < 2:
        raise ValueError(f"polyline_tangents: points must be (N,P,3) with P >= 2, got {x.shape}")
    d = np.empty_like(x)
    d[:, 1:-1] = x[:, 2:] - x[:, :-2]
    d[:, 0] = x[:, 1] - x[:, 0]
    d[:, -1] = x[:, -1] - x[:, -2]
    norm = np.linalg.norm(d, axis=-1)                                    # (N,P)
    valid = norm > 1e-12
    if not valid.all():
        p = x.shape[1]
        ar = np.broadcast_to(np.arange(p), valid.shape)
        prev = np.maximum.accumulate(np.where(valid, ar, -1), axis=1)    # last valid index <= i
        nxt = np.minimum.accumulate(np.where(valid, ar, p)[:, ::-1], axis=1)[:, ::-1]  # first >= i
        use_prev = (prev >= 0) & ((nxt >= p) | (ar - prev <= nxt - ar))
        src = np.where(use_prev, prev, np.where(nxt < p, nxt, 0))
        rows = np.arange(x.shape[0])[:, None]
        d, norm = d[rows, src], norm[rows, src]
        d[~((prev >= 0) | (nxt < p))] = 0.0
    t = np.divide(d, norm[..., None], out=np.zeros_like(d), where=norm[..., None] > 1e-12)
    return t.astype(np.float32)
