"""Does Stage 2 see the hair sway, and does its deformation field fit it?

On a ``benchmarks/quality.py`` work folder (sequences made with hair motion), for each keyframe:

- the ground truth's sway at the strand tips (``vid2haircut.synth.motion``: the offset of each
  point from the rest hairstyle in the head's frame), mean over the strands, millimetres;
- the image loss (silhouette + direction + depth, Stage 2's weights 1) of the ground truth encoded
  in the hair map (the ``oracle`` run), rendered as it is (a = 0), with the true sway of its own
  guides added (a = 1), half of it (a = 0.5) and reversed (a = -1): whether the images hold the sway;
- with ``--free-steps S``, for each turned keyframe: S Adam steps (lr 0.01) on free per-strand
  offsets of those guides, shaped like the deformation field's (two coefficients per strand along
  its normal and binormal, 8 mm each, weighted from zero at the root to one at the tip): how far
  the image loss alone moves the tips and whether it moves them along the sway;
- with ``--fit VARIANT`` (a Stage 2 run of the work folder, e.g. ``stage2``, or any Stage 2 output
  folder of the sequence), the tip offsets of
  its fitted deformation field on its fitted guides, mean and max in millimetres, and the median
  cosine between them and the ground truth's sway of the nearest-rooted ground-truth strand.

    .venv/bin/python benchmarks/sway_probe.py --work results/benchmarks/quality_v11 \\
        --sequences bob_1000,wavy_1004 --fit stage2 --free-steps 100
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
import quality_data  # noqa: E402  (the benchmark's sequence layout)
from keyframe_sway import tip_sway  # noqa: E402


def _cos(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(N,3), (N,3) -> (N,) cosine (0 where either is zero)."""
    return (a * b).sum(-1) / (a.norm(dim=-1) * b.norm(dim=-1) + 1e-12)


def free_offsets(canon: torch.Tensor, sway: torch.Tensor, data, position: int, render_cfg, steps: int,
                 lr: float = 0.01) -> str:
    """Fit per-strand offsets (the field's shape, free per strand) to one keyframe's image loss.

    Args:
        canon: (N,P,3) guides. sway: (N,P,3) their true offsets at this keyframe.
        position: keyframe position in ``data``. steps: Adam steps.

    Returns:
        One line: image loss before / after, mean tip offset (mm), mean cosine with the sway at the tips.
    """
    from vid2haircut.fit.deform import DeformConfig, deformation_weight, strand_frames
    from vid2haircut.fit.scene import image_losses, render_frames

    field = DeformConfig()                                   # the Stage 2 field's bound and pinned root
    nrm, bin_ = strand_frames(canon)
    w = deformation_weight(torch.linspace(0.0, 1.0, canon.shape[1]), field.pinned_fraction)[None, :, None]
    ab = torch.zeros(canon.shape[0], 1, 2, requires_grad=True)
    opt = torch.optim.Adam([ab], lr=lr)
    fr = torch.tensor([position])

    def offsets() -> torch.Tensor:
        return w * field.max_offset * (ab[..., :1] * nrm + ab[..., 1:] * bin_)

    def image_loss() -> torch.Tensor:
        return sum(image_losses(render_frames((canon + offsets())[None], data, fr, render_cfg), data, fr).values())

    first = None
    for _ in range(steps):
        opt.zero_grad()
        total = image_loss()
        first = float(total) if first is None else first
        total.backward()
        opt.step()
    with torch.no_grad():
        tip = offsets()[:, -1]
        last = float(image_loss())
        moved = tip.norm(dim=-1) > 1e-4
        cos = float(_cos(tip[moved], sway[moved, -1]).mean()) if bool(moved.any()) else 0.0
    return (f"free per-strand offsets, {steps} steps: image loss {first:.4f} -> {last:.4f}, tip offset mean "
            f"{tip.norm(dim=-1).mean() * 1e3:.1f} mm, mean cos with the true sway {cos:+.2f}")


