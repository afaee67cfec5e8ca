"""Stage 2 settings sweep over a ``benchmarks/quality.py`` work folder, in parallel processes.

Starts every named Stage 2 setting from the cached default Stage 1 of each sequence (run
``benchmarks/quality.py --variants stage1`` on the work folder first), runs the (sequence, setting)
pairs ``--jobs`` at a time, and prints Chamfer_pts / Chamfer_angle per sequence, their means and
the front / side / back split, scored like ``quality.py``. Runs are cached under
``<work>/sweep/<sequence>/<setting>/``.

    .venv/bin/python benchmarks/stage2_sweep.py --work results/benchmarks/qx_prior_photo \
        --grid '{"base": {}, "lrz01": {"lr_z": 0.01}}' --jobs 2

For an accelerator machine the work is split: ``--pack DIR`` copies what Stage 2 needs (calibration,
front-stage outputs, Stage 1 hair maps; no images or ground truth) into a small folder that can
travel, ``--run-only --tar FILE`` runs there and bundles the hair maps of the runs made by that call
(about 0.35 MB each), and back here
``--untar FILE`` unpacks them; scoring then decodes each hair map to dense strands exactly as the
stage does (:func:`vid2haircut.fit.outputs.stage_strands`: same seed, keyframes and carving) before
comparing with the ground truth.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tarfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import quality_data  # noqa: E402  (the benchmark's sequence layout)
import quality_report  # noqa: E402
from quality_score import score  # noqa: E402

KEEP = ("hairmap.npz", "stage2.json")


def _run_one(job: tuple) -> tuple[str, str, float]:
    work, name, setting, over, device, threads = job
    import torch

    torch.set_num_threads(threads)
    from vid2haircut.fit.pipeline import run_stage2

    seq = quality_data.seq_files(Path(work), name)
    out = Path(work) / "sweep" / name / setting
    if not (out / "stage2.json").is_file():
        t0 = time.perf_counter()
        run_stage2(seq["root"], name, seq["keyframes"], seq["head"], seq["targets"],
                   Path(work) / "runs" / name / "stage1", out, settings=over, device=device, progress=False)
        return name, setting, time.perf_counter() - t0
    return name, setting, 0.0


def pack(work: Path, dest: Path, names: list[str]) -> None:
    """Copy what Stage 2 reads (no images, no ground truth) from ``work`` into ``dest``."""
    for n in names:
        cal = Path("data") / n / "calibration" / "camera_params.json"
        files = [cal, Path("front") / n / "keyframes.json", Path("front") / n / "head.npz"]
        files += [p.relative_to(work) for p in (work / "front" / n / "targets").iterdir()
                  if p.suffix in (".npz", ".json")]
        files += [Path("runs") / n / "stage1" / f for f in ("hairmap.npz", "codec.npz", "stage1.json")]
        for f in files:
            (dest / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(work / f, dest / f)


def decoded(work: Path, name: str, setting: str) -> Path:
    """Dense strands of one sweep run (decoded from its hair map when only that came back), exactly as
    the stage decodes them (:func:`vid2haircut.fit.outputs.stage_strands`: the run's seed, decoding
    settings, keyframes and fitting size, so carving sees what the run saw)."""
    from vid2haircut.fit.data import load_fit_data
    from vid2haircut.fit.outputs import load_hairmap, stage_strands
    from vid2haircut.fit.pipeline import stage2_config
    from vid2haircut.io.strand_formats import save_strands
    from vid2haircut.prior.codec import StrandCodec

    out = work / "sweep" / name / setting
    path = out / "strands.npz"
    if not path.is_file():
        seq = quality_data.seq_files(work, name)
        cfg = stage2_config(json.loads((out / "stage2.json").read_text())["config"])
        data = load_fit_data(seq["root"], name, seq["keyframes"], seq["head"], seq["targets"], size=cfg.render.size,
                             n_keyframes=cfg.n_keyframes, occlude_head=cfg.render.occlude_head)
        z, mask, _ = load_hairmap(out / "hairmap.npz")
        dense, _ = stage_strands(z, mask, data, StrandCodec.load(work / "runs" / name / "stage1" / "codec.npz"), cfg)
        save_strands(path, dense)
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", required=True, help="a benchmarks/quality.py work folder (Stage 1 cached)")
    p.add_argument("--grid", default='{"base": {}}', help="JSON {setting name: Stage 2 overrides}, or a file")
    p.add_argument("--sequences", default=",".join(f"{f}_{s}" for f, s in quality_data.SEQUENCES))
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--threads", type=int, default=1, help="torch threads per job")
    p.add_argument("--device", default="cpu")
    p.add_argument("--pack", default=None, help="copy the Stage 2 inputs to this folder and stop")
    p.add_argument("--run-only", action="store_true", help="run, do not score")
    p.add_argument("--tar", default=None, help="after running, bundle the runs' hair maps into this tar file")
    p.add_argument("--untar", default=None, help="unpack a --tar bundle into the work folder first")
    p.add_argument("--score-only", action="store_true", help="score the runs already in the work folder")
    p.add_argument("--out", default=None, help="also write the Markdown table here")
    args = p.parse_args(argv)
    work, names = Path(args.work), args.sequences.split(",")
    if args.pack:
        pack(work, Path(args.pack), names)
        return 0
    text = args.grid.strip()
    grid = json.loads(text if text.startswith("{") else Path(text).read_text())  # inline JSON or a file
    if args.untar:
        with tarfile.open(args.untar) as t:
            t.extractall(work, filter="data")
    jobs = [(str(work), n, s, over, args.device, args.threads) for s, over in grid.items() for n in names]
    new = []
    if not (args.untar or args.score_only):
        with ProcessPoolExecutor(args.jobs) as ex:
            for n, s, sec in ex.map(_run_one, jobs):
                print(f"{s} {n}: {sec:.1f}s", flush=True)
                if sec > 0:
                    new.append((n, s))
    if args.tar:  # only this call's runs: a carried work folder already holds the earlier ones
        with tarfile.open(args.tar, "w") as t:
            for n, s in new:
                for f in KEEP:
                    t.add(work / "sweep" / n / s / f, arcname=f"sweep/{n}/{s}/{f}")
    if args.run_only:
        return 0
    rows = ["| setting | " + " | ".join(names) + " | mean CD_pts | mean CD_angle | front | side | back |",
            "|---" * (len(names) + 6) + "|"]
    for s in grid:
        ms = [score(decoded(work, n, s), quality_data.seq_files(work, n)["gt"],
                            work / "sweep" / n / s / "metrics.json") for n in names]
        cells = [f"{m['chamfer_pts'] * 1e4:.4f}" for m in ms]
        reg = [np.mean([m[f"chamfer_pts_{r}"] for m in ms]) * 1e4 for r in ("front", "side", "back")]
        rows.append(f"| {s} | " + " | ".join(cells) + f" | {np.mean([m['chamfer_pts'] for m in ms]) * 1e4:.4f} | "
                    f"{np.mean([m['chamfer_angle'] for m in ms]):.4f} | " + " | ".join(f"{r:.3f}" for r in reg) + " |")
    text = "Stage 2 sweep, Chamfer_pts (1e-4 m^2) per sequence\n\n" + "\n".join(rows) + "\n"
    quality_report.emit(text, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
