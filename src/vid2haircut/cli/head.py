"""``vid2haircut head export DIR``: write the built-in proxy head (mesh, landmarks, scalp UV)."""

from __future__ import annotations

import argparse

from vid2haircut.cli import argtypes


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("head", help="head model tools")
    sub = parser.add_subparsers(dest="head_command", required=True, metavar="<action>")
    exp = sub.add_parser("export", help="write head.obj, landmarks.json and scalp_uv.npz of the proxy head")
    exp.add_argument("out_dir", metavar="DIR", type=argtypes.out_folder, help="output folder")
    for name, what in (("scale", "overall size"), ("width", "ear-to-ear width"),
                       ("depth", "front-to-back depth"), ("crown", "height of the cranium top")):
        exp.add_argument(f"--{name}", type=float, default=1.0, help=f"{what} factor (default 1)")
    exp.add_argument("--res", type=argtypes.bounded_int(1, 4096), default=64, help="scalp UV map resolution (default 64)")
    exp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vid2haircut.head.export import export_proxy_head

    export_proxy_head(args.out_dir, scale=args.scale, width=args.width, depth=args.depth,
                      crown=args.crown, res=args.res)
    return 0
