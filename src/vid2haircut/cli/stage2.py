"""``vid2haircut stage2``: joint refinement over the keyframes (deformation MLP, visibility-aware updates)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    from vid2haircut.cli.stage1 import add_fit_args

    p = subparsers.add_parser("stage2", help="multi-keyframe refinement -> dense canonical strands.npz",
                              description=__doc__)
    add_fit_args(p)
    p.add_argument("--stage1-dir", required=True, help="output folder of stage1 (hairmap.npz, codec.npz)")
    p.add_argument("--no-resume", action="store_true", help="ignore an existing checkpoint.pt in --out")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vid2haircut.fit.settings import load_settings
    from vid2haircut.fit.pipeline import run_stage2

    run_stage2(args.dataset_root, args.subject, args.keyframes, args.head, args.targets, args.stage1_dir, args.out,
               settings=load_settings(args.settings), device=args.device, seed=args.seed,
               resume=not args.no_resume, progress=not args.no_progress)
    return 0
