"""Strand metrics against ground truth: Chamfer distance of points and of tangent angles, and
precision / recall / F1 of oriented points (see docs/method.md, "Metrics").

Both strand sets are resampled to the same number of points per strand, turned into oriented
point sets (position + unit tangent), and compared whole (the default) or, to save time, through a
random subset of at most ``max_points`` points with a fixed seed. With P the predicted and G the
ground-truth points:

- ``chamfer_pts`` = mean_p min_g |p-g|^2 + mean_g min_p |g-p|^2 (squared metres).
- ``chamfer_angle`` = mean of the two one-sided averages of arccos|t_p . t_nn(p)| (radians), the
  nearest neighbour taken by position.
- ``precision_<r>mm_<a>deg``: fraction of predicted points that have *some* ground-truth point
  within r whose (undirected) tangent is within a degrees; ``recall`` the other way round;
  ``f1`` their harmonic mean. Distances and angles are inclusive (<=).

A random subset is not a neutral shortcut for Chamfer_pts: a point's nearest neighbour in a 20%
subset lies farther than in the whole set, so every score gains a positive bias that does not
depend on the prediction and that compresses ratios between methods towards 1. With 10,000
strands of 100 points, a ground truth against itself through two different 200,000-point subsets
scores 0.015e-4 m^2, half the representation floor of a bob (0.030e-4 at 200,000 points, 0.015e-4
whole).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from vid2haircut.checks import as_whole
from vid2haircut.io.atomic import write_json
from vid2haircut.io.strand_formats import load_strands
from vid2haircut.strands import StrandSet

__all__ = ["THRESHOLDS", "REGIONS", "OrientedPoints", "oriented_points", "evaluate_strands", "evaluate_files",
           "tip_heights", "region_of"]

#: (radius metres, angle degrees) pairs of the oriented-point precision / recall (HairGS).
THRESHOLDS: tuple[tuple[float, float], ...] = ((0.002, 20.0), (0.003, 30.0), (0.004, 40.0))
_KNN = 16            # neighbours tried before falling back to an exact ball query


@dataclass(frozen=True)
class OrientedPoints:
    """A point set with unit tangents.

    Attributes:
        points: (M,3) float64 positions, metres.
        tangents: (M,3) float64 unit tangents (zero where undefined).
    """

    points: np.ndarray
    tangents: np.ndarray


def oriented_points(strands: StrandSet, n_points: int = 100, max_points: int | None = None,
                    seed: int = 0) -> OrientedPoints:
    """Resample to ``n_points`` per strand and flatten to an oriented point set; with ``max_points``
    (not None, > 0) keep at most that many points (a uniform random subset without replacement,
    ``default_rng(seed)``, kept in strand order)."""
    s = strands.resample(n_points)
    pts = s.points.reshape(-1, 3).astype(np.float64)
    tan = s.tangents().reshape(-1, 3).astype(np.float64)
    norm = np.linalg.norm(tan, axis=1, keepdims=True)
    tan = np.divide(tan, norm, out=np.zeros_like(tan), where=norm > 0)      # unit in float64
    if max_points and len(pts) > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(len(pts), int(max_points), replace=False))
        pts, tan = pts[keep], tan[keep]
    return OrientedPoints(pts, tan)


def _abs_cos(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a.b| along the last axis, clipped to [0,1]."""
    return np.clip(np.abs(np.einsum("...i,...i->...", a, b)), 0.0, 1.0)


