"""Codec and hair map on an accelerator: same results as on the CPU, and timings of dense decoding.

    python benchmarks/prior_device_check.py [--out result.json]

Runs every step on the CPU and on ``cuda`` (when present) and prints the largest differences and
the forward + backward time of ``decode_dense`` (10k strands) at 32x32 and 64x64.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from vid2haircut.head import get_head
from vid2haircut.io.atomic import write_text
from vid2haircut.prior.corpus import build_corpus, fit_codec
from vid2haircut.prior.hairmap import HairMap, decode_dense, decode_guides, encode_strands


def timed(fn, device: torch.device, repeat: int = 3) -> tuple[float, object]:
    """Best wall time of ``fn()`` over ``repeat`` runs (synchronising CUDA), and its last result."""
    best, out = float("inf"), None
    for _ in range(repeat):
        if device.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        out = fn()
        if device.type == "cuda":
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - t0)
    return best, out


def dense_step(hm: HairMap, head, codec, n: int):
    z = hm.z.clone().requires_grad_(True)
    d = decode_dense(HairMap(z, hm.mask), head, codec, n_strands=n, seed=0)
    (d.points[:, 1:] ** 2).sum().backward()
    return d.points.detach(), z.grad


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--strands", type=int, default=3000)
    args = ap.parse_args()
    dev = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    head = get_head("proxy-v1")
    corpus = build_corpus(["wavy", "bob"], [0], args.strands, head=head)
    codec = fit_codec(corpus, k=64)
    style = corpus.strand_set(0)
    res_out: dict = {"device": str(dev), "torch": torch.__version__,
                     "gpu": torch.cuda.get_device_name(0) if dev.type == "cuda" else None}
    x = torch.as_tensor(corpus.points)
    c_cpu = codec.encode(x)
    c_dev = codec.to(dev).encode(x.to(dev))
    res_out["encode_max_diff"] = float((c_dev.cpu() - c_cpu).abs().max())
    y_cpu = codec.decode(c_cpu, x[:, 0])
    y_dev = codec.decode(c_dev, x[:, 0].to(dev))
    res_out["decode_max_diff_m"] = float((y_dev.cpu() - y_cpu).abs().max())
    for res in (32, 64):
        hm_cpu = encode_strands(style, head, codec, res=res)
        hm_dev = encode_strands(style, head, codec, res=res, device=dev)
        g_cpu = decode_guides(hm_cpu, head, codec).points
        g_dev = decode_guides(hm_dev, head, codec).points
        t_cpu, (p_cpu, gr_cpu) = timed(lambda: dense_step(hm_cpu, head, codec, 10000), torch.device("cpu"))
        t_dev, (p_dev, gr_dev) = timed(lambda: dense_step(hm_dev, head, codec, 10000), dev)
        res_out[f"res{res}"] = {
            "z_max_diff": float((hm_dev.z.cpu() - hm_cpu.z).abs().max()),
            "guides_max_diff_m": float((g_dev.cpu() - g_cpu).abs().max()),
            "dense_points_max_diff_m": float((p_dev.cpu() - p_cpu).abs().max()),
            "dense_grad_rel_diff": float((gr_dev.cpu() - gr_cpu).norm() / gr_cpu.norm()),
            "dense10k_fwd_bwd_s": {"cpu": t_cpu, str(dev): t_dev},
        }
    text = json.dumps(res_out, indent=2)
    print(text)
    if args.out is not None:
        write_text(args.out, text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
