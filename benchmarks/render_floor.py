"""What is left of a numba-backend render when the compositing itself costs nothing: the floor.

Times forward+backward of ``render_bench.py``'s scene (silhouette + normalised depth + direction,
best of ``--repeat``) three ways, alternating, in one process:

- ``full``: the renderer with the binned compositing model (``compositing="bins"``, whose two
  kernels the other variants replace; the exact model, the numba backend's default, walks the
  same windows in depth order);
- ``walk``: the two compositing kernels replaced by the window walk alone (every (Gaussian,
  pixel) contribution listed with its power, without z_ref) and alpha and log(1 - alpha) of each,
  the least any compositing model over these windows must do, and a backward pass that returns
  zero gradients of the Gaussians;
- ``none``: both compositing kernels replaced by no-ops (projection, windows, tile binning,
  gradient sums, the projection's backward, torch's image channels and loss, Python: what any
  compositing model pays besides its own work).

The images of the stubbed runs are wrong (zeros); only their times mean anything. Against the
``scatter_add_`` ceiling of the same scene (``render_bench.py``), this says how much time a
compositing model may take at most to stay within a given multiple of the ceiling.

    .venv/bin/python benchmarks/render_floor.py [--strands 4000] [--size 256] [--frames 1] [--repeat 15] [--rounds 3]
"""

from __future__ import annotations

import vid2haircut  # noqa: F401  (before torch: its OpenMP spin setting applies only then, as in the CLI)

import argparse
import sys
from pathlib import Path

import torch
from numba import njit, prange

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_bench import add_scene_args, best_ms, scene_call  # noqa: E402  (the scene, its loss, the timer)

from vid2haircut.render import numba_kernels  # noqa: E402
from vid2haircut.render.numba_kernels import walk_scratch, walk_tile  # noqa: E402


@njit(cache=True, parallel=True, error_model="numpy")
def walk_only(gpar, zs, wint, wflt, head, has_head, consts, nbins, tile_start, sorted_g, boxes, work_start, work_tiles,
              width, height, tile, offsets, elems, e_range, out, vis_weight, visible, compress):
    """``numba_kernels.composite_forward``'s signature; only its step 1 (``walk_tile``, without z_ref)."""
    for wk in prange(work_start.shape[0] - 1):
        scratch = walk_scratch(tile, zs)
        for j in range(work_start[wk], work_start[wk + 1]):
            walk_tile(work_tiles[j], scratch, gpar, zs, wint, wflt, head, has_head, consts, False, tile_start,
                      sorted_g, boxes, width, height, tile, offsets, elems, e_range, compress)


def _no_forward(*args) -> None:
    args[18][:] = 0  # e_range: no elements (the backward stub reads nothing)


def _no_backward(*args) -> None:
    args[-1].fill(0.0)  # the per-instance gradient sums


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_args(ap)
    ap.add_argument("--repeat", type=int, default=15, help="timed runs per variant and round (the best counts)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of the three variants, alternating")
    args = ap.parse_args(argv)
    call = scene_call(args, compositing="bins")
    real = numba_kernels.composite_forward, numba_kernels.composite_backward
    variants = {"full": real, "walk": (walk_only, _no_backward), "none": (_no_forward, _no_backward)}
    print(f"{args.frames} x {args.strands} strands x 32 points at {args.size}x{args.size}, {torch.get_num_threads()} threads; "
          f"forward+backward ms, best of {args.repeat}\n")
    print("| round | " + " | ".join(variants) + " |")
    print("|---|" + "---|" * len(variants))
    try:
        for r in range(args.rounds):
            row = []
            for fwd, bwd in variants.values():
                numba_kernels.composite_forward, numba_kernels.composite_backward = fwd, bwd
                row.append(best_ms(call, "cpu", args.repeat))
            print(f"| {r + 1} | " + " | ".join(f"{t:.1f}" for t in row) + " |", flush=True)
    finally:
        numba_kernels.composite_forward, numba_kernels.composite_backward = real
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
