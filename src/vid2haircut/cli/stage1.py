"""``vid2haircut stage1``: single-view fit of the hair map on the reference keyframe (Im2Haircut baseline)."""

from __future__ import annotations

import argparse

from vid2haircut.cli import argtypes


def add_fit_args(p: argparse.ArgumentParser) -> None:
    """Arguments shared by the fitting stages: the sequence, its front-stage files, settings."""
    from vid2haircut.cli.keyframes import add_sequence_args

    add_sequence_args(p)
    p.add_argument("--keyframes", required=True, help="keyframes.json of the keyframes stage")
    p.add_argument("--head", required=True, help="head.npz of the fit_head stage")
    p.add_argument("--targets", "--targets-dir", dest="targets", required=True, help="folder of the targets stage (frame_<t>.npz)")
    p.add_argument("--settings", default=None,
                   help='config overrides: a JSON object or a .json file, e.g. \'{"iterations": 50}\'')
    p.add_argument("--device", default=None, type=argtypes.device, help="torch device (default: the config's, cpu)")
    p.add_argument("--seed", type=argtypes.nonneg_int, default=None, help="seed (default: the config's, 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("stage1", help="single-view hair map fit -> strands.npz, hairmap.npz, renders",
                              description=__doc__)
    add_fit_args(p)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--prior-dir", default=None, help="trained prior folder (codec.npz, prior.pt, prior.json)")
    src.add_argument("--codec", default=None, help="strand codec .npz: optimise the hair map directly (no prior)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vid2haircut.fit.settings import load_settings
    from vid2haircut.fit.pipeline import run_stage1

    run_stage1(args.dataset_root, args.subject, args.keyframes, args.head, args.targets, args.out,
               prior_dir=args.prior_dir, codec_path=args.codec, settings=load_settings(args.settings),
               device=args.device, seed=args.seed, progress=not args.no_progress)
    return 0
