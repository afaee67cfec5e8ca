"""Fitting stages on an accelerator: the same code runs on ``cuda`` and agrees with the CPU.

    PYTHONPATH=src python benchmarks/fit_device_check.py [--out result.json]

On the toy problem (:mod:`vid2haircut.fit.toy`) it runs Stage 1 and Stage 2 on the CPU and on
``cuda`` (when present) and reports the first-step loss terms (which must agree closely), the final
totals, the visibility-gate check (invisible points get exactly zero gradient) and the time per
Stage 2 step at the fitting size of the pipeline (160 px, 32x32 map, 6 keyframes).
"""

from __future__ import annotations

import argparse
import json
import math
import time

import torch

from vid2haircut.fit.config import Stage1Config, Stage2Config
from vid2haircut.fit.settings import apply_overrides
from vid2haircut.fit.scene import image_losses, render_frames
from vid2haircut.fit.stage1 import fit_stage1
from vid2haircut.fit.stage2 import Stage2Model, fit_stage2
from vid2haircut.fit.toy import toy_problem
from vid2haircut.fit.visibility import point_visibility


def run_small(device: str) -> dict:
    """Stage 1 + Stage 2 on a small toy problem -> losses and times."""
    tp = toy_problem(size=64, n_frames=3, map_res=16, k=16, device=device)
    c1 = apply_overrides(Stage1Config(), {"iterations": 20, "map_res": 16, "render": {"n_points": 16}})
    t0 = time.perf_counter()
    r1 = fit_stage1(tp.data, tp.codec, c1, progress=False)
    t1 = time.perf_counter() - t0
    c2 = apply_overrides(Stage2Config(), {"iterations": 20, "canonical_steps": 8, "ramp_steps": 4,
                                          "render": {"n_points": 16}})
    t0 = time.perf_counter()
    r2 = fit_stage2(tp.data, tp.codec, c2, r1.z, r1.mask, progress=False)
    t2 = time.perf_counter() - t0
    model = Stage2Model(tp.data, tp.codec, c2, r1.z, r1.mask)
    canon = model.canonical()[:, model.layout.render_index].detach().requires_grad_(True)
    frames = torch.tensor([1], device=device)
    moved, _, _ = model.deformed(canon, frames, 0.0)
    out = render_frames(moved, tp.data, frames, c2.render)
    model.gate.set_visibility(out.visibility)
    loss = image_losses(out, tp.data, frames)
    (loss["silhouette"] + loss["direction"]).backward()
    pv = point_visibility(out.visibility[0])
    return {"stage1_first": {k: v[0] for k, v in r1.history.terms.items()},
            "stage1_final_total": r1.history.total[-1], "stage2_first": {k: v[0] for k, v in r2.history.terms.items()},
            "stage2_final_total": r2.history.total[-1], "stage1_s": t1, "stage2_s": t2,
            "invisible_points": int((~pv).sum()),
            "invisible_grad_max": float(canon.grad.norm(dim=-1)[~pv].max()) if (~pv).any() else 0.0,
            "visible_grad_max": float(canon.grad.norm(dim=-1)[pv].max())}


def step_time(device: str, steps: int = 6) -> float:
    """Seconds per Stage 2 step (deformation on) at the pipeline's fitting size."""
    tp = toy_problem(size=160, n_frames=6, map_res=32, k=32, n_points=32, device=device)
    cfg = apply_overrides(Stage2Config(), {"iterations": steps + 2, "canonical_steps": 0, "ramp_steps": 1})
    model = Stage2Model(tp.data, tp.codec, cfg, torch.zeros_like(tp.z_gt).to(device), tp.mask.to(device))
    opts = model.make_optimizers()
    times = []
    for s in range(steps + 2):
        if device == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        for o in opts:
            o.zero_grad()
        sum(model.get_loss_dict(s).values()).backward()
        for o in opts:
            o.step()
        if device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return min(times[2:])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=None)
    args = p.parse_args()
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    res = {"devices": devices, "torch": torch.__version__}
    for d in devices:
        res[d] = run_small(d)
        res[d]["stage2_step_s_160px_6frames"] = step_time(d)
        print(d, json.dumps(res[d], indent=1), flush=True)
    if "cuda" in devices:
        a, b = res["cpu"]["stage2_first"], res["cuda"]["stage2_first"]
        # Terms that are off at the first step are recorded as NaN on both devices: compare the rest.
        on = [k for k in a if math.isfinite(a[k]) or math.isfinite(b[k])]
        res["max_rel_diff_first_step"] = max(abs(a[k] - b[k]) / max(abs(a[k]), 1e-9) for k in on)
        print("max relative difference of the first-step loss terms cpu vs cuda:", res["max_rel_diff_first_step"])
    if args.out:
        with open(args.out, "w") as f:
            json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
