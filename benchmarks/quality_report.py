"""Report tables of ``benchmarks/quality.py`` (and ``stage2_sweep.py``): Markdown from scored runs.

Kept apart from the runs: every function here reads scores (dicts from ``quality.score``) or the
runs' ``stage2.json`` records and returns text.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

LABELS = {"oracle": "Ground truth encoded in the hair map (representation floor)",
          "prior": "Prior prediction alone", "stage1": "Stage 1 (single view, Z optimised; default)",
          "stage1_ft": "Stage 1 (single view, prior net fine-tuned; Im2Haircut recipe)",
          "stage2": "**Stage 2 (Vid2Haircut, 6 keyframes)**", "no_deformation": "Stage 2 w/o deformation MLP",
          "no_smoothness": "Stage 2 w/o smoothness", "no_visibility": "Stage 2 w/o visibility masking",
          "no_pca": "Stage 2 w/o PCA consistency",
          "segment_gate": "Stage 2, visibility gate per segment (method.md)",
          "kf1": "Stage 2, 1 keyframe", "kf3": "Stage 2, 3 keyframes",
          "stage2_ft": "Stage 2 (6 keyframes) started from the fine-tuned Stage 1",
          "stage2_oracle": "Stage 2 (6 keyframes) started from the ground truth encoded in the hair map"}
def region_table(results: dict, seqs: list[str], variants: list[str]) -> str:
    """Markdown: mean Chamfer_pts (1e-4 m^2) of each variant split into front / side / back parts."""
    lines = ["| method | front | side | back | total |", "|---|---|---|---|---|"]
    for v in variants:
        ms = [results[(s, v)] for s in seqs if (s, v) in results]
        if len(ms) != len(seqs):
            continue
        parts = [np.mean([m[f"chamfer_pts_{r}"] for m in ms]) * 1e4 for r in ("front", "side", "back")]
        lines.append(f"| {LABELS[v]} | " + " | ".join(f"{x:.3f}" for x in parts) + f" | {sum(parts):.3f} |")
    return "\n".join(lines)


def _mean(results: dict, seqs: list[str], v: str, key: str) -> float:
    """Mean of ``key`` of variant ``v`` over ``seqs``, in 1e-4 units (Chamfer_pts in 1e-4 m^2)."""
    return float(np.mean([results[(s, v)][key] for s in seqs])) * 1e4


def _bound_claim(results: dict, seqs: list[str], base: str, fit: str, bound: float, digits: int) -> str:
    """"<fit> would reach <bound>: at most Nx lower than <base> (..); measured .., Mx."."""
    b, f = _mean(results, seqs, base, "chamfer_pts"), _mean(results, seqs, fit, "chamfer_pts")
    return (f"{LABELS[fit]} would reach {bound:.{digits}f}: at most {b / bound:.2f}x lower than {LABELS[base]} "
            f"({b:.{digits}f}); measured {f:.{digits}f}, {b / f:.2f}x.")


def region_bound(results: dict, seqs: list[str], base: str = "stage1", fit: str = "stage2") -> str:
    """One sentence: the lowest Chamfer_pts ``fit`` could reach with its back region as fitted and its
    front and side at the representation floor (``oracle``), and the ratio ``base`` / that bound.

    At the generator's default the keyframes turn to about 64 degrees, so the back is seen at most
    at grazing angles and stays close to where the single view left it; this bounds the gain over ``base`` that better fitting
    of the seen regions alone can give. Returns "" unless all three variants were scored on every
    sequence.
    """
    if not all((s, v) in results for s in seqs for v in ("oracle", base, fit)):
        return ""
    seen = _mean(results, seqs, "oracle", "chamfer_pts_front") + _mean(results, seqs, "oracle", "chamfer_pts_side")
    back = _mean(results, seqs, fit, "chamfer_pts_back")
    return (f"Region bound: with its back as fitted ({back:.3f}; {LABELS[base]}: "
            f"{_mean(results, seqs, base, 'chamfer_pts_back'):.3f}) and its front and side at the floor "
            f"({seen:.3f}), " + _bound_claim(results, seqs, base, fit, seen + back, 3))


def unseen_bound(results: dict, seqs: list[str], base: str = "stage1", fit: str = "stage2") -> str:
    """One sentence like :func:`region_bound`, with the part of Chamfer_pts that no keyframe can show
    (``chamfer_pts_unseen``: points in the back region or outside the image of every keyframe, see
    ``quality_score.unseen_test``) as fitted and the rest at the representation floor. Returns "" unless
    the three variants carry that part on every sequence."""
    if not all((s, v) in results and "chamfer_pts_unseen" in results[(s, v)]
               for s in seqs for v in ("oracle", base, fit)):
        return ""
    seen = _mean(results, seqs, "oracle", "chamfer_pts") - _mean(results, seqs, "oracle", "chamfer_pts_unseen")
    hidden = _mean(results, seqs, fit, "chamfer_pts_unseen")
    return (f"Observability bound: with what no keyframe shows (the back, and hair outside the image of "
            f"every keyframe) as fitted ({hidden:.4f}; {LABELS[base]}: "
            f"{_mean(results, seqs, base, 'chamfer_pts_unseen'):.4f}) and the rest at the floor ({seen:.4f}), "
            + _bound_claim(results, seqs, base, fit, seen + hidden, 4))


def tip_table(results: dict, seqs: list[str], variants: list[str]) -> str:
    """Markdown: mean over the sequences of the median tip height above the ground truth's (cm) per root region."""
    lines = ["| method | front | side | back |", "|---|---|---|---|"]
    for v in variants:
        ms = [results[(s, v)] for s in seqs if (s, v) in results]
        if len(ms) != len(seqs) or not all("tip_dy_back" in m for m in ms):
            continue
        parts = [np.nanmean([m[f"tip_dy_{r}"] for m in ms]) * 100 for r in ("front", "side", "back")]
        lines.append(f"| {LABELS[v]} | " + " | ".join(f"{x:+.1f}" for x in parts) + " |")
    return "\n".join(lines)


