"""A tiny, fully known fitting problem (for tests and smoke runs; seconds on a CPU).

A procedural strand family on the proxy head (strands leave the scalp, follow it downwards and
then fall), a small codec fitted on it, a ground-truth hair map whose strand length varies over
the scalp, and M keyframes of the ground truth rendered by the same strand renderer (head yawing
in front of a fixed camera) as targets. :func:`write_toy_files` writes the problem in the
front-stage file formats (calibration, keyframes.json, head.npz, targets) for the file-level entry
points and the command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from vid2haircut.fit.data import FitData, make_fit_data
from vid2haircut.prior.codec import StrandCodec

__all__ = ["ToyProblem", "toy_strands", "toy_problem", "write_toy_files"]

SERIAL = "toycam"


class ToyProblem(NamedTuple):
    """Attributes: data (targets at the fitting size), codec, z_gt (K,R,R), mask (R,R), head,
    targets (full-size numpy targets per keyframe), K (3,3), world_2_cam (4,4), world_from_head (M,4,4),
    frames (M,), size."""

    data: FitData
    codec: StrandCodec
    z_gt: torch.Tensor
    mask: torch.Tensor
    head: Any
    targets: list[dict[str, np.ndarray]]
    K: np.ndarray
    world_2_cam: np.ndarray
    world_from_head: np.ndarray
    frames: list[int]
    size: int


def toy_strands(roots: np.ndarray, lengths: np.ndarray, lift: np.ndarray, n_points: int) -> np.ndarray:
    """Strands that follow the head downwards and then fall.

    Args:
        roots: (N,3) root points (head centred at the origin); lengths: (N,) metres;
        lift: (N,) outward push (0.2..0.6); n_points: points per strand.

    Returns:
        (N,n_points,3) float32.
    """
    p = np.asarray(roots, np.float64).copy()
    out = [p.copy()]
    step = (np.asarray(lengths, np.float64) / (n_points - 1))[:, None]
    down = np.array([0.0, -1.0, 0.0])
    r0 = np.linalg.norm(p, axis=1, keepdims=True)
    for _ in range(n_points - 1):
        rad = p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-9)
        tang = down[None] - (rad @ down)[:, None] * rad
        near = np.linalg.norm(p, axis=1, keepdims=True) < r0 + 0.012
        d = np.where(near, tang + lift[:, None] * rad, down + 0.05 * rad)
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
        p = p + step * d
        out.append(p.copy())
    return np.stack(out, 1).astype(np.float32)


def toy_problem(size: int = 40, n_frames: int = 3, map_res: int = 12, k: int = 12, n_points: int = 16,
                yaw_deg: float = 45.0, seed: int = 0, device: str | torch.device = "cpu") -> ToyProblem:
    """Build the toy problem.

    Args:
        size: image side in pixels (targets rendered and fitted at this size).
        n_frames: keyframes M (yaw spread evenly over [-yaw_deg, yaw_deg], the frontal one first).
        map_res: hair map resolution R; k: codec components; n_points: points per strand.
        seed: seed of the codec corpus.
    """
    from vid2haircut.camera import look_at
    from vid2haircut.geometry import axis_angle_to_matrix, make_transform
    from vid2haircut.head import get_head
    from vid2haircut.prior.hairmap import HairMap, decode_guides
    from vid2haircut.prior.scalp import scalp_grid
    from vid2haircut.render import render_strands

    head = get_head("proxy-v1")
    rng = np.random.default_rng(seed)
    corpus_grid = scalp_grid(head, 24)
    roots = corpus_grid.roots.reshape(-1, 3)[corpus_grid.index]
    reps = np.repeat(roots, 4, 0)
    corpus = toy_strands(reps, rng.uniform(0.04, 0.16, len(reps)), rng.uniform(0.2, 0.6, len(reps)), n_points)
    codec = StrandCodec.fit(corpus, k=k)
    grid = scalp_grid(head, map_res)
    uv = grid.uv.reshape(-1, 2)
    gt_len = 0.07 + 0.06 * uv[:, 1]                       # longer towards the face side
    gt_lift = 0.3 + 0.2 * uv[:, 0]
    gt = toy_strands(grid.roots.reshape(-1, 3), gt_len, gt_lift, n_points)
    z_gt = codec.encode(torch.as_tensor(gt)).T.reshape(k, map_res, map_res)
    mask = torch.as_tensor(grid.valid, dtype=torch.float32)
    guides = decode_guides(HairMap(z_gt, mask), head, codec).points
    f = 1.3 * size
    K = np.array([[f, 0.0, (size - 1) / 2], [0.0, f, (size - 1) / 2], [0.0, 0.0, 1.0]])
    w2c = look_at(np.array([0.0, -0.03, 0.7]), np.array([0.0, -0.03, 0.0]))
    yaws = [0.0] + [float(y) for y in np.linspace(-yaw_deg, yaw_deg, n_frames) if abs(y) > 1e-9][: n_frames - 1]
    poses = np.stack([make_transform(axis_angle_to_matrix(np.array([0.0, np.deg2rad(y), 0.0])), np.zeros(3))
                      for y in yaws])
    from vid2haircut.render import mesh_depth

    cfh = torch.as_tensor(np.stack([w2c @ p for p in poses]), dtype=torch.float32)
    Kt = torch.as_tensor(np.repeat(K[None], len(poses), 0), dtype=torch.float32)
    verts = torch.as_tensor(head.vertices)[None].expand(len(poses), -1, -1)
    hd = mesh_depth(verts, torch.as_tensor(head.faces), Kt, cfh, size, size)
    with torch.no_grad():
        out = render_strands(guides[None].expand(len(poses), -1, -1, -1), Kt, cfh, size, size, strand_width=0.004,
                             head_depth=hd, compositing="bins")
    targets = []
    angle = out.angle  # computed on each read
    for b in range(len(poses)):
        m = out.mask[b].numpy()
        d = out.depth[b].numpy()
        if m.sum() > 2:
            lo, hi = np.quantile(d[m], [0.05, 0.95])
            d = np.where(m, (d - lo) / max(hi - lo, 1e-6), 0.0)
        targets.append({"mask": out.silhouette[b].numpy().astype(np.float32), "angle": angle[b].numpy(),
                        "confidence": m.astype(np.float32), "depth": d.astype(np.float32), "depth_valid": m})
    frames = list(range(len(poses)))
    data = make_fit_data(frames, targets, K, w2c, poses, head, "proxy-v1", size, True, device)
    return ToyProblem(data, codec, z_gt, mask, head, targets, K, w2c, poses, frames, size)


def write_toy_files(problem: ToyProblem, root: str | Path, subject: str = "toy") -> dict[str, Path]:
    """Write the problem as front-stage files.

    Returns:
        {"dataset_root", "keyframes", "head", "targets", "codec"} paths.
    """
    from vid2haircut.camera import Camera, save_cameras
    from vid2haircut.front.headfile import save_head_fit
    from vid2haircut.front.pose import HeadFit
    from vid2haircut.io.atomic import write_json, write_npz
    from vid2haircut.io.sequence import calibration_path

    root = Path(root)
    work = root / "_work" / subject
    m = len(problem.frames)
    save_cameras(calibration_path(root, subject),
                 {SERIAL: Camera(problem.K, problem.world_2_cam, problem.size, problem.size)})
    write_json(work / "keyframes.json", {"frames": problem.frames, "reference": problem.frames[0], "serial": SERIAL,
                                         "scores": {}})
    fit = HeadFit("proxy-v1", np.ones(3), np.asarray(problem.frames, np.int64), problem.world_from_head,
                  np.zeros(m), np.ones((m, 68), bool), np.full((m, 68, 2), np.nan, np.float32))
    save_head_fit(work / "head.npz", fit, SERIAL, "tracking")
    for t, tg in zip(problem.frames, problem.targets):
        write_npz(work / "targets" / f"frame_{t:05d}.npz", mask=tg["mask"], angle=tg["angle"],
                  confidence=tg["confidence"], depth=tg["depth"], depth_valid=tg["depth_valid"], frame=np.int64(t))
    problem.codec.save(work / "codec.npz")
    return {"dataset_root": root, "keyframes": work / "keyframes.json", "head": work / "head.npz",
            "targets": work / "targets", "codec": work / "codec.npz"}
