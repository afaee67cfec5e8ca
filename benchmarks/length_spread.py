"""How uneven are hair ends, how far do strands fan out? Spreads inside one hair-map texel, over the prior's corpus.

A texel of the hair map holds one guide, and every dense strand decoded near it gets that guide's
length. The generated hairstyles (the prior's training corpus: the same families, seeds and strand
counts as ``vid2haircut train_prior``) are not cut so evenly. This groups each style's strands by
the texel of the R x R map that their root falls in, takes each strand's length relative to its
texel's median, and prints the spread of that ratio per family and pooled: the plain standard
deviation and the robust one (1.4826 x the median absolute deviation, which a few strands that
curl back or stop short do not inflate). The pooled robust spread at R = 32 is the default
``length_spread`` of both stages (:func:`vid2haircut.polylines.vary_lengths`).

It also prints how far the strands of one texel fan out: at 25/50/75/100% of the points, each
strand's root-relative point minus the texel's median one, its component across the texel's median
direction there, and the per-axis robust spread of that (median distance / 1.1774, the per-axis
standard deviation for a 2-D normal). The pooled value at the tip is the one measured for
``tip_scatter`` (:func:`vid2haircut.polylines.scatter_strands`, which grows the displacement with the
square root of the arc-length fraction, as these spreads do; off by default, see
``benchmarks/RESULTS.md``, "Uneven ends").

Last, how far the strands of one texel lie from each other in depth: at 10/25/50/75/100% of the
points, each strand's distance from the head surface minus the texel's median one there, and the
robust spread of that (how much a dense strand's own depth in the hair could differ from its
guide's, were it drawn like the corpus; measured and not used, ``benchmarks/RESULTS.md``, "How full
the hair is").

    python benchmarks/length_spread.py [--res 32] [--seeds 8] [--strands 1500]
"""

from __future__ import annotations

import argparse

import numpy as np


def robust_std(x: np.ndarray) -> float:
    """1.4826 x the median absolute deviation (the standard deviation for normal data)."""
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if len(x) else float("nan")


def relative_lengths(lengths: np.ndarray, uv: np.ndarray, style: np.ndarray, res: int) -> np.ndarray:
    """(N,) length / median length of the strands of the same style rooted in the same texel of an
    ``res`` x ``res`` uv grid; NaN where that texel holds fewer than 3 strands."""
    rel = np.full(len(lengths), np.nan)
    for idx in texel_groups(uv, style, res):
        med = float(np.median(lengths[idx]))
        if med > 0:
            rel[idx] = lengths[idx] / med
    return rel


