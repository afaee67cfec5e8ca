"""Benchmark of the strand renderer: forward and forward+backward time per frame.

For 2k / 4k / 10k strands x 32 points at 256x256 and 512x512 it prints a Markdown table with the
forward and forward+backward milliseconds per frame, the number of (Gaussian, pixel)
contributions T the renderer evaluates, and the same machine's time for a plain ``scatter_add_``
of T values into an image of that size (the bandwidth ceiling; the indices are the renderer's own
pixel indices, so the memory access pattern is the same). On the CPU torch runs this 1-D
scatter-add on one thread whatever ``--threads`` says (the same time at 1 and 2 threads, measured):
the ceiling is a single-core figure.

Usage:
    python benchmarks/render_bench.py [--quick] [--breakdown] [--device cpu|cuda] [--threads N] [--frames B]
                                      [--backend auto|numba|torch] [--compositing auto|bins|exact] [--repeat N]
                                      [--rounds R]

On a machine whose speed drifts (shared VMs: the same call measured 59 ms, then 100+ ms, within
minutes), one series of ``--repeat`` runs can fall wholly in a slow moment, and a ratio of a quiet
renderer series to a slow scatter-add series (or the reverse) means nothing: ``--rounds R`` runs
the whole set of cases R times, one after the other, and prints for each case the best of every
column over the rounds (each column's quiet figure, the ratio from those) and the range of the
rounds' forward+backward and scatter-add bests, which shows how much the machine drifted.

The scene is a synthetic long-hair style on a 0.1 m scalp sphere seen from 0.6 m with a head
occluder (the sphere's depth), hair filling most of the frame, as in the fitting stages.
"""

from __future__ import annotations

import argparse
import math
import os
import time

import vid2haircut  # noqa: F401  (before torch: its OpenMP spin setting applies only then, as in the CLI)

import numpy as np
import torch

from vid2haircut.camera import intrinsics_from_fov, look_at
from vid2haircut.machine import machine_info, machine_summary
from vid2haircut.render import render_strands
from vid2haircut.render.api import DEFAULT_ALPHA_MIN, resolve_compositing
from vid2haircut.render.footprint import build_footprint
from vid2haircut.render.gaussians import segment_gaussians
from vid2haircut.render.numba_backend import resolve_backend


def hair_scene(n_strands: int, n_points: int = 32, seed: int = 0) -> np.ndarray:
    """[N, P, 3] strands: roots on the upper scalp, growing out then falling under gravity."""
    rng = np.random.default_rng(seed)
    radius = 0.1
    theta = np.arccos(rng.uniform(-0.2, 1.0, n_strands))  # polar angle from +y (up)
    phi = rng.uniform(0, 2 * np.pi, n_strands)
    normal = np.stack([np.sin(theta) * np.cos(phi), np.cos(theta), np.sin(theta) * np.sin(phi)], -1)
    roots = radius * normal
    length = rng.uniform(0.15, 0.25, n_strands)
    t = np.linspace(0, 1, n_points)[None, :, None]
    seg = length[:, None, None] * t
    out = normal[:, None] * np.minimum(seg, 0.03) * 1.0
    fall = np.array([0.0, -1.0, 0.0]) * np.maximum(seg - 0.02, 0.0)
    wave = 0.004 * np.sin(seg * 60 + phi[:, None, None]) * np.cross(normal, [0.0, 1.0, 0.0])[:, None]
    return (roots[:, None] + out * 1.2 + fall + wave).astype(np.float32)


