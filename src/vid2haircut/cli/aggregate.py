"""``vid2haircut aggregate``: collect metrics.json files into metrics.csv and a Markdown table of means."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("aggregate", help="metrics.json files -> metrics.csv + Markdown table of means",
                              description=__doc__)
    p.add_argument("--inputs", nargs="*", default=[], metavar="JSON",
                   help="metrics files, laid out as .../{subject}/{seq}/{stage}/{variant}/metrics.json "
                        "unless --labels is given")
    p.add_argument("--labels", nargs="+", default=None, metavar="S/Q/STAGE/VARIANT",
                   help="one subject/seq/stage/variant label per input, in the same order")
    p.add_argument("--no-gt", nargs="+", default=[], metavar="S/Q/STAGE/VARIANT",
                   help="runs without ground truth (no metrics file): listed with empty metric cells")
    p.add_argument("--out-csv", required=True, help="output CSV, one row per subject/seq/stage/variant")
    p.add_argument("--out-md", default=None, help="output Markdown table of means per stage/variant")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vid2haircut.evaluate.aggregate import aggregate_metrics

    aggregate_metrics(args.inputs, args.out_csv, args.out_md, labels=args.labels, no_gt=args.no_gt)
    return 0