def _directed(src: OrientedPoints, dst: OrientedPoints, dst_tree: cKDTree,
              chunk: int = 4096) -> tuple[np.ndarray, float, np.ndarray]:
    """One direction src -> dst.

    Returns:
        (M,) squared nearest distance of every src point, mean nearest-neighbour angle (rad), and a (len(THRESHOLDS),)
        array with the fraction of src points matched at each (radius, angle) threshold.
    """
    radii = np.array([r for r, _ in THRESHOLDS])
    cos_min = np.cos(np.deg2rad([a for _, a in THRESHOLDS]))
    k = int(min(_KNN, len(dst.points)))
    d, nn = dst_tree.query(src.points, k=k, workers=-1)
    d, nn = d.reshape(len(src.points), k), nn.reshape(len(src.points), k)
    sq = d[:, 0] ** 2
    t_nn = dst.tangents[nn[:, 0]]
    # arccos|t.t'| computed as atan2(|t x t'|, |t.t'|): same value, accurate near 0
    angle = np.arctan2(np.linalg.norm(np.cross(src.tangents, t_nn), axis=1), _abs_cos(src.tangents, t_nn))
    cos_k = _abs_cos(src.tangents[:, None, :], dst.tangents[nn])                  # (M,k)
    matched = np.stack([((d <= r) & (cos_k >= c - 1e-12)).any(1) for r, c in zip(radii, cos_min)], 1)
    # points not matched although more than k dst points may lie within r: exact ball query
    todo = ~matched & (d[:, -1:] <= radii[None, :]) & (k < len(dst.points))
    rows = np.flatnonzero(todo.any(1))
    for start in range(0, len(rows), chunk):
        q = rows[start:start + chunk]
        r_q = np.where(todo[q], radii[None, :], 0.0).max(1)                     # largest radius needed
        lists = dst_tree.query_ball_point(src.points[q], r_q, workers=-1)
        counts = np.fromiter((len(x) for x in lists), np.int64, len(q))       # >= k > 0 each
        neigh = np.fromiter((j for x in lists for j in x), np.int64, int(counts.sum()))
        owner = np.repeat(q, counts)                                          # src index per pair
        dist = np.linalg.norm(dst.points[neigh] - src.points[owner], axis=1)
        cos = _abs_cos(dst.tangents[neigh], src.tangents[owner])
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        for j, (r, c) in enumerate(zip(radii, cos_min)):
            hit = np.logical_or.reduceat((dist <= r) & (cos >= c - 1e-12), first)
            matched[q, j] |= hit & todo[q, j]
    return sq, float(angle.mean()), matched.mean(0)


def _tag(radius: float, angle: float) -> str:
    return f"{radius * 1000:g}mm_{angle:g}deg"


#: azimuth bounds (degrees from the face direction +z about the vertical axis +y) of the regions
#: of ``evaluate_strands(..., by_region=True)``: front |az| < 60, sides 60 <= |az| < 120, back |az| >= 120.
REGIONS: tuple[tuple[str, float, float], ...] = (("front", 0.0, 60.0), ("side", 60.0, 120.0), ("back", 120.0, 181.0))


def region_of(points: np.ndarray) -> np.ndarray:
    """(M,3) head-frame points -> (M,) index into :data:`REGIONS` by azimuth about +y from +z."""
    az = np.degrees(np.abs(np.arctan2(points[:, 0], points[:, 2])))
    out = np.zeros(len(points), np.int64)
    for i, (_, lo, _hi) in enumerate(REGIONS):
        out[az >= lo] = i
    return out


def tip_heights(strands: StrandSet) -> dict[str, float]:
    """Median tip height (head frame +y, metres) of the strands rooted in each head region.

    Hanging hair ends along a cut line, so comparing these medians with the ground truth's tells
    whether a reconstruction's hair is too short (higher tips) or too long, region by region; the
    region is the root's (:data:`REGIONS`), NaN where no strand is rooted.

    Returns:
        {"front": m, "side": m, "back": m}.
    """
    pts = np.asarray(strands.points)
    if len(pts) == 0:
        return {name: float("nan") for name, _, _ in REGIONS}
    tips = pts[:, -1]
    reg = region_of(pts[:, 0])
    return {name: float(np.median(tips[reg == i, 1])) if np.any(reg == i) else float("nan")
            for i, (name, _, _) in enumerate(REGIONS)}


