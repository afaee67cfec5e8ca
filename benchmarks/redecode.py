"""Carry a ``benchmarks/quality.py`` work folder over to new dense-strand settings without refitting.

The fits (hair maps) do not depend on how the dense strands are decoded from them, so a change of
the decoding (``length_spread``, ``tip_scatter``, the silhouette carving) needs no new fit. This
makes a new work folder that links the old one's synthesised data and front-stage outputs, copies
each run's hair map, codec and record (the record's ``config`` gets the new decoding settings), and
decodes every run's dense strands again exactly as the stage does
(:func:`vid2haircut.fit.outputs.stage_strands`: the run's seed, and for carving the run's own
keyframes and fitting size). The prior and oracle rows are left out: ``quality.py`` remakes them
with the present code.
Then ``quality.py --work NEW ...`` with the old variants scores everything and prints the tables.

    python benchmarks/redecode.py --src results/benchmarks/quality_v13 --dst results/benchmarks/quality_v14 \
        [--length-spread 0.04] [--tip-scatter 0.002] [--carve-tolerance 1.0] [--runs stage1,stage2] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import quality_data  # noqa: E402  (the benchmark's sequence layout)

from vid2haircut.fit.components import CARVE_TOLERANCE, LENGTH_SPREAD  # noqa: E402
from vid2haircut.fit.config import Stage2Config  # noqa: E402

RECORDS = ("stage1.json", "stage2.json")


def redecode_sequence(job: tuple) -> list[str]:
    """Re-decode every fitted run of one sequence into ``dst``; returns the run folders written."""
    src, dst, name, decoding, only = job
    import torch

    torch.set_num_threads(1)                           # --jobs processes share the cores
    from vid2haircut.fit.data import load_fit_data
    from vid2haircut.fit.outputs import load_hairmap, stage_strands
    from vid2haircut.fit.pipeline import stage1_config, stage2_config
    from vid2haircut.io.atomic import write_json
    from vid2haircut.io.strand_formats import save_strands
    from vid2haircut.prior.codec import StrandCodec

    seq = quality_data.seq_files(Path(src), name)
    loaded: dict = {}
    done = []
    for run in sorted((Path(src) / "runs" / name).iterdir()):
        if only and run.name not in only:
            continue
        rec = next((run / r for r in RECORDS if (run / r).is_file()), None)
        if rec is None or not (run / "hairmap.npz").is_file():
            continue                                   # prior / oracle rows: remade by quality.py
        out = Path(dst) / "runs" / name / run.name
        if (out / "strands.npz").is_file():
            done.append(str(out))
            continue
        out.mkdir(parents=True, exist_ok=True)
        for f in ("hairmap.npz", "codec.npz"):
            shutil.copy2(run / f, out / f)
        record = json.loads(rec.read_text())
        stage1 = rec.name == "stage1.json"
        rc = record["config"]
        # only what the decoding reads (older records may hold settings the code no longer has)
        keep = {k: rc[k] for k in ("seed", "n_dense", "n_keyframes") if k in rc}
        keep["render"] = {k: rc["render"][k] for k in ("size", "occlude_head") if k in rc.get("render", {})}
        cfg = (stage1_config if stage1 else stage2_config)({**keep, **decoding})
        # the stage's own keyframes and fitting size: carving sees what the stage saw
        key = (1 if stage1 else cfg.n_keyframes, cfg.render.size, cfg.render.occlude_head)
        if key not in loaded:
            loaded[key] = load_fit_data(seq["root"], name, seq["keyframes"], seq["head"], seq["targets"],
                                        size=key[1], n_keyframes=key[0], occlude_head=key[2])
        z, mask, _ = load_hairmap(run / "hairmap.npz")
        dense, cut = stage_strands(z, mask, loaded[key], StrandCodec.load(run / "codec.npz"), cfg)
        save_strands(out / "strands.npz", dense)
        record["config"].update(decoding)
        record["carved_fraction"] = cut
        write_json(out / rec.name, record)             # last: quality.py treats the record as "run done"
        done.append(str(out))
    return done


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--src", required=True, help="existing quality.py work folder")
    p.add_argument("--dst", required=True, help="new work folder (created)")
    p.add_argument("--length-spread", type=float, default=LENGTH_SPREAD, help="relative spread of dense strand lengths")
    p.add_argument("--tip-scatter", type=float, default=0.0, help="per-axis spread of the strand tips, metres")
    p.add_argument("--carve-tolerance", type=float, default=CARVE_TOLERANCE,
                   help="silhouette carving tolerance, fitting pixels (0 = off)")
    p.add_argument("--carve-min-fraction", type=float, default=Stage2Config.carve_min_fraction,
                   help="see Stage2Config.carve_min_fraction")
    p.add_argument("--sequences", default=None, help="comma-separated names (default: every sequence in --src)")
    p.add_argument("--runs", default=None, help="comma-separated run (variant) names (default: every fitted run)")
    p.add_argument("--jobs", type=int, default=1)
    args = p.parse_args(argv)
    src, dst = Path(args.src).resolve(), Path(args.dst)
    if not (src / "runs").is_dir():
        raise SystemExit(f"{src}: not a quality.py work folder (no runs/)")
    names = args.sequences.split(",") if args.sequences else sorted(d.name for d in (src / "runs").iterdir())
    dst.mkdir(parents=True, exist_ok=True)
    for sub in ("data", "front"):
        link = dst / sub
        if not link.exists():
            os.symlink(os.path.realpath(src / sub), link)
    only = tuple(args.runs.split(",")) if args.runs else ()
    decoding = {"length_spread": float(args.length_spread), "tip_scatter": float(args.tip_scatter),
                "carve_tolerance": float(args.carve_tolerance), "carve_min_fraction": float(args.carve_min_fraction)}
    jobs = [(str(src), str(dst), n, decoding, only) for n in names]
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as ex:
        for n, done in zip(names, ex.map(redecode_sequence, jobs)):
            print(f"{n}: {len(done)} runs decoded", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
