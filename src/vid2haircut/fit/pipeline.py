"""File-level entry points of the fitting stages (what the ``stage1`` / ``stage2`` commands call).

:func:`run_stage1` and :func:`run_stage2` read the front-stage files, fit, and write the artifacts
listed in :mod:`vid2haircut.fit.outputs` into ``out_dir``. Stage 2 writes a checkpoint every
``checkpoint_every`` steps and resumes from it when run again with the same inputs and settings.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import time
from pathlib import Path

import numpy as np
import torch

from vid2haircut.fit.config import Stage1Config, Stage2Config
from vid2haircut.fit.settings import apply_overrides, config_to_dict
from vid2haircut.fit.data import FitData, load_fit_data
from vid2haircut.fit.scene import drawn_compositing
from vid2haircut.fit.outputs import (dense_strands, load_hairmap, load_torch, save_torch, stage_strands,
                                     write_hairmap, write_loss_curve, write_record, write_renders, write_strands)
from vid2haircut.fit.stage1 import FitResult, fit_stage1, initial_hairmap, prior_view_input
from vid2haircut.fit.stage2 import checkpoint_state, fit_stage2
from vid2haircut.io.atomic import check_outputs
from vid2haircut.io.strand_formats import save_strands
from vid2haircut.machine import machine_info
from vid2haircut.prior.codec import StrandCodec

__all__ = ["run_stage1", "run_stage2", "stage1_config", "stage2_config"]

log = logging.getLogger(__name__)

DECODING_ONLY = ("n_dense", "length_spread", "tip_scatter", "carve_tolerance", "carve_min_fraction")
"""Stage settings that change how the output is decoded from the fitted hair map, not the fit."""


def stage1_config(settings: dict | None = None, device: str | None = None, seed: int | None = None) -> Stage1Config:
    """Default Stage 1 config with ``settings`` overrides, then ``device`` / ``seed`` when given."""
    cfg = apply_overrides(Stage1Config(), settings)
    if device:
        cfg.device = device
    if seed is not None:
        cfg.seed = int(seed)
    return cfg


def stage2_config(settings: dict | None = None, device: str | None = None, seed: int | None = None) -> Stage2Config:
    """Default Stage 2 config with ``settings`` overrides, then ``device`` / ``seed`` when given."""
    cfg = apply_overrides(Stage2Config(), settings)
    if device:
        cfg.device = device
    if seed is not None:
        cfg.seed = int(seed)
    return cfg


def _write_common(out_dir: Path, res: FitResult, data: FitData, codec: StrandCodec,
                  cfg: Stage1Config | Stage2Config, title: str) -> float:
    """Write the artifacts both stages share; returns the fraction of dense strands carving cut."""
    dense, cut = stage_strands(res.z, res.mask, data, codec, cfg)
    write_strands(out_dir, res.guides, res.texel_index, dense, data.head_model)
    write_hairmap(out_dir / "hairmap.npz", res.z, res.mask, codec.fingerprint(), data.head_model)
    codec.save(out_dir / "codec.npz")
    write_renders(out_dir, res.render, data, res.frames)
    write_loss_curve(out_dir / "loss_curve.png", res.history, cfg.weights, title)
    return cut


COMMON_OUTPUTS = ("strands.npz", "guides.npz", "hairmap.npz", "codec.npz", "loss_curve.png")


def _check_outputs(out_dir: Path, data: FitData, names) -> None:
    """Refuse, before the fit, output paths that cannot be written (a folder in place of a file, a
    file in place of the folder): a failure after the fit would leave the first files replaced."""
    renders = [Path("renders") / f"frame_{int(t):05d}.png" for t in data.frames]
    check_outputs([out_dir / n for n in (*COMMON_OUTPUTS, *names, *renders)])


def _final_terms(res: FitResult) -> dict:
    return {k: v[-1] for k, v in res.history.terms.items()}


def run_stage1(dataset_root: str | Path, subject: str, keyframes_json: str | Path, head_npz: str | Path,
               targets_dir: str | Path, out_dir: str | Path, prior_dir: str | Path | None = None,
               codec_path: str | Path | None = None, settings: dict | None = None, device: str | None = None,
               seed: int | None = None, progress: bool = True) -> dict:
    """Stage 1 from files: fit the reference keyframe and write the artifacts into ``out_dir``.

    Args:
        dataset_root, subject: location of the calibration.
        keyframes_json, head_npz, targets_dir: front-stage outputs of the sequence.
        out_dir: output folder.
        prior_dir: trained prior (codec.npz, prior.pt, prior.json); its weights are fine-tuned.
        codec_path: strand codec to optimise Z directly when no prior is given.
        settings: :class:`Stage1Config` overrides; device, seed: override the config's.
        progress: tqdm bar.

    Returns:
        The record written to ``stage1.json``.
    """
    t0 = time.perf_counter()
    cfg = stage1_config(settings, device, seed)
    out = Path(out_dir)
    if prior_dir is None and codec_path is None:
        raise ValueError("stage1 needs a prior folder (--prior-dir) or a strand codec (--codec)")
    data = load_fit_data(dataset_root, subject, keyframes_json, head_npz, targets_dir, size=cfg.render.size,
                         n_keyframes=1, occlude_head=cfg.render.occlude_head, device=cfg.device)
    _check_outputs(out, data, ("stage1.json", "prior_hairmap.npz", "prior_strands.npz"))
    prior = None
    if prior_dir is not None:
        from vid2haircut.prior.model import load_prior

        net, codec, _ = load_prior(prior_dir, device=cfg.device)
        prior = (net, prior_view_input(data, net.cfg.input_size, cfg.device))
        z0, m0 = initial_hairmap(data, codec, prior)
        write_hairmap(out / "prior_hairmap.npz", z0, m0, codec.fingerprint(), data.head_model)
        # The prior's prediction alone (the "prior" row of the evaluation table).
        save_strands(out / "prior_strands.npz",
                     dense_strands(z0, m0, data.head, codec.to("cpu"), cfg.n_dense, cfg.seed, data.head_model,
                                   length_spread=cfg.length_spread, tip_scatter=cfg.tip_scatter))
    else:
        codec = StrandCodec.load(codec_path)
    res = fit_stage1(data, codec, cfg, prior, progress=progress)
    codec = codec.to("cpu")
    cut = _write_common(out, res, data, codec, cfg, "stage 1")
    record = {"stage": "stage1", "config": config_to_dict(cfg), "reference": data.frames[0], "carved_fraction": cut,
              "fit_size": [data.width, data.height], "compositing": drawn_compositing(cfg.render, data),
              "n_guides": int(res.texel_index.numel()),
              "prior": str(prior_dir) if prior_dir is not None else None,
              "codec_fingerprint": codec.fingerprint(), "fit_seconds": res.seconds,
              "total_seconds": time.perf_counter() - t0, "machine": machine_info(cfg.device),
              "final_terms": _final_terms(res), "history": res.history.to_dict()}
    write_record(out / "stage1.json", record)
    return record


def _signature(cfg: Stage2Config, data: FitData, z: torch.Tensor, mask: torch.Tensor) -> str:
    """Hash of everything that defines a Stage 2 fit (for resuming only a matching checkpoint). The
    settings that only decode the output (:data:`DECODING_ONLY`) are left out, so changing them
    resumes a finished fit and decodes it again."""
    d = config_to_dict(cfg)
    for key in ("checkpoint_every", "device", *DECODING_ONLY):
        d.pop(key, None)
    d["render"]["compositing"] = drawn_compositing(cfg.render, data)  # ("auto": the model it names here)
    if d["render"]["compositing"] == "bins":  # the signature of the fits made before the choice
        del d["render"]["compositing"], d["render"]["t_min"]
        d.pop("gate_bins_every", None)  # (the exact model's alone)
    h = hashlib.sha256(json.dumps({"cfg": d, "frames": data.frames}, sort_keys=True).encode())
    for t in (z, mask, data.mask, data.cam_from_head):
        h.update(np.ascontiguousarray(t.detach().cpu().numpy(), np.float32).tobytes())
    return h.hexdigest()[:16]


def run_stage2(dataset_root: str | Path, subject: str, keyframes_json: str | Path, head_npz: str | Path,
               targets_dir: str | Path, stage1_dir: str | Path, out_dir: str | Path, settings: dict | None = None,
               device: str | None = None, seed: int | None = None, resume: bool = True,
               progress: bool = True) -> dict:
    """Stage 2 from files: refine Stage 1's hair map over the keyframes and write the artifacts.

    Args:
        dataset_root, subject, keyframes_json, head_npz, targets_dir: as :func:`run_stage1`.
        stage1_dir: Stage 1 output folder (hairmap.npz, codec.npz).
        out_dir: output folder (``strands.npz`` is the dense canonical hairstyle).
        settings: :class:`Stage2Config` overrides; device, seed: override the config's.
        resume: continue from ``out_dir/checkpoint.pt`` when it matches these inputs and settings.
        progress: tqdm bar.

    Returns:
        The record written to ``stage2.json``.
    """
    t0 = time.perf_counter()
    cfg = stage2_config(settings, device, seed)
    out, s1 = Path(out_dir), Path(stage1_dir)
    z, mask, fp = load_hairmap(s1 / "hairmap.npz")
    codec = StrandCodec.load(s1 / "codec.npz")
    if fp and fp != codec.fingerprint():
        raise ValueError(f"{s1 / 'hairmap.npz'}: made with codec {fp}, but {s1 / 'codec.npz'} is {codec.fingerprint()}")
    if z.shape[0] != codec.k:
        raise ValueError(f"{s1 / 'hairmap.npz'}: K={z.shape[0]} does not match the codec's K={codec.k}")
    data = load_fit_data(dataset_root, subject, keyframes_json, head_npz, targets_dir, size=cfg.render.size,
                         n_keyframes=cfg.n_keyframes, occlude_head=cfg.render.occlude_head, device=cfg.device)
    _check_outputs(out, data, ("stage2.json", "checkpoint.pt", "deform.pt"))
    sig = _signature(cfg, data, z, mask)
    ckpt_path = out / "checkpoint.pt"
    state = None
    if resume and ckpt_path.is_file():
        try:
            state = load_torch(ckpt_path)
        except ValueError as e:  # a checkpoint is only a cache of the fit: start afresh, it is rewritten
            log.warning("%s; starting afresh", e)
        if not isinstance(state, dict):
            if state is not None:
                log.warning("%s: not a Stage 2 checkpoint (a %s); starting afresh", ckpt_path, type(state).__name__)
            state = None
        elif state.get("signature") != sig:
            log.info("%s: made with other inputs or settings; starting afresh", ckpt_path)
            state = None

    def on_step(step, model, trainer):
        last = step == cfg.iterations - 1
        if last or (cfg.checkpoint_every > 0 and (step + 1) % cfg.checkpoint_every == 0):
            save_torch(ckpt_path, {**checkpoint_state(step, model, trainer), "signature": sig})

    res = fit_stage2(data, codec, cfg, z, mask, progress=progress, resume=state, on_step=on_step)
    codec = codec.to("cpu")
    cut = _write_common(out, res, data, codec, cfg, "stage 2")
    deform = res.extra["deform"]
    if deform is not None:
        save_torch(out / "deform.pt", {"state_dict": {k: v.cpu() for k, v in deform.state_dict().items()},
                                       "config": dataclasses.asdict(deform.cfg), "frames": list(data.frames),
                                       "texel_index": res.texel_index.cpu()})
    record = {"stage": "stage2", "config": config_to_dict(cfg), "keyframes": data.frames, "carved_fraction": cut,
              "fit_size": [data.width, data.height], "compositing": drawn_compositing(cfg.render, data),
              "n_guides": int(res.texel_index.numel()),
              "codec_fingerprint": codec.fingerprint(), "signature": sig,
              "resumed_from_step": None if state is None else int(state["step"]),
              "fit_seconds": res.seconds, "total_seconds": time.perf_counter() - t0,
              "machine": machine_info(cfg.device), "observed_texels": int(res.extra["observed"].sum()),
              "final_terms": _final_terms(res), "history": res.history.to_dict()}
    write_record(out / "stage2.json", record)
    return record