def texel_groups(uv: np.ndarray, style: np.ndarray, res: int, min_count: int = 3) -> list[np.ndarray]:
    """Index arrays of the strands of one style rooted in one texel (texels with >= ``min_count``)."""
    tex = np.floor(np.clip(uv, 0.0, 1.0 - 1e-9) * res).astype(np.int64)
    key = (style.astype(np.int64) * res + tex[:, 1]) * res + tex[:, 0]
    order = np.argsort(key, kind="stable")
    ks = key[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    ends = np.r_[starts[1:], len(ks)]
    return [order[a:b] for a, b in zip(starts, ends) if b - a >= min_count]


def lateral_spread(points: np.ndarray, groups: list[np.ndarray], k: int) -> np.ndarray:
    """(M,) distance of each grouped strand's root-relative point ``k`` from its group's median,
    across the group's median direction at that point (metres)."""
    rel = points[:, k] - points[:, 0]
    k0, k1 = max(k - 1, 0), min(k + 1, points.shape[1] - 1)
    out = []
    for idx in groups:
        dev = rel[idx] - np.median(rel[idx], axis=0)
        tan = np.median(points[idx, k1] - points[idx, k0], axis=0)
        tan = tan / (np.linalg.norm(tan) + 1e-12)
        out.append(np.linalg.norm(dev - (dev @ tan)[:, None] * tan[None], axis=1))
    return np.concatenate(out) if out else np.zeros(0)


def standoff_deviation(sdf: np.ndarray, groups: list[np.ndarray], k: int) -> np.ndarray:
    """(M,) each grouped strand's head distance at point ``k`` minus its group's median there (metres).

    Args:
        sdf: (N,P) head signed distance of every strand point; groups: from :func:`texel_groups`.
    """
    out = [sdf[idx, k] - np.median(sdf[idx, k]) for idx in groups]
    return np.concatenate(out) if out else np.zeros(0)


def main(argv: list[str] | None = None) -> int:
    from vid2haircut.prior.corpus import build_corpus
    from vid2haircut.synth.hairstyles import FAMILIES

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--res", type=int, default=32, help="hair map resolution R")
    p.add_argument("--seeds", type=int, default=8, help="generator seeds 0..N-1 per family (the corpus's)")
    p.add_argument("--strands", type=int, default=1500, help="strands per style (the corpus's)")
    args = p.parse_args(argv)
    c = build_corpus(FAMILIES, range(args.seeds), strands_per_style=args.strands, n_points=100)
    lengths = np.linalg.norm(np.diff(np.asarray(c.points, np.float64), axis=1), axis=-1).sum(1)
    rel = relative_lengths(lengths, np.asarray(c.uv), np.asarray(c.style), args.res) - 1.0
    ok = np.isfinite(rel)
    fam_of_style = np.array([f for f, _ in c.styles])
    print(f"| family | strands | std | robust std |  (texel of a {args.res}x{args.res} map)")
    print("|---|---|---|---|")
    for fam in FAMILIES:
        sel = ok & (fam_of_style[np.asarray(c.style)] == fam)
        print(f"| {fam} | {int(sel.sum())} | {rel[sel].std():.4f} | {robust_std(rel[sel]):.4f} |")
    print(f"| **pooled** | {int(ok.sum())} | {rel[ok].std():.4f} | **{robust_std(rel[ok]):.4f}** |")
    points = np.asarray(c.points, np.float64)
    groups = texel_groups(np.asarray(c.uv), np.asarray(c.style), args.res)
    fam_grouped = fam_of_style[np.asarray(c.style)[np.concatenate(groups)]]
    p = points.shape[1]
    print("\nFan-out across the strands' direction, per-axis robust spread in mm, at the share of the points:\n")
    print("| family | " + " | ".join(f"{q}%" for q in (25, 50, 75, 100)) + " |")
    print("|---|---|---|---|---|")
    spreads = [lateral_spread(points, groups, round(q / 100 * (p - 1))) / 1.1774 for q in (25, 50, 75, 100)]
    for fam in FAMILIES:
        sel = fam_grouped == fam
        print(f"| {fam} | " + " | ".join(f"{np.median(d[sel]) * 1e3:.2f}" for d in spreads) + " |")
    print("| **pooled** | " + " | ".join(f"{np.median(d) * 1e3:.2f}" for d in spreads[:-1])
          + f" | **{np.median(spreads[-1]) * 1e3:.2f}** |")
    from vid2haircut.head import get_head

    sdf = np.asarray(get_head("proxy-v1").sdf_np(points.reshape(-1, 3)), np.float64).reshape(points.shape[:2])
    shares = (10, 25, 50, 75, 100)
    dev = [standoff_deviation(sdf, groups, round(q / 100 * (p - 1))) for q in shares]
    print("\nDistance from the head surface, robust spread in mm of each strand's minus its texel's median,"
          " at the share of the points:\n")
    print("| family | " + " | ".join(f"{q}%" for q in shares) + " |")
    print("|---|" + "---|" * len(shares))
    for fam in FAMILIES:
        sel = fam_grouped == fam
        print(f"| {fam} | " + " | ".join(f"{robust_std(d[sel]) * 1e3:.2f}" for d in dev) + " |")
    print("| **pooled** | " + " | ".join(f"{robust_std(d) * 1e3:.2f}" for d in dev) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
