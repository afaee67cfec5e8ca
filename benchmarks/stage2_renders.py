"""Time the renders of a Stage 2 step: its ``render_strands`` calls, recorded and replayed.

Runs a few Stage 2 steps (``--steps``, half of them drawing the guides, then the dense strands) from
the cached default Stage 1 of one sequence of a ``benchmarks/quality.py`` work folder, records the
first ``render_strands`` call of each kind (points shape, strand width, translucent silhouette,
whether the step differentiates it), then times each: forward+backward of silhouette + normalised
depth + direction when the fit differentiates it, else the forward alone; best of ``--repeat``.

    .venv/bin/python benchmarks/stage2_renders.py --work results/benchmarks/quality_set2_v24 \\
        --sequence short_straight_1015 [--threads 2] [--repeat 8]
"""

from __future__ import annotations

import vid2haircut  # noqa: F401  (before torch, as in the CLI: see the package docstring)

import argparse
import os
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stage2_steps import run_short  # noqa: E402  (a short Stage 2 run from a quality work folder)


def record_calls(work: Path, sequence: str, steps: int) -> list[dict]:
    """The first render_strands call of each kind in ``steps`` Stage 2 steps (inputs cloned)."""
    import vid2haircut.fit.scene as scene  # every Stage 2 render goes through scene.render_frames
    from vid2haircut.render import api

    calls: dict[tuple, dict] = {}

    def recording(points, K, E, width, height, strand_width=api.DEFAULT_STRAND_WIDTH, head_depth=None, **kw):
        key = (tuple(points.shape), float(strand_width), kw.get("silhouette_opacity"), kw.get("shading", True),
               points.requires_grad)
        if key not in calls:
            calls[key] = dict(points=points.detach().clone(), K=K.detach().clone(), E=E.detach().clone(),
                              width=width, height=height, strand_width=strand_width, kw=kw,
                              head_depth=None if head_depth is None else head_depth.detach().clone(),
                              grad=points.requires_grad)
        return api.render_strands(points, K, E, width, height, strand_width, head_depth, **kw)

    scene.render_strands = recording
    try:
        run_short(work, sequence, steps // 2, steps - steps // 2, {})
    finally:
        scene.render_strands = api.render_strands
    return list(calls.values())


def time_call(c: dict, repeat: int) -> float:
    """Best wall time (ms) of the call: forward+backward when differentiated, else forward."""
    from vid2haircut.render import render_strands

    pts = c["points"].clone().requires_grad_(c["grad"])

    def run():
        out = render_strands(pts, c["K"], c["E"], c["width"], c["height"], c["strand_width"], c["head_depth"],
                             **c["kw"])
        if c["grad"]:
            (out.silhouette.sum() + out.depth_normalized.sum() + out.direction.sum()).backward()
            pts.grad = None

    run()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - t0)
    return best * 1e3


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", required=True, help="a benchmarks/quality.py work folder (Stage 1 cached)")
    p.add_argument("--sequence", default="short_straight_1015")
    p.add_argument("--steps", type=int, default=8, help="Stage 2 steps to record from (half of them guides only)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeat", type=int, default=8)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    calls = record_calls(Path(args.work), args.sequence, args.steps)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, GOMP_SPINCOUNT="
          f"{os.environ.get('GOMP_SPINCOUNT', 'unset')}, vid2haircut from {Path(vid2haircut.__file__).parent}\n")
    print("| frames x strands x points | size | strand width (m) | translucent silhouette | timed | ms |")
    print("|---|---|---|---|---|---|")
    for c in calls:
        B, N, P = c["points"].shape[:3]
        what = "forward+backward" if c["grad"] else "forward"
        print(f"| {B} x {N} x {P} | {c['width']}x{c['height']} | {c['strand_width']:g} | "
              f"{c['kw'].get('silhouette_opacity')} | {what} | {time_call(c, args.repeat):.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
