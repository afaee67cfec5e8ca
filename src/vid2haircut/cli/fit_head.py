"""``vid2haircut fit_head``: fit the head shape and a rigid pose per keyframe to face landmarks."""

from __future__ import annotations

import argparse

from vid2haircut.cli import argtypes
from vid2haircut.cli.keyframes import add_sequence_args


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("fit_head", help="head pose per keyframe -> head.npz + overlay PNG",
                              description=__doc__)
    add_sequence_args(p)
    p.add_argument("--keyframes", required=True, help="keyframes.json of the keyframes stage")
    p.add_argument("--head-model", default="proxy-v1", help="head model name or FLAME .pkl path")
    p.add_argument("--landmark-embedding", default=None,
                   help="FLAME landmark embedding (.npz/.pkl with lmk_face_idx, lmk_b_coords)")
    p.add_argument("--landmarks", default="auto", choices=["auto", "file", "detect"],
                   help="landmark source: the sequence's landmark file, MediaPipe detection, or auto")
    p.add_argument("--use-tracking", action="store_true",
                   help="take the poses from tracking/head_tracking.npz instead of fitting them")
    p.add_argument("--fit-scale", action="store_true", help="also fit the overall head scale (ill-posed)")
    p.add_argument("--min-frames", type=argtypes.bounded_int(1), default=1, help="fail when fewer keyframes have a face")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vid2haircut.front.pose import PoseFitConfig
    from vid2haircut.front.stages import run_fit_head

    run_fit_head(args.dataset_root, args.subject, args.sequence, args.keyframes, args.out, serial=args.serial,
                 head_model=args.head_model, use_tracking=args.use_tracking, landmark_source=args.landmarks,
                 cfg=PoseFitConfig(fit_scale=args.fit_scale), min_frames=args.min_frames,
                 landmark_embedding=args.landmark_embedding)
    return 0
