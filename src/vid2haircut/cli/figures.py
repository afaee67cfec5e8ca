"""``vid2haircut figures``: report figures (turntable strip, scalp coverage map, metrics table)."""

from __future__ import annotations

import argparse

from vid2haircut.cli import argtypes


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("figures", help="report figures: turntable, coverage, metrics-table",
                              description=__doc__)
    sub = p.add_subparsers(dest="figure", required=True, metavar="<figure>")

    t = sub.add_parser("turntable", help="front / 3/4 / side / back views of strands on the head (PNG)")
    t.add_argument("--strands", required=True, help="reconstructed strands (.npz, .data, .hair, .ply)")
    t.add_argument("--gt", default=None, help="ground-truth strands, drawn as a second row")
    t.add_argument("--head", default=None, help="fitted head.npz or head model name (default: the strands' own)")
    t.add_argument("--size", type=argtypes.bounded_int(16, 4096), default=256, help="side of one view, pixels")
    t.add_argument("--max-strands", type=argtypes.nonneg_int, default=20000, help="thin larger strand sets to this many")
    t.add_argument("--seed", type=argtypes.nonneg_int, default=0, help="seed of the thinning and colour jitter")
    t.add_argument("--out", required=True, type=argtypes.image_path, help="output PNG")
    t.set_defaults(func=run_turntable)

    c = sub.add_parser("coverage", help="scalp coverage map: keyframes that saw each scalp texel (PNG)")
    c.add_argument("--root", required=True, help="dataset root (for <root>/<subject>/calibration)")
    c.add_argument("--subject", required=True)
    c.add_argument("--seq", required=True)
    c.add_argument("--keyframes", required=True, help="keyframes.json")
    c.add_argument("--head", required=True, help="head.npz of the fitted head poses")
    c.add_argument("--res", type=argtypes.bounded_int(1, 4096), default=64, help="scalp UV resolution of the map")
    c.add_argument("--device", default="cpu", type=argtypes.device, help="torch device of the head z-buffer")
    c.add_argument("--out", required=True, type=argtypes.image_path, help="output PNG")
    c.set_defaults(func=run_coverage)

    m = sub.add_parser("metrics-table", help="metrics.json files of one sequence -> table (.png, .rst or .md)")
    m.add_argument("--inputs", nargs="*", default=[], metavar="JSON",
                   help="metrics files laid out as .../{subject}/{seq}/{stage}/{variant}/metrics.json")
    m.add_argument("--labels", nargs="+", default=None, metavar="S/Q/STAGE/VARIANT",
                   help="one label per input instead of reading them from the paths")
    m.add_argument("--no-gt", nargs="+", default=[], metavar="S/Q/STAGE/VARIANT",
                   help="runs without ground truth, shown with n/a")
    m.add_argument("--title", default="", help="table title")
    m.add_argument("--out", required=True, help="output .png, .rst or .md")
    m.set_defaults(func=run_metrics_table)


def run_turntable(args: argparse.Namespace) -> int:
    from vid2haircut.report.turntable import TurntableStyle, write_turntable

    write_turntable(args.out, args.strands, args.gt, head=args.head,
                    style=TurntableStyle(size=args.size, max_strands=args.max_strands, seed=args.seed))
    return 0


def run_coverage(args: argparse.Namespace) -> int:
    from vid2haircut.report.coverage import write_coverage

    write_coverage(args.out, args.root, args.subject, args.seq, args.keyframes, args.head, res=args.res,
                   device=args.device)
    return 0


def run_metrics_table(args: argparse.Namespace) -> int:
    from vid2haircut.report.metrics_table import write_metrics_table

    write_metrics_table(args.out, args.inputs, labels=args.labels, no_gt=args.no_gt, title=args.title)
    return 0
