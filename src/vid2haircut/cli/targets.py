"""``vid2haircut targets``: hair mask, Gabor orientation and relative depth targets per keyframe."""

from __future__ import annotations

import argparse

from vid2haircut.cli import argtypes

from vid2haircut.cli.keyframes import add_sequence_args


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("targets", help="per-keyframe targets -> frame_<t>.npz + orientation PNGs",
                              description=__doc__)
    add_sequence_args(p)
    p.add_argument("--head", required=True, help="head.npz of the fit_head stage")
    p.add_argument("--mask-source", default="auto", choices=["auto", "file", "fallback"],
                   help="hair masks: the sequence's hair_masks, the GrabCut fallback, or auto")
    p.add_argument("--depth-source", default="auto", choices=["auto", "maps", "triangulate", "none"],
                   help="depth: the sequence's depth_maps, sparse triangulation, none, or auto")
    p.add_argument("--device", default=None, type=argtypes.device, help="torch device of the Gabor bank (default cpu)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vid2haircut.front.stages import run_targets

    run_targets(args.dataset_root, args.subject, args.sequence, args.head, args.out, serial=args.serial,
                mask_source=args.mask_source, depth_source=args.depth_source, device=args.device)
    return 0
