"""Prior prediction on unseen generated views, against the mean-hairstyle baseline.

For every (family, unseen seed, view) a hairstyle is generated, rendered from a random frontal-ish
pose (:mod:`vid2haircut.prior.views`), passed through the prior, and the predicted map is decoded
to dense strands (:func:`vid2haircut.prior.hairmap.decode_dense`). Chamfer_pts (m^2, method.md)
against the generated strands is computed with :func:`vid2haircut.evaluate.metrics.evaluate_strands`
for

- ``prior``: the network's prediction (z, sigmoid(mask logits));
- ``mean_hairstyle``: the codec's mean strand everywhere (zero map) with the training set's mean
  mask (the baseline of the issue);
- ``mean_map``: the training set's per-texel mean map and mean mask (a stronger, image-free
  baseline, reported for honesty).

Example::

    net, codec, record = load_prior("src/vid2haircut/data/prior/default")
    rows = evaluate_prior(net, codec, families=FAMILIES, seeds=(1000, 1001))
    print(markdown_summary(rows))
"""

from __future__ import annotations

from typing import Any, NamedTuple, Sequence

import numpy as np
import torch

from vid2haircut.prior.codec import StrandCodec
from vid2haircut.prior.hairmap import HairMap, decode_dense
from vid2haircut.prior.model import PriorNet
from vid2haircut.prior.views import ViewConfig, prior_input, random_pose, training_view, view_strands
from vid2haircut.strands import StrandSet

__all__ = ["PriorEvalRow", "METHODS", "evaluate_prior", "summarise", "markdown_summary"]

METHODS = ("prior", "mean_hairstyle", "mean_map")
"""Compared predictions (columns of the summary)."""


class PriorEvalRow(NamedTuple):
    """Scores of one unseen view.

    Attributes:
        family, seed, view: the hairstyle and view index.
        chamfer: method name -> Chamfer_pts (m^2) of its decoded strands vs ground truth.
        mask_iou: method name -> IoU of its thresholded baldness mask vs the encoded target mask.
    """

    family: str
    seed: int
    view: int
    chamfer: dict[str, float]
    mask_iou: dict[str, float]


def _dense(z: torch.Tensor, mask: torch.Tensor, head: Any, codec: StrandCodec, n: int, seed: int) -> StrandSet:
    with torch.no_grad():
        return decode_dense(HairMap(z.float().cpu(), mask.float().cpu()), head, codec.to("cpu"), n_strands=n,
                            mask_threshold=0.5, seed=seed).to_strand_set()


