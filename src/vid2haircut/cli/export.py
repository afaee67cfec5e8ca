"""``vid2haircut export``: write a strand file as USD, .hair, .data, PLY and .npz (plus head.obj)."""

from __future__ import annotations

import argparse

from vid2haircut.cli import argtypes


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("export", help="export strands to USD / .hair / .data / PLY / .npz",
                              description=__doc__)
    p.add_argument("--strands", required=True, help="input strand file (.npz, .data, .hair, .ply)")
    p.add_argument("--out-dir", required=True, type=argtypes.out_folder, help="output folder")
    p.add_argument("--head", default=None, help="head model to export alongside (e.g. proxy-v1)")
    p.add_argument("--stem", default="hair", type=argtypes.file_stem, help="file name stem of the strand files")
    p.add_argument("--usd-format", choices=("usda", "usdc"), default="usda", help="USD encoding")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vid2haircut.export.export import export_files

    export_files(args.strands, args.out_dir, head=args.head, stem=args.stem, usd_format=args.usd_format)
    return 0
