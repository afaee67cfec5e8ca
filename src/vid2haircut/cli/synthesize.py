"""``vid2haircut synthesize``: write a synthetic head-motion sequence, or a hairstyle contact sheet."""

from __future__ import annotations

import argparse

def _cfg_defaults():
    from vid2haircut.synth.sequence import SynthConfig

    return SynthConfig()


def register(subparsers: argparse._SubParsersAction) -> None:
    d = _cfg_defaults()
    p = subparsers.add_parser(
        "synthesize", help="write a synthetic sequence folder (or --preview a contact sheet)",
        description="Write <root>/<subject>/sequences/<seq> in the sequence-folder format: a procedural "
                    "hairstyle on the proxy head turning in front of one camera, with masks, depth, "
                    "landmarks, tracking, calibration and ground truth. With --preview PNG, only write a "
                    "contact sheet of the hairstyle families instead.")
    p.add_argument("--root", help="dataset root")
    p.add_argument("--subject", help="subject folder name, e.g. synth_0000")
    p.add_argument("--seq", help="sequence name, e.g. HAIR")
    p.add_argument("--family", default=d.family, help=f"hairstyle family (default {d.family})")
    p.add_argument("--seed", type=int, default=d.seed, help="hairstyle / noise seed")
    p.add_argument("--frames", type=int, default=d.n_frames, help="number of frames")
    p.add_argument("--size", type=int, default=d.width, help="image width = height, pixels")
    p.add_argument("--strands", type=int, default=d.n_strands, help="number of strands")
    p.add_argument("--points", type=int, default=d.n_points, help="points per strand")
    p.add_argument("--landmark-noise", type=float, default=d.landmark_noise_px, help="landmark noise sigma, px")
    p.add_argument("--yaw-max", type=float, default=d.yaw_max_deg, help="peak yaw, degrees")
    p.add_argument("--pitch-max", type=float, default=d.pitch_max_deg, help="peak pitch, degrees")
    p.add_argument("--sway-max", type=float, default=d.sway_max_m, help="hair sway bound, metres")
    p.add_argument("--sway-gain", type=float, default=d.sway_gain,
                   help="hair sway per unit of head angular velocity and lever (larger: hair lags more)")
    p.add_argument("--head-scale", type=float, default=d.head_scale)
    p.add_argument("--head-width", type=float, default=d.head_width)
    p.add_argument("--head-depth", type=float, default=d.head_depth)
    p.add_argument("--head-crown", type=float, default=d.head_crown)
    p.add_argument("--image-format", choices=("jpg", "png"), default=d.image_format)
    p.add_argument("--serial", default=d.serial, help="camera serial")
    p.add_argument("--save-frame-points", action="store_true", help="store every frame's moved strands")
    p.add_argument("--overwrite", action="store_true", help="replace an existing sequence folder")
    p.add_argument("--workers", type=int, default=2, help="frames rendered in parallel (threads)")
    p.add_argument("--preview", metavar="PNG", help="write a contact sheet of all families to PNG and exit")
    p.add_argument("--preview-size", type=int, default=256, help="contact sheet: side of one view, px")
    p.add_argument("--preview-strands", type=int, default=4000, help="contact sheet: strands per hairstyle")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.preview:
        from vid2haircut.synth.preview import contact_sheet

        contact_sheet(args.preview, seed=args.seed, n_strands=args.preview_strands, size=args.preview_size)
        return 0
    missing = [f"--{k}" for k in ("root", "subject", "seq") if not getattr(args, k)]
    if missing:
        raise ValueError(f"synthesize: {', '.join(missing)} required (or --preview PNG)")
    from vid2haircut.synth.sequence import SynthConfig, synthesize_sequence

    cfg = SynthConfig(family=args.family, seed=args.seed, n_frames=args.frames, width=args.size, height=args.size,
                      n_strands=args.strands, n_points=args.points, landmark_noise_px=args.landmark_noise,
                      yaw_max_deg=args.yaw_max, pitch_max_deg=args.pitch_max, sway_max_m=args.sway_max,
                      sway_gain=args.sway_gain,
                      head_scale=args.head_scale, head_width=args.head_width, head_depth=args.head_depth,
                      head_crown=args.head_crown, image_format=args.image_format, serial=args.serial,
                      save_frame_points=args.save_frame_points)
    synthesize_sequence(args.root, args.subject, args.seq, cfg, workers=args.workers, overwrite=args.overwrite)
    return 0
