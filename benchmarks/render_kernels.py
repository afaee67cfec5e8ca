"""Where the time of one numba-backend render goes: each kernel timed inside ``render_strands``.

Wraps the numba kernels the backend calls (projection, windows, tile binning, compositing,
visibility and gradient sums, image channels), runs forward+backward of the benchmark scene of
``render_bench.py`` (silhouette + normalised depth + direction) ``--calls`` times and prints, per
kernel, the best and the median milliseconds, and what is left of the whole call (torch's image
channels and loss, Python).

    .venv/bin/python benchmarks/render_kernels.py [--strands 4000] [--size 256] [--frames 1] [--calls 20] [--threads N]
        [--compositing auto|bins|exact]
"""

from __future__ import annotations

import vid2haircut  # noqa: F401  (before torch: its OpenMP spin setting applies only then, as in the CLI)

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_bench import add_scene_args, scene_call  # noqa: E402  (the benchmark scene and its loss)

KERNELS = {
    "numba_project": ("project_forward", "project_backward"),
    "numba_windows": ("gaussian_windows",),
    "numba_tiles": ("gaussian_windows", "tile_head_max", "bin_windows", "assign_tiles"),  # (windows: before the split)
    "numba_walk": ("tile_bounds",),
    "numba_kernels": ("composite_forward", "composite_backward", "reduce_gradients"),
    "numba_channels": ("channels_forward", "channels_backward", "normalize_forward", "normalize_backward"),
    "numba_records": ("depth_order", "gather_gaussians", "gather_windows"),
    "numba_exact": ("depth_order", "gather_gaussians", "gather_windows", "composite_exact_forward",
                    "composite_exact_backward"),  # (its first three: before numba_records)
}

OTHER_PATH = ("gather_gaussians",)
"""Kernels the benchmark's scene does not call: the gather of Gaussians whose windows torch
computed (the projection by torch, when a camera needs gradients); the numba projection's windows
are computed in the gather (``gather_windows``)."""


def timed_kernels(times: dict[str, float], package: str = "vid2haircut") -> list:
    """Replace the kernels of ``package`` (render_ab.py passes another commit's copy) by wrappers
    adding their wall time to ``times``; returns the undo list."""
    import importlib

    undo = []
    for mod_name, names in KERNELS.items():
        try:
            mod = importlib.import_module(f"{package}.render.{mod_name}")
        except ModuleNotFoundError:  # a module the other commit does not have
            continue
        for name in names:
            fn = getattr(mod, name, None)
            if fn is None:  # a kernel the other commit does not have
                continue

            def wrapper(*a, _fn=fn, _name=name, **k):
                t0 = time.perf_counter()
                out = _fn(*a, **k)
                times[_name] = times.get(_name, 0.0) + time.perf_counter() - t0
                return out

            setattr(mod, name, wrapper)
            undo.append((mod, name, fn))
    return undo


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_args(ap)
    ap.add_argument("--calls", type=int, default=20, help="timed forward+backward calls (after 3 warm-ups)")
    ap.add_argument("--compositing", default="auto", choices=["auto", "bins", "exact"],
                    help="the compositing model (auto: the renderer's default, exact with numba)")
    args = ap.parse_args(argv)
    call = scene_call(args, compositing=args.compositing)
    times: dict[str, float] = {}
    undo = timed_kernels(times)
    try:
        for _ in range(3):
            call()
        per_kernel: dict[str, list[float]] = {}
        totals = []
        for _ in range(args.calls):
            times.clear()
            t0 = time.perf_counter()
            call()
            totals.append(time.perf_counter() - t0)
            for name, t in times.items():
                per_kernel.setdefault(name, []).append(t)
    finally:
        for mod, name, fn in undo:
            setattr(mod, name, fn)
    ms = lambda v: 1e3 * float(v)  # noqa: E731
    print(f"{args.frames} x {args.strands} strands x 32 points at {args.size}x{args.size}, {torch.get_num_threads()} threads, "
          f"{args.calls} calls: whole call best {ms(min(totals)):.1f} ms, median {ms(np.median(totals)):.1f} ms\n")
    print("| kernel | best ms | median ms |")
    print("|---|---|---|")
    med_sum = 0.0
    for name, v in per_kernel.items():
        med_sum += float(np.median(v))
        print(f"| {name} | {ms(min(v)):.2f} | {ms(np.median(v)):.2f} |")
    print(f"| rest (torch, Python) | | {ms(np.median(totals) - med_sum):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
