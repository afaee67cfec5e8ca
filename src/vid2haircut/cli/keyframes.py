"""``vid2haircut keyframes``: pick the keyframes of a sequence (most frontal frame + pose coverage)."""

from __future__ import annotations

import argparse

from vid2haircut.cli import argtypes


def add_sequence_args(p: argparse.ArgumentParser) -> None:
    """Arguments naming one sequence (shared by the front-stage commands)."""
    p.add_argument("--root", "--dataset-root", dest="dataset_root", required=True, help="dataset root holding <subject>/sequences/<seq>")
    p.add_argument("--subject", required=True, help="subject folder name")
    p.add_argument("--seq", "--sequence", dest="sequence", required=True, help="sequence name")
    p.add_argument("--serial", default=None, help="camera serial (default: first sorted / as recorded)")
    p.add_argument("--out", required=True, type=argtypes.out_folder, help="output folder")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("keyframes", help="select keyframes -> keyframes.json + contact sheet",
                              description=__doc__)
    add_sequence_args(p)
    p.add_argument("--num-keyframes", type=argtypes.bounded_int(1), default=6, help="number of keyframes M (>= 1)")
    p.add_argument("--head-model", default="proxy-v1", help="head model name or FLAME .pkl path")
    p.add_argument("--landmark-embedding", default=None,
                   help="FLAME landmark embedding (.npz/.pkl with lmk_face_idx, lmk_b_coords)")
    p.add_argument("--landmarks", default="auto", choices=["auto", "file", "detect"],
                   help="landmark source: the sequence's landmark file, MediaPipe detection, or auto")
    p.add_argument("--blur-ratio", type=argtypes.unit_float, default=0.35,
                   help="reject frames less sharp than this fraction of the median sharpness (0..1)")
    p.add_argument("--max-candidates", type=argtypes.bounded_int(1), default=300,
                   help="frames scored at most (evenly spaced)")
    p.add_argument("--still-frames", type=argtypes.nonneg_int, default=3,
                   help="the reference is the frontal frame whose head moved least over this many preceding "
                        "frames (hair lags the head); 0 = simply the most frontal frame")
    p.add_argument("--frontal-tolerance", type=argtypes.nonneg_float, default=3.0,
                   help="degrees above the most frontal view that still count as frontal for the reference")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vid2haircut.front.keyframes import KeyframeConfig
    from vid2haircut.front.stages import run_keyframes

    run_keyframes(args.dataset_root, args.subject, args.sequence, args.out, serial=args.serial,
                  head_model=args.head_model, landmark_embedding=args.landmark_embedding,
                  cfg=KeyframeConfig(num_keyframes=args.num_keyframes, max_candidates=args.max_candidates,
                                     blur_ratio=args.blur_ratio, landmark_source=args.landmarks,
                                     still_frames=args.still_frames,
                                     frontal_tolerance_deg=args.frontal_tolerance))
    return 0
