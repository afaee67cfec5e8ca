"""The renderer of another commit against the present one, call by call in one process.

On a shared machine whose speed drifts by more than a change is worth, separate runs of
``render_bench.py`` (even alternating) cannot tell a 5% change from the drift. This script
extracts the ``vid2haircut`` package of ``--base`` (a commit, with ``git archive``) into a
temporary folder under another package name, imports both, checks that they give the same
renders and point gradients (byte for byte, or reports that they differ), and times the
forward+backward of ``render_bench.py``'s scene and loss (silhouette + normalised depth +
direction) for each in turn: per round, ``--repeat`` calls of each, alternating, best of each;
with ``--kernels`` also each numba kernel of the call (best of the round, as render_kernels.py
times them), for changes too small to see in the whole call.
Both sides compile their numba kernels once (the base's into the temporary folder's cache).

    .venv/bin/python benchmarks/render_ab.py --base d326216 [--strands 4000] [--size 256] [--frames 1]
                                             [--threads N] [--rounds 3] [--repeat 15] [--kernels]
                                             [--compositing auto|bins|exact]
"""

from __future__ import annotations

import vid2haircut  # noqa: F401  (before torch: its OpenMP spin setting applies only then, as in the CLI)

import argparse
import importlib
import io
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import torch

from vid2haircut.render.api import resolve_compositing

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_bench import add_scene_args, forward_backward, setup  # noqa: E402  (the benchmark scene, its loss)
from render_kernels import timed_kernels  # noqa: E402  (the kernels' wrappers)

REPO = Path(__file__).resolve().parents[1]
BASE_NAME = "v2h_base"


def extract_base(commit: str, dest: Path) -> str:
    """Write commit's ``src/vid2haircut`` to ``dest / BASE_NAME`` with every reference to the package
    renamed; returns the commit's short hash."""
    short = subprocess.run(["git", "rev-parse", "--short", commit], cwd=REPO, check=True, capture_output=True,
                           text=True).stdout.strip()
    tar = subprocess.run(["git", "archive", commit, "src/vid2haircut"], cwd=REPO, check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as tf:
        for member in tf.getmembers():
            if not member.isfile() or not member.name.endswith(".py"):
                continue
            rel = Path(member.name).relative_to("src/vid2haircut")
            out = dest / BASE_NAME / rel
            out.parent.mkdir(parents=True, exist_ok=True)
            text = tf.extractfile(member).read().decode()
            out.write_text(re.sub(r"\bvid2haircut\b", BASE_NAME, text))
    return short


def same(a, ga, b, gb) -> bool:
    """Every image channel, the visibility and the point gradients equal byte for byte."""
    names = ("silhouette", "direction", "depth", "depth_normalized", "mask", "visibility")
    return all(torch.equal(getattr(a, k), getattr(b, k)) for k in names) and torch.equal(ga, gb)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="the commit to compare with (any git revision)")
    add_scene_args(ap)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=15, help="calls of each per round (the best is printed)")
    ap.add_argument("--kernels", action="store_true", help="also print each numba kernel's best time per round")
    ap.add_argument("--compositing", default="auto", choices=["auto", "bins", "exact"],
                    help="the compositing model (auto: the renderer's default, exact with numba)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        short = extract_base(args.base, Path(tmp))
        sys.path.insert(0, tmp)
        base = importlib.import_module(f"{BASE_NAME}.render").render_strands
        present = importlib.import_module("vid2haircut.render").render_strands
        pts, K, E, hd = setup(args.strands, args.size, args.frames, "cpu")
        pts.requires_grad_(True)
        opt = dict(compositing=resolve_compositing(args.compositing, "numba"))  # (a base may predate "auto")
        call = {"base": lambda: forward_backward(pts, K, E, hd, args.size, "numba", base, **opt),
                "present": lambda: forward_backward(pts, K, E, hd, args.size, "numba", present, **opt)}
        (a, ga), (b, gb) = call["base"](), call["present"]()  # also compiles both
        print(f"{args.frames} x {args.strands} strands x 32 points at {args.size}x{args.size}, "
              f"{torch.get_num_threads()} threads; "
              f"base {short} against the present code: renders and gradients "
              f"{'identical' if same(a, ga, b, gb) else 'DIFFER'}")
        package = {"base": BASE_NAME, "present": "vid2haircut"}
        for r in range(args.rounds):
            best = dict.fromkeys(call, float("inf"))
            kbest: dict[str, dict[str, float]] = {name: {} for name in call}
            for _ in range(args.repeat):
                for name, fn in call.items():
                    times: dict[str, float] = {}
                    undo = timed_kernels(times, package[name]) if args.kernels else []
                    t0 = time.perf_counter()
                    fn()
                    best[name] = min(best[name], time.perf_counter() - t0)
                    for mod, fname, f in undo:
                        setattr(mod, fname, f)
                    for k, t in times.items():
                        kbest[name][k] = min(kbest[name].get(k, float("inf")), t)
            print(f"round {r + 1}: forward+backward base {best['base'] * 1e3:.1f} ms, "
                  f"present {best['present'] * 1e3:.1f} ms", flush=True)
            for k in kbest["present"]:
                print(f"    {k}: base {kbest['base'].get(k, float('nan')) * 1e3:.2f} ms, "
                      f"present {kbest['present'][k] * 1e3:.2f} ms", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
