"""Where the ground-truth-to-prediction part of Chamfer_pts comes from, for cached quality runs.

For each sequence of a ``benchmarks/quality.py`` work folder and each variant, every ground-truth
point's squared distance to the nearest predicted point (the ``chamfer_pts_gt_to_pred`` term, every
point, exact) is split two ways: by the point's distance from the fitted head surface (0-1, 1-2,
2-3, 3-5, over 5 cm) and by its position along its strand (quarters of the 100 points, root first).
Each part is the share of the mean, so the parts of a row add up to the term (1e-4 m^2).
A second table projects every strand's tip into the reference keyframe (fitted head pose,
full-resolution camera): the share of tips inside the image, the share of those on the target hair
mask, and their median image row (pixels from the top), for the ground truth and each variant.
A third table gives each variant's strand length against the ground truth's (each strand matched
to the ground-truth strand with the nearest scalp uv), mean by the root's head region, in cm.
A fourth table splits the same term by the ground-truth point's head region (front / side / back,
:func:`vid2haircut.evaluate.metrics.region_of`), above or below ``UPPER_Y_M`` in the head frame, and
whether the point lies farther from the head surface than its nearest predicted point ("outside":
the prediction's hair is too flat there) or not ("inside").
A fifth table gives how far from the head surface the hair above ``UPPER_Y_M`` lies, in the side and
back regions: the mean and 90th percentile head distance of those points (mm), for the ground truth
and each variant (how full the hair is, whatever the nearest-point matching).

    .venv/bin/python benchmarks/gap_profile.py --work results/benchmarks/quality_v12 \\
        --sequences shoulder_straight_1001,wavy_1004
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
import quality_data  # noqa: E402  (the benchmark's sequence layout)

SDF_BINS_M = (0.0, 0.01, 0.02, 0.03, 0.05, np.inf)
N_POINTS = 100
UPPER_Y_M = -0.04
"""Head-frame height (metres) that splits the fourth table's upper and lower parts (about ear level)."""


