"""The strand-set type: N strands of P points each, with per-strand attributes.

A hairstyle is stored as a padded-free, fixed-count batch: ``points`` (N,P,3) float32 in metres,
root first. Files with strands of different lengths are brought to a common point count by
:func:`vid2haircut.polylines.resample_polylines` / :func:`~vid2haircut.polylines.resample_polyline_list`
(uniform in arc length, root and tip kept exactly).

Example::

    s = StrandSet(np.zeros((2, 4, 3), np.float32) + np.linspace(0, 0.1, 4)[None, :, None])
    s.resample(10).n_points  # 10
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from vid2haircut.polylines import polyline_tangents, resample_polyline_list, resample_polylines

__all__ = ["StrandSet", "EXPORTED_ATTRIBUTES", "check_exported_attributes"]


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
