"""Cost of the default prior training, measured on a sample and extrapolated; device check.

Times hairstyle generation (per style), training-view rendering (per view) and optimiser steps
of the default setting on the current machine, and extrapolates the full ``train_prior`` run
(styles x views x steps). With ``--device cuda`` it also trains a few steps on the accelerator and
checks that the CPU and the accelerator give the same forward pass for the same weights.

    .venv/bin/python benchmarks/prior_train_timing.py --threads 1 [--device cuda] [--out t.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch

from vid2haircut.head import get_head
from vid2haircut.io.atomic import write_json
from vid2haircut.prior.corpus import build_corpus, fit_codec
from vid2haircut.prior.dataset import build_dataset
from vid2haircut.prior.train import SETTINGS, fit_prior_net


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--styles", type=int, default=3, help="sample hairstyles to generate")
    ap.add_argument("--steps", type=int, default=30, help="sample optimiser steps")
    ap.add_argument("--device", default="cpu", help="also train on this device (e.g. cuda)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    cfg = SETTINGS["default"]
    head = get_head(cfg.data.head)
    fams = cfg.data.families_or_all()
    n_styles = len(fams) * len(cfg.data.train_seeds)

    t0 = time.perf_counter()
    corpus = build_corpus(fams[:args.styles], [0], cfg.data.strands_per_style, cfg.data.n_points, head)
    per_style = (time.perf_counter() - t0) / args.styles
    codec = fit_codec(corpus, k=cfg.model.k)
    t0 = time.perf_counter()
    data = build_dataset(corpus, codec, head, cfg.data, cfg.model.input_size, cfg.model.map_res, 0, None, False)
    per_view = (time.perf_counter() - t0) / data.n_views
    warm = dataclasses.replace(cfg, steps=3)
    fit_prior_net(data, codec, head, warm, 0, "cpu", False)
    sample = dataclasses.replace(cfg, steps=args.steps)
    t0 = time.perf_counter()
    _, hist = fit_prior_net(data, codec, head, sample, 0, "cpu", False)
    per_step = (time.perf_counter() - t0) / args.steps
    total = n_styles * (per_style + cfg.data.views_per_style * per_view) + cfg.steps * per_step
    out = {"threads": args.threads, "torch": torch.__version__, "per_style_s": per_style, "per_view_s": per_view,
           "per_step_s": per_step, "styles": n_styles, "views": n_styles * cfg.data.views_per_style,
           "steps": cfg.steps, "extrapolated_total_min": total / 60.0}
    if args.device != "cpu":
        dev = torch.device(args.device)
        t0 = time.perf_counter()
        net, hist = fit_prior_net(data, codec, head, dataclasses.replace(cfg, steps=60), 0, dev, False)
        out["device"] = {"name": str(dev), "steps": 60, "wall_s": time.perf_counter() - t0,
                         "first_loss": hist[0]["total"], "last_loss": hist[-1]["total"]}
        x = data.inputs[:4].float()
        with torch.no_grad():
            z_dev, m_dev = net(x.to(dev))
            z_cpu, m_cpu = net.cpu()(x)
        out["device"]["max_abs_diff_z"] = float((z_dev.cpu() - z_cpu).abs().max())
        out["device"]["max_abs_diff_mask"] = float((m_dev.cpu() - m_cpu).abs().max())
    print(json.dumps(out, indent=2))
    if args.out is not None:
        write_json(args.out, out)
    return 0 if np.isfinite(out["per_step_s"]) else 1


if __name__ == "__main__":
    raise SystemExit(main())
