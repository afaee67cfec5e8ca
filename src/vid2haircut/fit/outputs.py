"""Artifacts of the fitting stages, all written atomically.

Per stage output folder::

    strands.npz        dense canonical hairstyle (StrandSet, metres, head canonical frame, root first,
                       head_model set; attribute "uv" of the roots); points pushed out of the head
    guides.npz         guide strands (one per hair-bearing texel; attribute "texel_index")
    hairmap.npz        z (K,R,R) float32, mask (R,R) float32, codec_fingerprint, head_model
    codec.npz          the strand codec (so that the next stage needs only this folder)
    renders/frame_<t:05d>.png   target | render panels per keyframe (silhouette, direction, depth)
    loss_curve.png     weighted loss terms per step (log scale)
    <stage>.json       settings, keyframes, timings, final loss terms, history
    deform.pt          Stage 2: deformation MLP + frame codes (state_dict, config, keyframes)
    checkpoint.pt      Stage 2: resumable state (removed nothing; overwritten every few steps)
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vid2haircut.fit.carve import carve_strands
from vid2haircut.fit.components import LossWeights
from vid2haircut.fit.trainer import History
from vid2haircut.io.atomic import atomic_path, write_image, write_json, write_npz
from vid2haircut.checks import float_array
from vid2haircut.io.strand_formats import save_strands
from vid2haircut.strands import StrandSet

__all__ = ["write_hairmap", "load_hairmap", "write_strands", "dense_strands", "stage_strands", "push_out_of_head",
           "extend_map", "render_panel", "write_renders", "write_loss_curve", "save_torch", "load_torch"]


def write_hairmap(path: str | Path, z: torch.Tensor, mask: torch.Tensor, codec_fingerprint: str,
                  head_model: str) -> None:
    """Write ``hairmap.npz`` (z (K,R,R), mask (R,R), codec fingerprint, head model)."""
    write_npz(path, z=z.detach().cpu().numpy().astype(np.float32), mask=mask.detach().cpu().numpy().astype(np.float32),
              codec_fingerprint=np.array(codec_fingerprint), head_model=np.array(head_model))


def load_hairmap(path: str | Path) -> tuple[torch.Tensor, torch.Tensor, str]:
    """Read ``hairmap.npz`` -> (z (K,R,R), mask (R,R), codec fingerprint); errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: hair map file not found")
    try:
        with np.load(path, allow_pickle=False) as d:
            z, mask, fp = d["z"], d["mask"], str(d["codec_fingerprint"]) if "codec_fingerprint" in d else ""
    except Exception as e:  # noqa: BLE001 - a missing key, a truncated zip (BadZipFile), pickled objects ...
        raise ValueError(f"{path}: not a hair map .npz ({type(e).__name__}: {e})") from None
    if z.ndim != 3 or mask.shape != z.shape[1:]:
        raise ValueError(f"{path}: z must be (K,R,R) and mask (R,R), got {z.shape} and {mask.shape}")
    z = float_array(z, path, "z", dtype=np.float32)
    mask = float_array(mask, path, "mask", dtype=np.float32)
    return torch.as_tensor(z), torch.as_tensor(mask), fp


def push_out_of_head(points: torch.Tensor, head: Any, margin: float = 1e-3, iters: int = 4) -> torch.Tensor:
    """Move strand points (not the roots) that lie inside the head, or closer than ``margin`` to it,
    along the SDF gradient to ``margin`` outside. points: (M,P,3) -> (M,P,3) (detached).

    Dense strands decoded at roots between the guides' texel centres (root-relative offsets in the
    canonical frame, no per-root frame) can dip into a curved scalp; this resolves it.
    """
    p = points.detach().clone()
    if p.numel() == 0 or margin is None:
        return p
    for _ in range(int(iters)):
        q = p[:, 1:].clone().requires_grad_(True)
        with torch.enable_grad():
            d = head.sdf(q)
            (g,) = torch.autograd.grad(d.sum(), q)
        g = g / g.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        p[:, 1:] = q.detach() + torch.relu(margin - d.detach())[..., None] * g
    return p


def extend_map(z: torch.Tensor, hair: torch.Tensor) -> torch.Tensor:
    """Fill the coefficients of texels without a guide from their guide neighbours, ring by ring.

    Dense strands near the hairline interpolate between a guide and its neighbours; a neighbour
    without a guide (bald or off the scalp) holds arbitrary coefficients (e.g. the codec's mean
    strand, hanging in front of the face). Each ring of texels next to the filled region gets the
    mean of its filled 8-neighbours until every texel is filled.

    Args:
        z: (K,R,R) map; hair: (R,R) bool texels that carry a guide.

    Returns:
        (K,R,R) map equal to ``z`` on ``hair``.
    """
    import torch.nn.functional as F

    out = z.detach().clone()
    filled = hair.detach().clone().bool()
    if not bool(filled.any()):
        return out
    kernel = torch.ones(1, 1, 3, 3, dtype=out.dtype, device=out.device)
    while not bool(filled.all()):
        f = filled.to(out.dtype)
        num = F.conv2d((out * f)[:, None], kernel, padding=1)[:, 0]
        den = F.conv2d(f[None, None], kernel, padding=1)[0, 0]
        ring = ~filled & (den > 0)
        out[:, ring] = num[:, ring] / den[ring]
        filled = filled | ring
    return out


