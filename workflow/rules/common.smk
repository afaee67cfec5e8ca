# Shared set-up: config validation, sequence discovery, wildcard constraints, target lists.
import sys
from pathlib import Path

from snakemake.utils import validate


validate(config, schema="../schemas/config.schema.yaml")

# Rules call the installed package through the interpreter that runs Snakemake.
PY = sys.executable
CLI = f"{PY} -m vid2haircut"
DATASET_ROOT = Path(config["dataset_root"])
SYNTH = config.get("synth", {})


def _synth_sequences():
    """{(subject, seq): record} of the sequences the `synthesize` rule makes."""
    return {(s["subject"], s["seq"]): s for s in SYNTH.get("sequences", [])}


def _discovered_sequences():
    """(subject, seq) pairs found on disk under dataset_root (sequence-format spec)."""
    found = set()
    for seq_dir in DATASET_ROOT.glob("*/sequences/*"):
        if seq_dir.is_dir() and (seq_dir / "images").exists():
            found.add((seq_dir.parent.parent.name, seq_dir.name))
    return found


def _selected_sequences():
    known = set(_synth_sequences()) | _discovered_sequences()
    if config.get("sequences"):
        chosen = [tuple(s.split("/", 1)) for s in config["sequences"]]
        missing = [f"{a}/{b}" for a, b in chosen if (a, b) not in known]
        if missing:
            raise ValueError(
                f"config 'sequences' names {missing}, not found under {DATASET_ROOT} "
                "and not in synth.sequences"
            )
        return sorted(chosen)
    return sorted(known)


SEQUENCES = _selected_sequences()
SUBJECTS = sorted({s for s, _ in SEQUENCES}) or ["none"]
SEQ_NAMES = sorted({q for _, q in SEQUENCES}) or ["none"]


wildcard_constraints:
    subject="|".join(SUBJECTS),
    seq="|".join(SEQ_NAMES),


def sequence_dir(wildcards):
    """The sequence folder of a (subject, seq) wildcard pair."""
    return DATASET_ROOT / wildcards.subject / "sequences" / wildcards.seq


def sequence_ready(wildcards):
    """File whose existence means the sequence folder is complete (made by `synthesize` for the demo)."""
    if (wildcards.subject, wildcards.seq) in _synth_sequences():
        return str(sequence_dir(wildcards) / "ground_truth" / "meta.json")
    return str(DATASET_ROOT / wildcards.subject / "calibration" / "camera_params.json")


def expand_sequences(pattern):
    return [pattern.format(subject=s, seq=q) for s, q in SEQUENCES]


def all_targets():
    targets = [str(DATASET_ROOT / s / "sequences" / q / "ground_truth" / "meta.json")
               for s, q in SEQUENCES if (s, q) in _synth_sequences()]
    targets.append("resources/head/proxy-v1/head.obj")
    return targets