def profile(gt_sdf: np.ndarray, d2: np.ndarray) -> tuple[float, list, list]:
    """(gt->pred term, parts by head distance, parts by strand quarter), all in 1e-4 m^2.

    Args:
        gt_sdf: (S*100,) signed distance from the head surface of the ground-truth points (strand by
            strand, root first), metres. d2: (S*100,) their squared distance to the nearest predicted point.
    """
    n = len(d2)
    by_sdf = np.digitize(np.maximum(gt_sdf, 0.0), SDF_BINS_M[1:-1])
    pos = np.arange(n) % N_POINTS
    sdf_parts = [float(d2[by_sdf == i].sum() / n * 1e4) for i in range(len(SDF_BINS_M) - 1)]
    arc_parts = [float(d2[(pos >= a) & (pos < a + N_POINTS // 4)].sum() / n * 1e4) for a in range(0, N_POINTS, N_POINTS // 4)]
    return float(d2.mean() * 1e4), sdf_parts, arc_parts


def shell_split(gt_points: np.ndarray, gt_sdf: np.ndarray, d2: np.ndarray, nearest_sdf: np.ndarray) -> list[float]:
    """The gt->pred term (1e-4 m^2) in 12 parts that add up to it: for each head region (front, side,
    back) and height (upper, lower: above / below :data:`UPPER_Y_M`), the part from ground-truth points
    farther from the head than their nearest predicted point ("outside") and the rest ("inside").

    Args:
        gt_points: (S,3); gt_sdf: (S,) their head signed distance; d2: (S,) their squared distance to
            the nearest predicted point; nearest_sdf: (S,) that point's head signed distance.
    """
    from vid2haircut.evaluate.metrics import REGIONS, region_of

    n = len(d2)
    reg, upper, outside = region_of(gt_points), gt_points[:, 1] > UPPER_Y_M, gt_sdf > nearest_sdf
    return [float(d2[(reg == r) & (upper == u) & (outside == o)].sum() / n * 1e4)
            for r in range(len(REGIONS)) for u in (True, False) for o in (True, False)]


def standoff(points: np.ndarray, sdf: np.ndarray) -> list[float]:
    """Mean and 90th percentile head distance (mm) of the points above ``UPPER_Y_M``, side then back.

    Args:
        points: (S,3) head-frame points; sdf: (S,) their head signed distance, metres.

    Returns:
        [side mean, side p90, back mean, back p90] (nan where a part holds no point).
    """
    from vid2haircut.evaluate.metrics import REGIONS, region_of

    names = [r[0] for r in REGIONS]
    reg, upper = region_of(points), points[:, 1] > UPPER_Y_M
    out = []
    for r in ("side", "back"):
        d = sdf[(reg == names.index(r)) & upper] * 1e3
        out += [float(d.mean()), float(np.percentile(d, 90))] if d.size else [float("nan")] * 2
    return out


def tip_rows(tips: np.ndarray, camera, world_from_head: np.ndarray, mask: np.ndarray) -> tuple[float, float, float]:
    """(share in the image, share of those on ``mask``, median row of those) of (S,3) head-frame tips."""
    uv, z = camera.project(tips @ world_from_head[:3, :3].T + world_from_head[:3, 3])
    u, v = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    ok = (z > 0) & (u >= 0) & (u < mask.shape[1]) & (v >= 0) & (v < mask.shape[0])
    if not ok.any():
        return 0.0, float("nan"), float("nan")
    return float(ok.mean()), float(mask[v[ok], u[ok]].mean()), float(np.median(v[ok]))


def length_errors(gt, pred) -> list[float]:
    """Mean length (cm) of the ``pred`` strands minus that of the ``gt`` strand with the nearest root
    uv (both StrandSets with a ``uv`` attribute), per root head region (:data:`REGIONS` order; NaN
    where none is rooted)."""
    from vid2haircut.evaluate.metrics import REGIONS, region_of

    match = cKDTree(gt.attributes["uv"]).query(pred.attributes["uv"])[1]
    d = (pred.lengths() - gt.lengths()[match]) * 100.0
    reg = region_of(pred.points[:, 0])
    return [float(d[reg == i].mean()) if np.any(reg == i) else float("nan") for i in range(len(REGIONS))]


def main(argv: list[str] | None = None) -> int:
    from vid2haircut.evaluate.metrics import oriented_points
    from vid2haircut.fit.data import load_fit_camera
    from vid2haircut.front.headfile import load_head_fit, resolve_head
    from vid2haircut.front.keyframes import load_keyframes
    from vid2haircut.front.targets.build import load_targets
    from vid2haircut.io.strand_formats import load_strands

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", required=True, help="a benchmarks/quality.py work folder")
    p.add_argument("--sequences", required=True, help="comma-separated sequence names")
    p.add_argument("--variants", default="oracle,stage1,stage2", help="comma-separated cached variants")
    args = p.parse_args(argv)
    work = Path(args.work)
    variants = args.variants.split(",")
    gaps, tips, lengths, shells, standoffs = [], [], [], [], []
    for name in args.sequences.split(","):
        seq = quality_data.seq_files(work, name)
        gt_set = load_strands(seq["gt"])
        gt = oriented_points(gt_set, N_POINTS).points
        fit, extra = load_head_fit(seq["head"])
        head = resolve_head(fit.head_model, fit.shape)
        sdf = np.asarray(head.sdf_np(gt)).ravel()
        ref = load_keyframes(seq["keyframes"])
        cam = load_fit_camera(seq["root"], name, extra.get("serial") or ref.serial)
        pose = fit.world_from_head[[int(t) for t in fit.frames].index(ref.reference)]
        mask = np.asarray(load_targets(Path(seq["targets"]) / f"frame_{ref.reference:05d}.npz")["mask"]) > 0.5
        for v in ["ground truth"] + variants:
            pred = None if v == "ground truth" else load_strands(work / "runs" / name / v / "strands.npz")
            pts = gt if pred is None else oriented_points(pred, N_POINTS).points
            part = standoff(pts, sdf if pred is None else np.asarray(head.sdf_np(pts)).ravel())
            standoffs.append(f"{name} | {v} | {part[0]:.1f} / {part[1]:.1f} | {part[2]:.1f} / {part[3]:.1f}")
            inside, on_mask, row = tip_rows(pts[N_POINTS - 1::N_POINTS], cam, pose, mask)
            tips.append(f"{name} | {v} | {inside:.2f} | {on_mask:.2f} | {row:.0f}")
            if pred is not None:
                err = length_errors(gt_set, pred)
                lengths.append(f"{name} | {v} | {' / '.join(f'{x:+.1f}' for x in err)}")
                dist, nearest = cKDTree(pts).query(gt, workers=-1)
                total, by_sdf, by_arc = profile(sdf, dist ** 2)
                gaps.append(f"{name} | {v} | {total:.4f} | {' / '.join(f'{x:.4f}' for x in by_sdf)} | "
                            f"{' / '.join(f'{x:.4f}' for x in by_arc)}")
                parts = shell_split(gt, sdf, dist ** 2, np.asarray(head.sdf_np(pts[nearest])).ravel())
                shells.append(f"{name} | {v} | " + " | ".join(f"{a:.4f} / {b:.4f}" for a, b in zip(parts[::2], parts[1::2])))
    print("sequence | variant | gt->pred | head distance 0-1 / 1-2 / 2-3 / 3-5 / >5 cm | strand quarters 1-4")
    print("\n".join(gaps))
    print("\nsequence | strands | tips in the reference image | of those on the target mask | median tip row (px)")
    print("\n".join(tips))
    print("\nsequence | variant | strand length minus the ground truth's, cm, roots front / side / back")
    print("\n".join(lengths))
    print("\nsequence | variant | gt->pred outside / inside: front upper | front lower | side upper | side lower | "
          "back upper | back lower")
    print("\n".join(shells))
    print("\nsequence | strands | head distance above the split, mm, mean / 90th percentile: side | back")
    print("\n".join(standoffs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