# Stage 2 variants whose final loss sums the same terms over the same keyframes as the full method's
SAME_OBJECTIVE = ["stage2", "stage2_ft", "stage2_oracle", "no_deformation", "no_visibility"]
IMAGE_TERMS = ("silhouette", "direction", "depth")


def loss_table(work: Path, seqs: list[str], variants: list[str]) -> str:
    """Markdown: the final weighted Stage 2 loss (seed 0) of each Stage 2 variant per sequence, as
    image terms (silhouette, direction, depth) / all terms, read from its ``stage2.json``; with
    ``stage2_oracle`` it shows whether the truth ends lower than the fits, i.e. whether the objective
    separates them, and which part of it does not."""
    rows = []
    for v in variants:
        if v not in SAME_OBJECTIVE:
            continue
        recs = [work / "runs" / s / v / "stage2.json" for s in seqs]
        if not all(r.is_file() for r in recs):
            continue
        cells, img_all, tot_all = [], [], []
        for r in recs:
            rec = json.loads(r.read_text())
            w, terms = rec["config"]["weights"], rec["history"]["terms"]
            img = sum(w[k] * terms[k][-1] for k in IMAGE_TERMS)
            tot = rec["history"]["total"][-1]
            cells.append(f"{img:.4f} / {tot:.4f}")
            img_all.append(img)
            tot_all.append(tot)
        rows.append(f"| {LABELS[v]} | " + " | ".join(cells) + f" | {np.mean(img_all):.4f} / {np.mean(tot_all):.4f} |")
    if not rows:
        return ""
    return ("Final weighted Stage 2 loss (seed 0), image terms / all terms, lower is better for "
            "the optimiser:\n\n| method | " + " | ".join(seqs) + " | mean |\n|" + "---|" * (len(seqs) + 2)
            + "\n" + "\n".join(rows))


def seed_table(per_seed: dict, seqs: list[str], variants: list[str], seeds: list[int]) -> str:
    """Markdown: mean Chamfer_pts (1e-4 m^2) over the sequences of each Stage 2 variant for every seed,
    and in how many seeds it is worse than the full method of the same seed."""
    lines = ["Mean Chamfer_pts (1e-4 m^2) per Stage 2 seed (the deformation field, frame codes and dense "
             "roots are drawn from it):", "",
             "| method | " + " | ".join(f"seed {s}" for s in seeds) + " | worse than full |",
             "|" + "---|" * (len(seeds) + 2)]
    means = {}
    for v in variants:
        for sd in seeds:
            vals = [per_seed[(s, v, sd)]["chamfer_pts"] for s in seqs if (s, v, sd) in per_seed]
            if len(vals) == len(seqs):
                means[(v, sd)] = float(np.mean(vals)) * 1e4
    for v in variants:
        if not all((v, sd) in means for sd in seeds):
            continue
        worse = "-" if v == "stage2" or not all(("stage2", sd) in means for sd in seeds) else \
            f"{sum(means[(v, sd)] > means[('stage2', sd)] for sd in seeds)} of {len(seeds)}"
        lines.append(f"| {LABELS[v]} | " + " | ".join(f"{means[(v, sd)]:.4f}" for sd in seeds) + f" | {worse} |")
    return "\n".join(lines)


def table(results: dict, seqs: list[str], variants: list[str]) -> str:
    """Markdown: one row per variant; Chamfer_pts (1e-4 m^2) / Chamfer_angle (rad) per sequence and mean."""
    head = "| method | " + " | ".join(seqs) + " | **mean CD_pts (1e-4 m^2)** | **mean CD_angle (rad)** |"
    lines = [head, "|" + "---|" * (len(seqs) + 3)]
    for v in variants:
        cells, pts, ang = [], [], []
        for s in seqs:
            m = results.get((s, v))
            if m is None:
                cells.append("-")
                continue
            pts.append(m["chamfer_pts"])
            ang.append(m["chamfer_angle"])
            cells.append(f"{m['chamfer_pts'] * 1e4:.3f} / {m['chamfer_angle']:.3f}")
        mean = (f"{np.mean(pts) * 1e4:.3f} | {np.mean(ang):.4f}" if len(pts) == len(seqs) else
                (f"({np.mean(pts) * 1e4:.3f}) | ({np.mean(ang):.4f})" if pts else "- | -"))
        lines.append(f"| {LABELS[v]} | " + " | ".join(cells) + f" | {mean} |")
    return "\n".join(lines)


def emit(text: str, out: str | None) -> None:
    """Print a report and also write it (atomically) to ``out`` when given."""
    print(text)
    if out:
        from vid2haircut.io.atomic import write_text

        write_text(out, text)
