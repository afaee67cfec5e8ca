"""Why the prior predicts hair too short: its inputs from the pipeline's targets vs from a clean render.

The prior is trained on views rendered by :func:`vid2haircut.prior.views.render_view` (wide
strands, exact 2D directions) but at test time it sees the pipeline's targets of the reference
keyframe (the sequence's hair mask, Gabor orientation of the photo, relative depth). For each
sequence of a ``benchmarks/quality.py`` work folder this script renders the ground-truth hairstyle
the training way from the reference keyframe's camera and fitted head pose, and runs the prior on
the pipeline's input, on the clean render, and on the pipeline's input with one channel (mask,
orientation, depth) swapped for the clean one. It prints, per input, the median tip height per root
region (metres, head frame +y up; see :func:`vid2haircut.evaluate.metrics.tip_heights`) and
Chamfer_pts (1e-4 m^2, 4000 decoded strands) against the ground truth.

    .venv/bin/python benchmarks/prior_gap.py --work results/benchmarks/quality_v5 \\
        --sequences bob_1000,shoulder_straight_1001,wavy_1004
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

INPUTS = ("pipeline", "clean render", "clean mask", "clean orientation", "clean depth")


def gap_rows(work: Path, seq: str, prior_dir: Path, n_dense: int = 4000) -> list[tuple[str, dict, float]]:
    """(input name, tip heights, Chamfer_pts 1e-4 m^2) for every entry of :data:`INPUTS` (plus the ground truth)."""
    from vid2haircut.evaluate.metrics import evaluate_strands, tip_heights
    from vid2haircut.fit.data import load_fit_data
    from vid2haircut.fit.outputs import dense_strands
    from vid2haircut.fit.stage1 import initial_hairmap
    from vid2haircut.io.strand_formats import load_strands
    from vid2haircut.prior.model import load_prior, prior_input
    from vid2haircut.prior.views import ViewConfig, render_view

    front = work / "front" / seq
    root = work / "data"
    data = load_fit_data(root, seq, front / "keyframes.json", front / "head.npz", front / "targets", n_keyframes=1,
                         occlude_head=False)
    net, codec, _ = load_prior(prior_dir)
    gt = load_strands(root / seq / "sequences" / "HAIR" / "ground_truth" / "strands.npz")
    t = data.reference_targets
    K, w2c = data.reference_camera
    pose = data.world_from_head[0]
    clean = render_view(np.asarray(gt.points)[::3], data.head, pose,
                        ViewConfig(render_size=t["mask"].shape[0], render_strands=3000), seed=0,
                        distance=float(np.linalg.norm((w2c[:3, :3].T @ -w2c[:3, 3])[[0, 2]])))
    if not (np.allclose(clean.K, K, rtol=1e-3, atol=0.5) and np.allclose(clean.world_2_cam, w2c, atol=1e-3)):
        raise SystemExit(f"{seq}: the reference camera is not the synthetic sequences' set-up that render_view "
                         "uses, so the clean render would not line up with the targets")
    pipe = (t["mask"], t["angle"], t["depth"], t["depth_valid"])
    ref = (clean.mask, clean.angle, clean.depth, clean.depth_valid)
    inputs = {"pipeline": pipe, "clean render": ref,
              "clean mask": (ref[0],) + pipe[1:],
              "clean orientation": (pipe[0], ref[1]) + pipe[2:],
              "clean depth": pipe[:2] + ref[2:]}
    rows = [("ground truth", tip_heights(gt), 0.0)]
    for name in INPUTS:
        x = prior_input(*inputs[name], K, w2c, pose, size=net.cfg.input_size)
        z, mask = initial_hairmap(data, codec, (net, x))
        s = dense_strands(z, mask, data.head, codec, n_dense, 0, data.head_model)
        cd = evaluate_strands(s, gt, max_points=100_000)["chamfer_pts"] * 1e4
        rows.append((name, tip_heights(s), float(cd)))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", default="results/benchmarks/quality_v5", help="a benchmarks/quality.py work folder")
    p.add_argument("--sequences", default="bob_1000,shoulder_straight_1001,wavy_1004")
    p.add_argument("--prior-dir", default=None, help="trained prior (default: the packaged one)")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    import vid2haircut

    prior_dir = Path(args.prior_dir) if args.prior_dir else Path(vid2haircut.__file__).parent / "data/prior/default"
    print("| sequence | prior input | tip front (m) | tip side (m) | tip back (m) | Chamfer_pts (1e-4 m^2) |")
    print("|---|---|---|---|---|---|")
    for seq in args.sequences.split(","):
        for name, tips, cd in gap_rows(Path(args.work), seq, prior_dir):
            print(f"| {seq} | {name} | {tips['front']:.3f} | {tips['side']:.3f} | {tips['back']:.3f} | "
                  f"{'-' if name == 'ground truth' else f'{cd:.3f}'} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
