"""The strand-set type: N strands of P points each, plus arc-length resampling and tangents.

A hairstyle is stored as a padded-free, fixed-count batch: ``points`` (N,P,3) float32 in metres,
root first. Files with strands of different lengths are brought to a common point count by
:func:`resample_polylines` / :func:`resample_polyline_list` (uniform in arc length, root and tip kept
exactly).

Example::

    s = StrandSet(np.zeros((2, 4, 3), np.float32) + np.linspace(0, 0.1, 4)[None, :, None])
    s.resample(10).n_points  # 10
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

__all__ = ["StrandSet", "resample_polylines", "resample_polyline_list", "polyline_tangents", "scatter_strands",
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
    if isinstance(n_points, bool) or not float(n_points).is_integer() or int(n_points) < 2:
        raise ValueError(f"resample_polylines: n_points must be a whole number >= 2, got {n_points!r}")
    n_points = int(n_points)
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


EXPORTED_ATTRIBUTES = {"color": (3,), "width": (), "transparency": ()}
"""Per-strand attributes the exporters write, with their shape after the leading N
(:func:`check_exported_attributes`; other tools' files may hold other shapes, which reading keeps)."""


def check_exported_attributes(strands: "StrandSet", what: str = "StrandSet") -> None:
    """Raise ValueError (prefixed ``what``) unless the attributes the exporters write have their
    per-strand size (:data:`EXPORTED_ATTRIBUTES`; e.g. a width of (N, 1) for (N,)) and finite
    numeric values."""
    n = strands.n_strands
    for key, tail in EXPORTED_ATTRIBUTES.items():
        if key not in strands.attributes:
            continue
        arr = strands.attributes[key]
        if arr.size != n * int(np.prod(tail)) or arr.dtype.kind not in "biuf":  # (N, 1) for (N,) is fine
            raise ValueError(f"{what}: attribute {key!r} must be numeric of shape {(n, *tail)} to be exported, "
                             f"got {arr.dtype} {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{what}: attribute {key!r} has NaN or infinite values")


@dataclass(frozen=True)
class StrandSet:
    """A hairstyle: N strands of P points each, root first, in metres.

    Attributes:
        points: (N,P,3) float32, P >= 2.
        attributes: per-strand arrays with leading dimension N (e.g. ``"color"`` (N,3) in [0,1],
            ``"width"`` (N,) metres). They are carried through resampling unchanged and through
            :meth:`subset` by indexing.
        head_model: name of the head model whose canonical frame the points are in, if known.
    """

    points: np.ndarray
    attributes: Mapping[str, np.ndarray] = field(default_factory=dict)
    head_model: str | None = None

    def __post_init__(self) -> None:
        pts = np.asarray(self.points)
        if pts.ndim != 3 or pts.shape[2] != 3:
            raise ValueError(f"StrandSet: points must be (N,P,3), got shape {pts.shape}")
        if pts.shape[1] < 2:
            raise ValueError(f"StrandSet: strands need at least 2 points, got P={pts.shape[1]}")
        if not np.issubdtype(pts.dtype, np.number):
            raise ValueError(f"StrandSet: points must be numeric, got dtype {pts.dtype}")
        pts = np.ascontiguousarray(pts, dtype=np.float32)
        if not np.isfinite(pts).all():
            raise ValueError("StrandSet: points contain NaN or infinite values")
        attrs: dict[str, np.ndarray] = {}
        for key, val in dict(self.attributes or {}).items():
            arr = np.asarray(val)
            if arr.ndim == 0 or arr.shape[0] != pts.shape[0]:
                raise ValueError(f"StrandSet: attribute {key!r} must have leading dimension "
                                 f"N={pts.shape[0]}, got shape {arr.shape}")
            attrs[str(key)] = arr
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "attributes", attrs)
        if self.head_model is not None:
            object.__setattr__(self, "head_model", str(self.head_model))

    # -- shape -------------------------------------------------------------------------------
    @property
    def n_strands(self) -> int:
        """Number of strands N."""
        return int(self.points.shape[0])

    @property
    def n_points(self) -> int:
        """Points per strand P."""
        return int(self.points.shape[1])

    def __len__(self) -> int:
        return self.n_strands

    @property
    def roots(self) -> np.ndarray:
        """(N,3) float32 first point of each strand."""
        return self.points[:, 0]

    @property
    def tips(self) -> np.ndarray:
        """(N,3) float32 last point of each strand."""
        return self.points[:, -1]

    # -- geometry ----------------------------------------------------------------------------
    def segment_lengths(self) -> np.ndarray:
        """(N,P-1) float32 lengths of the segments."""
        return np.linalg.norm(np.diff(self.points.astype(np.float64), axis=1), axis=-1).astype(np.float32)

    def lengths(self) -> np.ndarray:
        """(N,) float32 arc length of each strand."""
        return np.linalg.norm(np.diff(self.points.astype(np.float64), axis=1), axis=-1).sum(1).astype(np.float32)

    def tangents(self) -> np.ndarray:
        """(N,P,3) float32 unit tangents (central differences), see :func:`polyline_tangents`."""
        return polyline_tangents(self.points)

    def resample(self, n_points: int) -> "StrandSet":
        """Uniform arc-length resampling to ``n_points`` per strand (root and tip kept exactly).

        Returns ``self`` unchanged when it already has ``n_points`` points.
        """
        if int(n_points) == self.n_points:
            return self
        return StrandSet(resample_polylines(self.points, n_points), self.attributes, self.head_model)

    def subset(self, index: np.ndarray | slice | Sequence[int]) -> "StrandSet":
        """Strands selected by an integer index array, a boolean mask (N,) or a slice."""
        if not isinstance(index, slice):
            index = np.asarray(index)
            if index.size == 0:
                index = index.astype(np.int64)
            if index.dtype == bool and index.shape != (self.n_strands,):
                raise ValueError(f"StrandSet.subset: boolean mask must be ({self.n_strands},), got {index.shape}")
            if index.ndim != 1:
                raise ValueError(f"StrandSet.subset: index must be 1-D, got shape {index.shape}")
        pts = self.points[index]
        attrs = {k: v[index] for k, v in self.attributes.items()}
        return StrandSet(pts, attrs, self.head_model)

    def transform(self, T: np.ndarray) -> "StrandSet":
        """Apply a rigid / affine (4,4) transform ``p' = T[:3,:3] p + T[:3,3]`` to all points."""
        T = np.asarray(T, np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"StrandSet.transform: T must be (4,4), got {T.shape}")
        pts = self.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        return StrandSet(pts.astype(np.float32), self.attributes, self.head_model)

    def with_attributes(self, **attributes: np.ndarray) -> "StrandSet":
        """A copy with attributes added or replaced."""
        return StrandSet(self.points, {**self.attributes, **attributes}, self.head_model)

    @staticmethod
    def from_polylines(polylines: Sequence[np.ndarray], n_points: int | None = None,
                       attributes: Mapping[str, np.ndarray] | None = None,
                       head_model: str | None = None) -> "StrandSet":
        """Build a set from variable-length polylines (list of (P_i,3)), see
        :func:`resample_polyline_list` (default count: the largest P_i)."""
        return StrandSet(resample_polyline_list(polylines, n_points), attributes or {}, head_model)

    @staticmethod
    def concatenate(sets: Sequence["StrandSet"]) -> "StrandSet":
        """Stack sets with equal point counts; keeps only attributes present in all sets."""
        if not sets:
            raise ValueError("StrandSet.concatenate: no sets given")
        p = {s.n_points for s in sets}
        if len(p) != 1:
            raise ValueError(f"StrandSet.concatenate: point counts differ: {sorted(p)}")
        keys = set.intersection(*(set(s.attributes) for s in sets))
        attrs = {k: np.concatenate([s.attributes[k] for s in sets]) for k in sorted(keys)}
        heads = {s.head_model for s in sets}
        return StrandSet(np.concatenate([s.points for s in sets]), attrs,
                         heads.pop() if len(heads) == 1 else None)
