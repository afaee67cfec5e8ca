"""The ``vid2haircut`` command: one sub-command per pipeline stage.

Each sub-command lives in its own module of this folder, which defines ``register(subparsers)``
(argument parsing only) and calls exactly one library function. Logic lives in the package.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

# Sub-command modules, in the order of the pipeline.
COMMANDS = [
    "head",
    "synthesize",
    "keyframes",
    "fit_head",
    "targets",
    "train_prior",
    "stage1",
    "stage2",
    "evaluate",
    "export",
    "aggregate",
    "figures",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vid2haircut", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="<stage>")
    for name in COMMANDS:
        importlib.import_module(f"vid2haircut.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    try:
        rc = args.func(args)
    except (ValueError, FileNotFoundError, OSError) as e:
        logging.getLogger("vid2haircut").error("%s", e)
        return 2
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
