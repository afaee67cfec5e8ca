"""Time of one Stage 2 step, in each of its two phases, on a sequence of a quality work folder.

Runs a short Stage 2 schedule from the cached default Stage 1 of one sequence of a
``benchmarks/quality.py`` work folder (``--canonical`` steps that draw the guides, then
``--dense`` steps with the deformation field on and the dense strands drawn, as the default's
second half) and prints the median wall time of a step of each phase (the first two steps of
each phase are left out: numba's cache loading and the phase's first renders). Everything else
is the default Stage 2 configuration, with ``--settings`` overrides (JSON) on top.

    .venv/bin/python benchmarks/stage2_steps.py --work results/benchmarks/quality_v22 --sequence bob_1000 \\
        [--threads 2] [--settings '{"render": {"size": 160}}']
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import vid2haircut  # noqa: F401  (before torch, as in the CLI: see the package docstring)

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import quality_data  # noqa: E402  (the work folder's layout)


def run_short(work: Path, sequence: str, canonical: int, dense: int, settings: dict) -> None:
    """A ``canonical`` + ``dense`` step Stage 2 run from the work folder's cached Stage 1 of
    ``sequence`` (default configuration with ``settings`` on top), into a temporary folder."""
    from vid2haircut.fit.pipeline import run_stage2

    seq = quality_data.seq_files(work, sequence)
    stage1 = work / "runs" / sequence / "stage1"
    if not (stage1 / "hairmap.npz").is_file():
        raise SystemExit(f"{stage1 / 'hairmap.npz'}: no Stage 1 here; run benchmarks/quality.py "
                         "--variants stage1 first")
    over = {**settings, "iterations": canonical + dense, "canonical_steps": canonical,
            "ramp_steps": max(1, dense // 4), "checkpoint_every": 0}
    out = Path(tempfile.mkdtemp(prefix="stage2_short_"))
    try:
        run_stage2(seq["root"], seq["subject"], seq["keyframes"], seq["head"], seq["targets"], stage1, out,
                   settings=over, progress=False, resume=False)
    finally:
        shutil.rmtree(out, ignore_errors=True)


def step_times(work: Path, sequence: str, canonical: int, dense: int, settings: dict) -> tuple[list, list]:
    """Wall seconds of every step of a ``canonical`` + ``dense`` step Stage 2 run -> (guide steps, dense steps)."""
    from vid2haircut.fit import trainer

    times: list[float] = []
    original = trainer.Trainer.step

    def timed(self, *args, **kwargs):
        t0 = time.perf_counter()
        out = original(self, *args, **kwargs)
        times.append(time.perf_counter() - t0)
        return out

    trainer.Trainer.step = timed
    try:
        run_short(work, sequence, canonical, dense, settings)
    finally:
        trainer.Trainer.step = original
    return times[:canonical], times[canonical:]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", required=True, help="a benchmarks/quality.py work folder (Stage 1 cached)")
    p.add_argument("--sequence", default="bob_1000")
    p.add_argument("--canonical", type=int, default=10, help="guide steps (no deformation field)")
    p.add_argument("--dense", type=int, default=30, help="steps with the field and the dense strands")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--settings", default="{}", help="JSON Stage 2 overrides")
    args = p.parse_args(argv)
    if args.canonical < 3 or args.dense < 3:
        raise SystemExit("--canonical and --dense need at least 3 steps each (the first two are left out)")
    torch.set_num_threads(args.threads)
    guide, dense = step_times(Path(args.work), args.sequence, args.canonical, args.dense, json.loads(args.settings))
    print(f"{args.sequence}, {args.threads} threads, settings {args.settings}: guide step "
          f"{statistics.median(guide[2:]) * 1e3:.0f} ms, dense step {statistics.median(dense[2:]) * 1e3:.0f} ms "
          f"(medians of {len(guide) - 2} and {len(dense) - 2} steps)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
