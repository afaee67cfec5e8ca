"""The quality benchmark's sequences: which ones, where a work folder keeps them, and their making.

A sequence is named ``<family>_<seed>`` (a generator family, a seed >= 1000 that the prior never
trained on). :func:`prepare` synthesises it with ground truth and runs the front stages
(keyframes, head fit, targets) under ``<work>/``, cached; :func:`seq_files` says where each piece
lies. ``quality.py`` fits and scores them; the other benchmarks that read a quality work folder
(``stage2_sweep.py``, ``redecode.py``, ...) find its sequences here.
"""

from __future__ import annotations

import json
from pathlib import Path

SEQUENCES = [("bob", 1000), ("shoulder_straight", 1001), ("side_parted", 1002), ("bangs", 1003),
             ("wavy", 1004), ("short_straight", 1005)]
HEAD_FILL = 0.6  # fraction of the image height the head (crown to neck) fills (the generator's default)
YAW_MAX = 60.0  # largest head turn of the sequences, degrees (the generator's default; see --yaw-max)
SWAY_GAIN = 0.012  # hair sway of the sequences (the generator's default; see --sway-gain)


def parse_sequence(name: str) -> tuple[str, int]:
    """``<family>_<seed>`` -> (family, seed) for any generator family and a seed >= 1000 (the prior
    trains on seeds below 1000); SystemExit naming what is wrong otherwise."""
    from vid2haircut.synth.hairstyles import FAMILIES

    family, _, seed = name.rpartition("_")
    if family not in FAMILIES or not seed.isdigit():
        raise SystemExit(f"unknown sequence {name!r}: expected <family>_<seed> with a family of "
                         f"{', '.join(FAMILIES)}")
    if int(seed) < 1000:
        raise SystemExit(f"sequence {name!r}: seeds below 1000 are the prior's training hairstyles")
    return family, int(seed)


def seq_files(work: Path, subject: str) -> dict:
    """Where a sequence of a work folder and its front-stage outputs live (the dict :func:`prepare` returns)."""
    front = work / "front" / subject
    return {"root": work / "data", "subject": subject, "keyframes": front / "keyframes.json",
            "head": front / "head.npz", "targets": front / "targets",
            "gt": work / "data" / subject / "sequences" / "HAIR" / "ground_truth" / "strands.npz"}


def prepare(work: Path, family: str, seed: int, n_frames: int, sway_gain: float = SWAY_GAIN,
            head_fill: float = HEAD_FILL, n_keyframes: int = 6, yaw_max: float = YAW_MAX,
            depth_context: bool = False) -> dict:
    """Synthesise one sequence and run the front stages (cached) with ``n_keyframes`` keyframes
    (``depth_context``: depth maps and targets that also cover the visible head)."""
    from vid2haircut.front.keyframes import KeyframeConfig
    from vid2haircut.front.stages import run_fit_head, run_keyframes, run_targets
    from vid2haircut.synth.sequence import SynthConfig, synthesize_sequence

    seq = seq_files(work, f"{family}_{seed}")
    root, subject, front = seq["root"], seq["subject"], seq["keyframes"].parent
    meta = seq["gt"].with_name("meta.json")
    if meta.is_file():
        cached = json.loads(meta.read_text())
        for key, have, want in (("sway_gain", cached["motion"].get("sway_gain"), sway_gain),
                                ("head_fill", cached["config"].get("head_fill"), head_fill),
                                ("yaw_max_deg", cached["motion"].get("yaw_max_deg"), yaw_max),
                                ("depth_context", float(cached["config"].get("depth_context", False)),
                                 float(depth_context))):
            if have is None or abs(have - want) > 1e-12:
                raise SystemExit(f"{meta}: cached sequence has {key} {have}, not {want}; use another --work")
    else:
        synthesize_sequence(root, subject, "HAIR", SynthConfig(family=family, seed=seed, n_frames=n_frames,
                                                               sway_gain=sway_gain, head_fill=head_fill,
                                                               yaw_max_deg=yaw_max, depth_context=depth_context),
                            overwrite=True)
    if not (front / "keyframes.json").is_file():
        run_keyframes(root, subject, "HAIR", front, cfg=KeyframeConfig(num_keyframes=n_keyframes))
    have = len(json.loads((front / "keyframes.json").read_text())["frames"])
    if have != n_keyframes:
        raise SystemExit(f"{front / 'keyframes.json'}: cached front stages have {have} keyframes, not "
                         f"{n_keyframes}; use another --work")
    if not (front / "head.npz").is_file():
        run_fit_head(root, subject, "HAIR", front / "keyframes.json", front)
    if not (front / "targets" / "targets.json").is_file():
        run_targets(root, subject, "HAIR", front / "head.npz", front / "targets", depth_context=depth_context)
    return seq