def head_depth_sphere(K: np.ndarray, w2c: np.ndarray, width: int, height: int, radius: float = 0.1) -> np.ndarray:
    """[H, W] camera depth of a sphere at the world origin (+inf off the sphere)."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack([(xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1], np.ones_like(xs)], -1)
    c = w2c[:3, 3]  # sphere centre in camera coordinates (world origin)
    b = rays @ c
    rr = (rays * rays).sum(-1)
    disc = b * b - rr * (c @ c - radius * radius)
    t = (b - np.sqrt(np.maximum(disc, 0))) / rr
    return np.where(disc > 0, t, np.inf)  # z = t since the ray's z component is 1


def setup(n_strands: int, size: int, frames: int, device: str):
    pts = hair_scene(n_strands)
    K = intrinsics_from_fov(size, size, 36.0)
    E = look_at(np.array([0.0, -0.03, 0.6]), np.array([0.0, -0.04, 0.0]))
    hd = head_depth_sphere(K, E, size, size)
    f = lambda a: torch.tensor(np.repeat(a[None], frames, 0), dtype=torch.float32, device=device)  # noqa: E731
    return f(pts), f(K), f(E), f(hd)


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def best_ms(fn, device: str, repeat: int) -> float:
    """Smallest wall time of ``repeat`` runs (after one warm-up), milliseconds."""
    fn()
    _sync(device)
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        _sync(device)
        best = min(best, time.perf_counter() - t0)
    return best * 1e3


def forward_backward(pts, K, E, hd, size: int, backend: str = "auto", render=render_strands, **options):
    """One forward+backward of a scene from :func:`setup` (``pts`` requiring gradients), with the
    benchmark's loss: silhouette + normalised depth + direction, each summed. ``render``: the
    ``render_strands`` to call (render_ab.py passes another commit's); ``options``: its further
    keyword arguments (``compositing``). Returns (the render, d loss / d points); ``pts.grad`` is
    left None."""
    out = render(pts, K, E, size, size, head_depth=hd, backend=backend, **options)
    (out.silhouette.sum() + out.depth_normalized.sum() + out.direction.sum()).backward()
    grad, pts.grad = pts.grad, None
    return out, grad


def add_scene_args(ap: argparse.ArgumentParser) -> None:
    """The scene options of the single-scene renderer benchmarks (render_kernels.py, render_floor.py)."""
    ap.add_argument("--strands", type=int, default=4000)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (the kernels follow it)")
    ap.add_argument("--frames", type=int, default=1, help="frames per call (Stage 2 renders 6 keyframes in one)")


def scene_call(args: argparse.Namespace, **options):
    """Apply ``--threads`` and build the scene of ``args`` (:func:`add_scene_args`); returns a
    no-argument function doing one numba-backend :func:`forward_backward` of it (``options``:
    further ``render_strands`` arguments, ``compositing``)."""
    if args.threads:
        torch.set_num_threads(args.threads)
    pts, K, E, hd = setup(args.strands, args.size, args.frames, "cpu")
    pts.requires_grad_(True)
    return lambda: forward_backward(pts, K, E, hd, args.size, "numba", **options)


def bench_case(n_strands: int, size: int, device: str, repeat: int, frames: int = 1, backend: str = "auto",
               compositing: str = "auto") -> dict:
    pts, K, E, hd = setup(n_strands, size, frames, device)
    pts.requires_grad_(True)

    def fwd():
        with torch.no_grad():
            render_strands(pts, K, E, size, size, head_depth=hd, backend=backend, compositing=compositing)

    def fwd_bwd():
        forward_backward(pts, K, E, hd, size, backend, compositing=compositing)

    with torch.no_grad():
        g = segment_gaussians(pts, K, E)
        G = g.depths.numel()
        fp = build_footprint(g.means.reshape(G, 2), g.covs.reshape(G, 3), g.valid.reshape(G),
                             torch.arange(frames, device=device).repeat_interleave(g.depths.shape[1]),
                             size, size, math.log(DEFAULT_ALPHA_MIN))
    idx = (fp.colbase[None] + torch.arange(fp.rows, device=device)[:, None] * fp.vstride[None]).reshape(-1)
    vals = torch.rand(idx.shape[0], device=device)
    img = torch.zeros(frames * (size + 2 * fp.pad) ** 2, device=device)
    scatter = best_ms(lambda: img.zero_().scatter_add_(0, idx, vals), device, repeat)
    t_f = best_ms(fwd, device, repeat)
    t_fb = best_ms(fwd_bwd, device, repeat)
    return dict(strands=n_strands, size=size, segments=G // frames, T=idx.shape[0] // frames,
                fwd=t_f / frames, fwd_bwd=t_fb / frames, scatter=scatter / frames)


def table_row(n_strands: int, size: int, rounds: list[dict]) -> str:
    """One Markdown row of the benchmark table from the :func:`bench_case` results of one case in
    one or more rounds: each column's best over the rounds and the ratio of the two bests; with
    several rounds, the range of the rounds' forward+backward and scatter-add in brackets."""
    best = {k: min(r[k] for r in rounds) for k in ("fwd", "fwd_bwd", "scatter")}
    r0 = rounds[0]

    def spread(key: str) -> str:
        lo, hi = min(r[key] for r in rounds), max(r[key] for r in rounds)
        return f" ({lo:.1f}-{hi:.1f})" if len(rounds) > 1 else ""

    return (f"| {n_strands} | {size}x{size} | {r0['segments']} | {r0['T'] / 1e6:.2f} M | {best['fwd']:.1f} | "
            f"{best['fwd_bwd']:.1f}{spread('fwd_bwd')} | {best['scatter']:.1f}{spread('scatter')} | "
            f"{best['fwd_bwd'] / best['scatter']:.1f}x |")


def breakdown(n_strands: int, size: int, device: str, repeat: int, backend: str = "auto") -> None:
    """Print where the time of one forward+backward goes (ms per stage)."""
    pts, K, E, hd = setup(n_strands, size, 1, device)
    G = pts.shape[1] * (pts.shape[2] - 1)
    frame = torch.zeros(G, dtype=torch.int64, device=device)
    power_min = math.log(DEFAULT_ALPHA_MIN)
    if backend == "numba":  # each kernel timed inside render_strands, the backend's real path
        import render_kernels

        render_kernels.main(["--strands", str(n_strands), "--size", str(size), "--calls", str(max(repeat, 5))])
        setup_times = ""
    else:
        t_g = best_ms(lambda: segment_gaussians(pts, K, E), device, repeat)
        g = segment_gaussians(pts, K, E)
        args = (g.means.reshape(G, 2), g.covs.reshape(G, 3), g.valid.reshape(G), frame, size, size, power_min)
        t_fp = best_ms(lambda: build_footprint(*args), device, repeat)
        setup_times = f"gaussians {t_g:.1f}, footprint {t_fp:.1f}, "
    pts.requires_grad_(True)

    def fb(shading):
        out = render_strands(pts, K, E, size, size, head_depth=hd, shading=shading, backend=backend)
        (out.silhouette.sum() + out.depth.sum() + out.direction.sum()).backward()
        pts.grad = None

    with torch.no_grad():
        t_f = best_ms(lambda: render_strands(pts, K, E, size, size, head_depth=hd, backend=backend), device, repeat)
    t_fb = best_ms(lambda: fb(True), device, repeat)
    t_sil = best_ms(lambda: fb(False), device, repeat)
    print(f"\nbreakdown {n_strands} strands at {size}x{size} (ms): {setup_times}"
          f"forward {t_f:.1f}, forward+backward {t_fb:.1f}, silhouette-only forward+backward {t_sil:.1f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="4k strands at 256x256 only, 3 repeats")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (CPU)")
    ap.add_argument("--frames", type=int, default=1, help="frames per call (times are per frame)")
    ap.add_argument("--backend", default="auto", choices=["auto", "numba", "torch"],
                    help="compositing kernels (auto: numba on CPU when installed, else torch)")
    ap.add_argument("--compositing", default="auto", choices=["auto", "bins", "exact"],
                    help="the renderer's compositing model (auto, the default: exact with the numba backend, else "
                         "bins; exact: front to back with early termination, numba)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per case (the best is printed)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="run every case this many times in turn and print each column's best (drifting machines)")
    ap.add_argument("--breakdown", action="store_true",
                    help="also print the time per stage (4k strands, 256x256; numba: per kernel, render_kernels.py)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    cases = [(4000, 256)] if args.quick else [(n, s) for s in (256, 512) for n in (2000, 4000, 10000)]
    repeat = args.repeat
    backend = resolve_backend(args.backend, torch.zeros(1, device=args.device))
    print(f"device: {args.device}; {machine_summary(machine_info(args.device))}; "
          f"backend: {backend}; compositing: {resolve_compositing(args.compositing, backend)}; frames per call: {args.frames}; GOMP_SPINCOUNT={os.environ.get('GOMP_SPINCOUNT', 'unset')}; "
          f"load average: {', '.join(f'{x:.2f}' for x in os.getloadavg())}\n")
    header = ("| strands x 32 pts | image | segments | contributions T | forward ms | fwd+bwd ms | scatter_add_ T ms "
              "| fwd+bwd / scatter |\n|---|---|---|---|---|---|---|---|")
    if args.rounds > 1:
        runs = [[bench_case(n, s, args.device, repeat, args.frames, backend, args.compositing) for n, s in cases]
                for _ in range(args.rounds)]
        print(f"best of {args.rounds} rounds of {repeat} runs per column; the rounds' ranges in brackets\n")
        print(header)
        for i, (n, s) in enumerate(cases):
            print(table_row(n, s, [run[i] for run in runs]))
    else:  # each row as soon as its case is done
        print(header)
        for n, s in cases:
            print(table_row(n, s, [bench_case(n, s, args.device, repeat, args.frames, backend, args.compositing)]),
                  flush=True)
    if args.breakdown:
        breakdown(4000, 256, args.device, repeat, backend)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