def loss_probe(seq: dict, run: Path, params, free_steps: int = 0) -> list[str]:
    """Image loss of the oracle run's guides with a times the true sway, per keyframe (and, with
    ``free_steps``, :func:`free_offsets` on each turned keyframe)."""
    from vid2haircut.fit.pipeline import load_fit_data, load_hairmap, stage2_config
    from vid2haircut.fit.scene import image_losses, render_frames
    from vid2haircut.fit.stage2 import Stage2Model
    from vid2haircut.prior.codec import StrandCodec
    from vid2haircut.synth.motion import sway_points

    cfg = stage2_config({}, "cpu", None)
    z, mask, _ = load_hairmap(run / "hairmap.npz")
    codec = StrandCodec.load(run / "codec.npz")
    data = load_fit_data(seq["root"], seq["subject"], seq["keyframes"], seq["head"], seq["targets"],
                         size=cfg.render.size, n_keyframes=cfg.n_keyframes,
                         occlude_head=cfg.render.occlude_head, device="cpu")
    model = Stage2Model(data, codec, cfg, torch.as_tensor(z), torch.as_tensor(mask))
    with torch.no_grad():
        canon = model.canonical()[:, model.layout.render_index]
    rows = []
    for i, t in enumerate(data.frames):
        sway = torch.as_tensor(sway_points(canon.numpy(), params, t)) - canon
        losses = []
        for a in (0.0, 0.5, 1.0, -1.0):
            with torch.no_grad():
                fr = torch.tensor([i])
                parts = image_losses(render_frames((canon + a * sway)[None], data, fr, cfg.render), data, fr)
            losses.append(float(sum(parts.values())))
        rows.append(f"frame {t}: oracle image loss a=0 {losses[0]:.4f}, 0.5 {losses[1]:.4f}, "
                    f"1 {losses[2]:.4f}, -1 {losses[3]:.4f}")
        if free_steps and i > 0:
            rows.append(f"frame {t}: " + free_offsets(canon, sway, data, i, cfg.render, free_steps))
    return rows


def fit_probe(seq: dict, run: Path, rest: np.ndarray, params) -> list[str]:
    """Tip offsets of a fitted deformation field against the ground truth's sway, per keyframe."""
    from vid2haircut.fit.deform import DeformationField, DeformConfig
    from vid2haircut.synth.motion import sway_points

    rec = torch.load(run / "deform.pt", map_location="cpu", weights_only=False)
    field = DeformationField(len(rec["frames"]), rec["state_dict"]["texel_embed.weight"].shape[0],
                             DeformConfig(**rec["config"]))
    field.load_state_dict(rec["state_dict"])
    guides = torch.as_tensor(np.load(run / "guides.npz")["points"], dtype=torch.float32)
    _, near = cKDTree(rest[:, 0]).query(guides[:, 0].numpy())
    rows = []
    for i, t in enumerate(rec["frames"]):
        with torch.no_grad():
            off = field.offsets(guides, i)[:, -1].numpy()
        truth = (sway_points(rest, params, t) - rest)[near, -1]
        cos = _cos(torch.as_tensor(off), torch.as_tensor(truth)).numpy()
        tip = np.linalg.norm(off, axis=-1)
        rows.append(f"frame {t}: fitted tip offset mean {tip.mean() * 1e3:.1f} mm, max {tip.max() * 1e3:.1f} mm, "
                    f"median cos with the true sway {np.median(cos):+.2f}")
    return rows


def main(argv: list[str] | None = None) -> None:
    from vid2haircut.io.strand_formats import load_strands
    from vid2haircut.synth.motion import MotionParams

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--work", required=True, help="a benchmarks/quality.py work folder")
    p.add_argument("--sequences", required=True, help="comma-separated <family>_<seed>")
    p.add_argument("--fit", help="a Stage 2 variant of the work folder (or a Stage 2 output folder) whose "
                                 "deformation field to compare")
    p.add_argument("--free-steps", type=int, default=0, help="fit free per-strand offsets per keyframe")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    work = Path(args.work)
    for name in args.sequences.split(","):
        seq = quality_data.seq_files(work, name)
        meta = json.loads(seq["gt"].with_name("meta.json").read_text())
        if "motion" not in meta:
            raise SystemExit(f"{seq['gt'].with_name('meta.json')}: no 'motion' record")
        params = MotionParams.from_dict(meta["motion"])
        rest = np.asarray(load_strands(seq["gt"]).points)
        frames = json.loads(Path(seq["keyframes"]).read_text())["frames"]
        print(f"## {name}")
        for t, tip in zip(frames, tip_sway(rest, params, frames)):
            print(f"frame {t}: true tip sway mean {tip.mean() * 1e3:.1f} mm, max {tip.max() * 1e3:.1f} mm")
        print("\n".join(loss_probe(seq, work / "runs" / name / "oracle", params, args.free_steps)))
        if args.fit:
            run = Path(args.fit) if Path(args.fit).is_dir() else work / "runs" / name / args.fit
            print("\n".join(fit_probe(seq, run, rest, params)))


if __name__ == "__main__":
    main()