def decode_dense_map(z: torch.Tensor, mask: torch.Tensor, head: Any, codec: Any, n_strands: int, seed: int,
                     threshold: float = 0.5):
    """The HAAR-upsampled dense strands of a map (:func:`vid2haircut.prior.hairmap.decode_dense`)
    after extending it beyond its guides (:func:`extend_map`; guides are the valid scalp texels
    with ``mask >= threshold``). Differentiable in ``z`` through the guides' texels (the extended
    ones take their neighbours' values without a gradient).

    Returns:
        :class:`vid2haircut.prior.hairmap.DenseStrands`.
    """
    from vid2haircut.prior.hairmap import HairMap, decode_dense
    from vid2haircut.prior.scalp import scalp_grid

    valid = torch.as_tensor(scalp_grid(head, int(z.shape[-1])).valid, device=z.device)
    hair = valid & (mask.detach() >= threshold)
    z_ext = torch.where(hair[None], z, extend_map(z, hair))
    return decode_dense(HairMap(z_ext, mask.detach()), head, codec, n_strands=n_strands, seed=seed)


def dense_strands(z: torch.Tensor, mask: torch.Tensor, head: Any, codec: Any, n_strands: int, seed: int,
                  head_model: str, collision_margin: float | None = 1e-3, threshold: float = 0.5,
                  length_spread: float = 0.0, tip_scatter: float = 0.0) -> StrandSet:
    """Dense canonical strands of a map: the map is extended beyond its guides (:func:`extend_map`),
    upsampled by the HAAR scheme (:func:`vid2haircut.prior.hairmap.decode_dense`), pushed out
    of the head (:func:`push_out_of_head`, skipped when ``collision_margin`` is None) and, when
    ``length_spread`` > 0, given uneven ends (:func:`vid2haircut.polylines.vary_lengths` with that
    relative spread and ``seed``), and when ``tip_scatter`` > 0 fanned out around their paths
    (:func:`vid2haircut.polylines.scatter_strands`, tips moved by that per-axis spread in metres);
    either way pushed out again, as a moved strand may reach the head."""
    with torch.no_grad():
        d = decode_dense_map(z, mask, head, codec, n_strands, seed, threshold)
    pts = d.points if collision_margin is None else push_out_of_head(d.points, head, collision_margin)
    if length_spread > 0 or tip_scatter > 0:
        from vid2haircut.polylines import scatter_strands, vary_lengths

        moved = scatter_strands(vary_lengths(pts.cpu().numpy(), length_spread, seed), tip_scatter, seed)
        pts = torch.as_tensor(moved, device=pts.device)
        pts = pts if collision_margin is None else push_out_of_head(pts, head, collision_margin)
    return StrandSet(pts.cpu().numpy(), {"uv": d.uv.cpu().numpy()}, head_model=head_model)


def stage_strands(z: torch.Tensor, mask: torch.Tensor, data: Any, codec: Any, cfg: Any) -> tuple[StrandSet, float]:
    """A stage's dense output: :func:`dense_strands` with the stage's decoding settings (``n_dense``,
    ``seed``, ``length_spread``, ``tip_scatter``), then, when ``carve_tolerance`` > 0, carved to the
    silhouettes of the stage's keyframes ``data`` (:func:`vid2haircut.fit.carve.carve_strands`).

    Returns:
        (dense strands, fraction of them that carving cut).
    """
    dense = dense_strands(z, mask, data.head, codec, cfg.n_dense, cfg.seed, data.head_model,
                          length_spread=cfg.length_spread, tip_scatter=cfg.tip_scatter)
    if cfg.carve_tolerance <= 0:
        return dense, 0.0
    carved = carve_strands(dense.points, data, cfg.carve_tolerance, cfg.carve_min_fraction)
    return StrandSet(carved.points, dict(dense.attributes), head_model=dense.head_model), carved.cut_fraction


def write_strands(out_dir: str | Path, guides: torch.Tensor, texel_index: torch.Tensor, dense: StrandSet,
                  head_model: str) -> None:
    """Write ``strands.npz`` (dense) and ``guides.npz`` into ``out_dir``."""
    out = Path(out_dir)
    save_strands(out / "guides.npz", StrandSet(guides.detach().cpu().numpy(),
                                               {"texel_index": texel_index.cpu().numpy()}, head_model=head_model))
    save_strands(out / "strands.npz", dense)