def evaluate_strands(pred: StrandSet, gt: StrandSet, n_points: int = 100, max_points: int | None = None,
                     seed: int = 0, by_region: bool = False,
                     unseen: Callable[[np.ndarray], np.ndarray] | None = None) -> dict:
    """Score predicted strands against ground-truth strands (both in the same frame, metres).

    Args:
        pred, gt: strand sets (any point counts; both are resampled to ``n_points``).
        n_points: points per strand after resampling.
        max_points: cap on each oriented point set (random subset, ``seed``); None or 0 = every
            point (exact; the subset biases Chamfer_pts upwards, see the module docstring).
        by_region: also split Chamfer_pts by head region (:data:`REGIONS`): each point's squared
            nearest distance is credited to the region of that point, so ``chamfer_pts_front``,
            ``chamfer_pts_side`` and ``chamfer_pts_back`` add up to ``chamfer_pts`` (both sets in
            the head's canonical frame: face towards +z, up +y).
        unseen: optional test (M,3) points -> (M,) bool of the points that the input could not show
            (e.g. outside every keyframe's image, see ``benchmarks/quality.py``); adds
            ``chamfer_pts_unseen``, the part of ``chamfer_pts`` credited to such points of either set.

    Returns:
        dict of floats: ``chamfer_pts`` (m^2), ``chamfer_pts_pred_to_gt``, ``chamfer_pts_gt_to_pred``,
        ``chamfer_angle`` (rad), ``chamfer_angle_pred_to_gt``, ``chamfer_angle_gt_to_pred``, and per
        threshold ``precision_2mm_20deg``, ``recall_2mm_20deg``, ``f1_2mm_20deg`` (also 3mm_30deg,
        4mm_40deg); plus the counts ``n_strands_pred``, ``n_strands_gt``, ``n_points_pred``,
        ``n_points_gt`` (points actually compared).
    """
    for name, s in (("pred", pred), ("gt", gt)):
        if not isinstance(s, StrandSet):
            raise TypeError(f"evaluate_strands: {name} must be a StrandSet (vid2haircut.strands), got "
                            f"{type(s).__name__}; wrap (N, P, 3) points as StrandSet(points)")
        if s.n_strands == 0:
            raise ValueError(f"evaluate_strands: the {name} strand set is empty")
    if max_points is not None and (as_whole(max_points) is None or max_points < 0):
        raise ValueError(f"evaluate_strands: max_points must be a whole number >= 0 (0 or None: every point), "
                         f"got {max_points!r}")
    if pred.head_model and gt.head_model and pred.head_model != gt.head_model:
        raise ValueError(f"evaluate_strands: prediction is in the frame of head model {pred.head_model!r}, "
                         f"ground truth in {gt.head_model!r}")
    p = oriented_points(pred, n_points, max_points, seed)
    g = oriented_points(gt, n_points, max_points, seed)
    d_pg, ang_pg, prec = _directed(p, g, cKDTree(g.points))
    d_gp, ang_gp, rec = _directed(g, p, cKDTree(p.points))
    sq_pg, sq_gp = float(d_pg.mean()), float(d_gp.mean())
    out = {
        "chamfer_pts": sq_pg + sq_gp, "chamfer_pts_pred_to_gt": sq_pg, "chamfer_pts_gt_to_pred": sq_gp,
        "chamfer_angle": 0.5 * (ang_pg + ang_gp), "chamfer_angle_pred_to_gt": ang_pg,
        "chamfer_angle_gt_to_pred": ang_gp,
        "n_strands_pred": pred.n_strands, "n_strands_gt": gt.n_strands,
        "n_points_pred": len(p.points), "n_points_gt": len(g.points),
    }
    for (r, a), pr, rc in zip(THRESHOLDS, prec, rec):
        tag = _tag(r, a)
        out[f"precision_{tag}"] = float(pr)
        out[f"recall_{tag}"] = float(rc)
        out[f"f1_{tag}"] = float(2 * pr * rc / (pr + rc)) if pr + rc > 0 else 0.0
    if by_region:
        rp, rg = region_of(p.points), region_of(g.points)
        for i, (name, _, _) in enumerate(REGIONS):
            out[f"chamfer_pts_{name}"] = float(d_pg[rp == i].sum() / len(d_pg) + d_gp[rg == i].sum() / len(d_gp))
    if unseen is not None:
        up, ug = np.asarray(unseen(p.points), bool), np.asarray(unseen(g.points), bool)
        out["chamfer_pts_unseen"] = float(d_pg[up].sum() / len(d_pg) + d_gp[ug].sum() / len(d_gp))
    return out


def evaluate_files(pred_path: str | os.PathLike, gt_path: str | os.PathLike, out_json: str | os.PathLike,
                   n_points: int = 100, max_points: int | None = None, seed: int = 0) -> dict:
    """Load two strand files (any supported format), score them with :func:`evaluate_strands` and
    write them atomically to ``out_json`` as one flat JSON object: the metrics plus
    ``points_per_strand``, ``max_points`` (0 = every point), ``seed``, ``pred_file`` and ``gt_file`` (file names only,
    so the output does not depend on where the files live).

    Returns the written dict.
    """
    pred = load_strands(pred_path)
    gt = load_strands(gt_path)
    for path, s in ((pred_path, pred), (gt_path, gt)):
        if s.n_strands == 0:
            raise ValueError(f"{path}: the strand file holds no strands")
    record = evaluate_strands(pred, gt, n_points=n_points, max_points=max_points, seed=seed)
    record.update(points_per_strand=int(n_points), max_points=int(max_points or 0), seed=int(seed),
                  pred_file=Path(pred_path).name, gt_file=Path(gt_path).name)
    write_json(out_json, record)
    return record
