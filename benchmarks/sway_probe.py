"""Does Stage 2 see the hair sway, and does its deformation field fit it?

On a ``benchmarks/quality.py`` work folder (sequences made with hair motion), for each keyframe:

- the ground truth's sway at the strand tips (``vid2haircut.synth.motion``: the offset of each
  point from the rest hairstyle in the head's frame), mean over the strands, millimetres;
- the image loss (silhouette + direction + depth, Stage 2's weights 1) of the ground truth encoded
  in the hair map (the ``oracle`` run), rendered as it is (a = 0), with the true sway of its own
  guides added (a = 1), half of it (a = 0.5) and reversed (a = -1): whether the images hold the sway;
- with ``--fit VARIANT`` (a Stage 2 run of the work folder, e.g. ``stage2``), the tip offsets of
  its fitted deformation field on its fitted guides, mean and max in millimetres, and the median
  cosine between them and the ground truth's sway of the nearest-rooted ground-truth strand.

    .venv/bin/python benchmarks/sway_probe.py --work results/benchmarks/quality_v8 \\
        --sequences bob_1000,wavy_1004 --fit stage2
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
import quality  # noqa: E402  (the benchmark's sequence layout)


def loss_probe(seq: dict, run: Path, params) -> list[str]:
    """Image loss of the oracle run's guides with a times the true sway, per keyframe."""
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
        cos = (off * truth).sum(-1) / (np.linalg.norm(off, axis=-1) * np.linalg.norm(truth, axis=-1) + 1e-12)
        tip = np.linalg.norm(off, axis=-1)
        rows.append(f"frame {t}: fitted tip offset mean {tip.mean() * 1e3:.1f} mm, max {tip.max() * 1e3:.1f} mm, "
                    f"median cos with the true sway {np.median(cos):+.2f}")
    return rows


def main(argv: list[str] | None = None) -> None:
    from vid2haircut.io.strand_formats import load_strands
    from vid2haircut.synth.motion import MotionParams, sway_points

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--work", required=True, help="a benchmarks/quality.py work folder")
    p.add_argument("--sequences", required=True, help="comma-separated <family>_<seed>")
    p.add_argument("--fit", help="a Stage 2 variant of the work folder whose deformation field to compare")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    work = Path(args.work)
    for name in args.sequences.split(","):
        seq = quality.seq_files(work, name)
        meta = json.loads(seq["gt"].with_name("meta.json").read_text())
        if "motion" not in meta:
            raise SystemExit(f"{seq['gt'].with_name('meta.json')}: no 'motion' record")
        params = MotionParams.from_dict(meta["motion"])
        rest = np.asarray(load_strands(seq["gt"]).points)
        frames = json.loads(Path(seq["keyframes"]).read_text())["frames"]
        print(f"## {name}")
        for t in frames:
            tip = np.linalg.norm(sway_points(rest, params, t)[:, -1] - rest[:, -1], axis=-1)
            print(f"frame {t}: true tip sway mean {tip.mean() * 1e3:.1f} mm, max {tip.max() * 1e3:.1f} mm")
        print("\n".join(loss_probe(seq, work / "runs" / name / "oracle", params)))
        if args.fit:
            print("\n".join(fit_probe(seq, work / "runs" / name / args.fit, rest, params)))


if __name__ == "__main__":
    main()