def _angle_rgb(angle: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(H,W) angle in [0,pi) and weight in [0,1] -> (H,W,3) uint8 colour wheel image."""
    import cv2

    hsv = np.stack([(angle / math.pi * 179.0).astype(np.uint8), np.full(angle.shape, 255, np.uint8),
                    (np.clip(weight, 0, 1) * 255).astype(np.uint8)], -1)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)


def render_panel(target: dict[str, np.ndarray], render: dict[str, np.ndarray], scale: int = 2) -> np.ndarray:
    """A 2 x 3 panel: target (top) and render (bottom) silhouette, direction, depth.

    Args:
        target: ``mask`` (H,W), ``angle`` (H,W), ``confidence`` (H,W), ``depth`` (H,W), ``depth_valid`` (H,W).
        render: ``silhouette``, ``angle``, ``depth`` (relative, [0,1] inside ``mask``), ``mask`` (H,W).
        scale: nearest-neighbour enlargement.

    Returns:
        (2H*scale, 3W*scale, 3) uint8 RGB.
    """
    def grey(a):
        return np.repeat((np.clip(a, 0, 1) * 255).astype(np.uint8)[..., None], 3, -1)

    def depth_img(d, valid):
        return np.where(valid[..., None], grey(1.0 - np.clip(d, 0, 1)), np.zeros((*d.shape, 3), np.uint8))

    top = [grey(target["mask"]), _angle_rgb(target["angle"], target["confidence"] * (target["mask"] > 0.5)),
           depth_img(target["depth"], target["depth_valid"])]
    bottom = [grey(render["silhouette"]), _angle_rgb(render["angle"], render["mask"].astype(np.float32)),
              depth_img(render["depth"], render["mask"])]
    img = np.concatenate([np.concatenate(top, 1), np.concatenate(bottom, 1)], 0)
    return np.repeat(np.repeat(img, scale, 0), scale, 1)


def write_renders(out_dir: str | Path, out: Any, data: Any, frames: torch.Tensor) -> list[Path]:
    """Write ``renders/frame_<t:05d>.png`` for the rendered keyframes ``frames`` (B,) of ``out``."""
    from vid2haircut.fit.image_terms import quantile_normalize

    paths = []
    angle = out.angle  # computed on each read
    for b, f in enumerate(frames.tolist()):
        dirs = data.direction[f].cpu().numpy()
        tgt = {"mask": data.mask[f].cpu().numpy(), "angle": np.remainder(0.5 * np.arctan2(dirs[..., 1], dirs[..., 0]),
                                                                          math.pi),
               "confidence": data.confidence[f].cpu().numpy(), "depth": data.depth[f].cpu().numpy(),
               "depth_valid": data.depth_valid[f].cpu().numpy()}
        m = out.mask[b].detach()
        depth = (quantile_normalize(out.depth[b].detach(), m) if int(m.sum()) > 1 else out.depth[b].detach())
        ren = {"silhouette": out.silhouette[b].detach().cpu().numpy(), "angle": angle[b].cpu().numpy(),
               "depth": depth.cpu().numpy(), "mask": m.cpu().numpy()}
        p = Path(out_dir) / "renders" / f"frame_{int(data.frames[f]):05d}.png"
        write_image(p, render_panel(tgt, ren))
        paths.append(p)
    return paths


def write_loss_curve(path: str | Path, history: History, weights: LossWeights, title: str = "") -> None:
    """Plot the weighted loss terms and the total per step (log scale) to a PNG (matplotlib Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    steps = np.asarray(history.steps)
    names = {f.name for f in dataclasses.fields(weights)}
    for k, vals in sorted(history.terms.items()):
        v = np.asarray(vals, np.float64) * (getattr(weights, k) if k in names else 1.0)
        if np.isfinite(v).any() and np.nanmax(np.abs(v)) > 0:
            ax.plot(steps, np.abs(v), label=k, lw=1)
    if len(steps):
        ax.plot(steps, history.total, label="total", color="k", lw=1.5)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("weighted loss")
    ax.set_title(title)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def save_torch(path: str | Path, obj: Any) -> None:
    """Atomically ``torch.save`` an object."""
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


def load_torch(path: str | Path) -> Any:
    """``torch.load`` on the CPU (plain tensors / dicts only); errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file not found")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unpickling failure
        raise ValueError(f"{path}: not a readable torch file ({e})") from None


def write_record(path: str | Path, record: dict) -> None:
    """Write the stage's JSON record."""
    write_json(path, record)
