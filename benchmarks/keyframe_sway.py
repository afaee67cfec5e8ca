"""How far the hair of each keyframe is from rest: the ground truth's tip sway per keyframe.

For every sequence of ``benchmarks/quality.py`` work folders, prints the selected keyframes (the
reference marked ``*``) with the mean over the ground-truth strands (every ``--stride``-th) of the
tip's offset from the rest hairstyle at that frame, in millimetres (``vid2haircut.synth.motion``:
the same moved strands the synthesiser rendered). The reference keyframe defines the canonical hair
(Stage 1 fits it, Stage 2 pins its deformation to zero), so its sway is an error that no stage can
remove.

    .venv/bin/python benchmarks/keyframe_sway.py results/benchmarks/quality_v11 results/benchmarks/quality_v12
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import quality_data  # noqa: E402  (the benchmark's sequence layout)


def tip_sway(rest: np.ndarray, params, frames: list[int]) -> np.ndarray:
    """(N,P,3) rest strands, MotionParams, K frames -> (K, N) ground-truth tip offsets from rest, metres."""
    from vid2haircut.synth.motion import sway_points

    return np.stack([np.linalg.norm(sway_points(rest, params, t)[:, -1] - rest[:, -1], axis=-1) for t in frames])


def keyframe_sway(work: Path, name: str, stride: int = 5) -> tuple[list[int], int, list[float]]:
    """(keyframes, reference, mean tip sway per keyframe in mm) of one sequence of a work folder."""
    from vid2haircut.io.strand_formats import load_strands
    from vid2haircut.synth.motion import MotionParams

    seq = quality_data.seq_files(work, name)
    meta = json.loads(seq["gt"].with_name("meta.json").read_text())
    rest = np.asarray(load_strands(seq["gt"]).points[::stride])
    kf = json.loads(seq["keyframes"].read_text())
    sway = tip_sway(rest, MotionParams.from_dict(meta["motion"]), kf["frames"]).mean(axis=1) * 1e3
    return kf["frames"], kf["reference"], [float(x) for x in sway]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("work", nargs="+", help="benchmarks/quality.py work folders")
    p.add_argument("--stride", type=int, default=5, help="use every stride-th ground-truth strand")
    args = p.parse_args(argv)
    for w in map(Path, args.work):
        refs = []
        print(f"{w}: mean tip sway (mm) per keyframe, * = reference")
        for d in sorted((w / "front").iterdir()):
            if not (d / "keyframes.json").is_file():
                continue
            frames, ref, sway = keyframe_sway(w, d.name, args.stride)
            refs.append(sway[frames.index(ref)])
            cells = "  ".join(f"{t}{'*' if t == ref else ''}: {s:.1f}" for t, s in zip(frames, sway))
            print(f"  {d.name:24s} {cells}")
        if refs:
            print(f"  reference sway: mean {np.mean(refs):.2f} mm, max {np.max(refs):.2f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