def evaluate_prior(net: PriorNet, codec: StrandCodec, families: Sequence[str], seeds: Sequence[int],
                   views_per_style: int = 1, view_cfg: ViewConfig = ViewConfig(), strands_per_style: int = 1500,
                   n_dense: int = 2000, head: Any = None, seed: int = 0, max_points: int = 50_000,
                   progress: bool = True,
                   ) -> list[PriorEvalRow]:
    """Score the prior and the baselines on unseen hairstyles.

    Args:
        net: trained prior (its ``train_mean_z`` / ``train_mean_mask`` buffers give the baselines).
        codec: the prior's codec.
        families, seeds: hairstyles to generate (use seeds outside the training seeds, e.g. >= 1000).
        views_per_style: random views per hairstyle.
        view_cfg: how the views are made (:func:`vid2haircut.prior.views.training_view`); pass the
            prior's own (``ViewConfig.from_dict(record["config"]["data"]["view"])``), as
            ``benchmarks/prior_eval.py`` does: a prior trained on photo views is scored on photo views.
        strands_per_style: ground-truth strands generated per hairstyle.
        n_dense: dense strands decoded from every predicted map.
        head: head model (default ``get_head("proxy-v1")``).
        seed: seed of the view poses (view ``v`` of (family, seed s) uses ``SeedSequence([seed, 4241, s, v])``
            plus the family index).
        max_points: cap on each point set of the Chamfer computation (random subset).
        progress: tqdm bar.

    Returns:
        One :class:`PriorEvalRow` per view.
    """
    from tqdm.auto import tqdm

    from vid2haircut.evaluate.metrics import evaluate_strands   # scoring only; prior never fits with it
    from vid2haircut.head import get_head
    from vid2haircut.prior.corpus import generate_style
    from vid2haircut.prior.hairmap import encode_strands
    from vid2haircut.prior.scalp import scalp_grid

    head = head if head is not None else get_head("proxy-v1")
    dev = next(net.parameters()).device
    res = net.cfg.map_res
    valid = torch.as_tensor(scalp_grid(head, res).valid)
    mean_mask = net.train_mean_mask.detach().cpu()
    baselines = {"mean_hairstyle": (torch.zeros_like(net.train_mean_z).cpu(), mean_mask),
                 "mean_map": (net.train_mean_z.detach().cpu(), mean_mask)}
    rows: list[PriorEvalRow] = []
    jobs = [(fi, f, s, v) for fi, f in enumerate(families) for s in seeds for v in range(views_per_style)]
    bar = tqdm(jobs, desc="prior eval", disable=not progress, leave=False)
    cache: dict[tuple[str, int], tuple[StrandSet, torch.Tensor, np.ndarray]] = {}
    for fi, fam, s, v in bar:
        if (fam, s) not in cache:
            cache.clear()
            gt = generate_style(fam, s, strands_per_style, codec.n_points, head)
            cache[(fam, s)] = (gt, encode_strands(gt, head, codec, res=res).mask > 0.5,
                               view_strands(gt.points, fam, s, view_cfg, codec.n_points, head))
        gt, target_mask, shown = cache[(fam, s)]
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 4241, int(s), int(v), fi]))
        pose = random_pose(rng, view_cfg)
        maps = training_view(shown, head, pose, view_cfg, int(rng.integers(2 ** 31)))
        x = prior_input(*maps.as_tuple(), maps.K, maps.world_2_cam, pose, size=net.cfg.input_size, device=dev)
        with torch.no_grad():
            z, logits = net(x)
        preds = {"prior": (z[0].cpu(), torch.sigmoid(logits[0]).cpu()), **baselines}
        chamfer, iou = {}, {}
        for name, (zm, mm) in preds.items():
            dense = _dense(zm, mm, head, codec, n_dense, seed)
            chamfer[name] = float(evaluate_strands(dense, gt, n_points=codec.n_points, max_points=max_points,
                                                   seed=seed)["chamfer_pts"]) if dense.n_strands else float("nan")
            pm = (mm > 0.5) & valid
            tm = target_mask & valid
            iou[name] = float((pm & tm).sum()) / max(float((pm | tm).sum()), 1.0)
        rows.append(PriorEvalRow(fam, int(s), int(v), chamfer, iou))
    return rows


def summarise(rows: Sequence[PriorEvalRow]) -> dict[str, dict[str, float]]:
    """Mean Chamfer_pts per family and method, plus ``"mean"`` over all rows (family -> method -> m^2)."""
    out: dict[str, dict[str, float]] = {}
    for fam in dict.fromkeys(r.family for r in rows):
        sel = [r for r in rows if r.family == fam]
        out[fam] = {m: float(np.nanmean([r.chamfer[m] for r in sel])) for m in METHODS}
    out["mean"] = {m: float(np.nanmean([r.chamfer[m] for r in rows])) for m in METHODS}
    return out


def markdown_summary(rows: Sequence[PriorEvalRow]) -> str:
    """A Markdown table: per family Chamfer_pts (x 1e-4 m^2) of the prior and the baselines, the
    prior's ratio to the mean hairstyle, and the mean mask IoU of the prior."""
    table = summarise(rows)
    lines = ["| family | prior | mean hairstyle | mean map | prior / mean hairstyle | prior mask IoU |",
             "|---|---|---|---|---|---|"]
    for fam, vals in table.items():
        sel = rows if fam == "mean" else [r for r in rows if r.family == fam]
        iou = float(np.mean([r.mask_iou["prior"] for r in sel]))
        name = "**mean**" if fam == "mean" else fam
        lines.append(f"| {name} | {1e4 * vals['prior']:.2f} | {1e4 * vals['mean_hairstyle']:.2f} | "
                     f"{1e4 * vals['mean_map']:.2f} | {vals['prior'] / vals['mean_hairstyle']:.2f} | {iou:.2f} |")
    return "\n".join(lines)
