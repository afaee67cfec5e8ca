"""``vid2haircut train_prior``: train the learned hair prior (cached: skipped when up to date)."""

from __future__ import annotations

import argparse

from vid2haircut.cli import argtypes


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("train_prior", help="train the hair prior (codec + network) on generated hairstyles",
                              description=__doc__)
    p.add_argument("--out-dir", required=True, type=argtypes.out_folder, help="artifact folder (codec.npz, prior.pt, prior.json)")
    p.add_argument("--setting", default="default", choices=["default", "tiny", "render", "render_large", "standoff"],
                   help="training preset (vid2haircut.prior.train.SETTINGS): default = photo-like views (the "
                        "bundled prior), tiny = tests, render / render_large = direct renders, standoff = default "
                        "with the standoff term")
    p.add_argument("--seed", type=argtypes.nonneg_int, default=0, help="seed of views, initialisation and batches")
    p.add_argument("--device", default="cpu", type=argtypes.device, help="torch device, e.g. cpu or cuda")
    p.add_argument("--cache-dir", default=None,
                   help="cache of the generated corpus and rendered views (default: a temporary folder)")
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads while training (default 1: reproducible on any machine)")
    p.add_argument("--force", action="store_true", help="retrain even when the artifact is up to date")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vid2haircut.prior.train import train_prior

    train_prior(args.out_dir, setting=args.setting, seed=args.seed, device=args.device, cache_dir=args.cache_dir,
                force=args.force, num_threads=args.threads)
    return 0
