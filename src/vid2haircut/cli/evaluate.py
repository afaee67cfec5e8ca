"""``vid2haircut evaluate``: score a predicted strand file against ground-truth strands."""

from __future__ import annotations

import argparse

from vid2haircut.cli import argtypes


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("evaluate", help="Chamfer / angle / F1 metrics of strands against ground truth",
                              description=__doc__)
    p.add_argument("--pred", required=True, help="predicted strands (.npz, .data, .hair, .ply)")
    p.add_argument("--gt", required=True, help="ground-truth strands (e.g. ground_truth/strands.npz)")
    p.add_argument("--out", required=True, help="output metrics JSON")
    p.add_argument("--n-points", type=int, default=100, help="points per strand after resampling")
    p.add_argument("--max-points", type=argtypes.nonneg_int, default=0,
                   help="cap on each point set (random subset; 0 = every point, exact)")
    p.add_argument("--seed", type=argtypes.nonneg_int, default=0, help="seed of the subsampling")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vid2haircut.evaluate.metrics import evaluate_files

    evaluate_files(args.pred, args.gt, args.out, n_points=args.n_points, max_points=args.max_points,
                   seed=args.seed)
    return 0
