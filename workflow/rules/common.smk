# Shared set-up: config validation, sequence discovery, wildcard constraints, target lists.
import sys
from pathlib import Path

from snakemake.utils import validate

from vid2haircut.workflow_support import select_sequences


validate(config, schema="../schemas/config.schema.yaml")

# Rules call the installed package through the interpreter that runs Snakemake.
CLI = f"{sys.executable} -m vid2haircut"
DATASET_ROOT = Path(config["dataset_root"])
SYNTH = config.get("synth", {})
CAMERA_ARG = f"--serial {config['camera']}" if config.get("camera") else ""
SYNTH_SEQUENCES = {(s["subject"], s["seq"]): s for s in SYNTH.get("sequences", [])}
SEQUENCES = select_sequences(DATASET_ROOT, set(SYNTH_SEQUENCES), config.get("sequences"))
SUBJECTS = sorted({s for s, _ in SEQUENCES}) or ["none"]
SEQ_NAMES = sorted({q for _, q in SEQUENCES}) or ["none"]


wildcard_constraints:
    subject="|".join(SUBJECTS),
    seq="|".join(SEQ_NAMES),


def synth_record(wildcards):
    return SYNTH_SEQUENCES[(wildcards.subject, wildcards.seq)]


def sequence_dir(wildcards):
    """The sequence folder of a (subject, seq) wildcard pair."""
    return DATASET_ROOT / wildcards.subject / "sequences" / wildcards.seq


def sequence_ready(wildcards):
    """File whose existence means the sequence folder is complete (made by `synthesize` for the demo)."""
    if (wildcards.subject, wildcards.seq) in SYNTH_SEQUENCES:
        return str(sequence_dir(wildcards) / "ground_truth" / "meta.json")
    return str(DATASET_ROOT / wildcards.subject / "calibration" / "camera_params.json")


def expand_sequences(pattern):
    return [pattern.format(subject=s, seq=q) for s, q in SEQUENCES]


def all_targets():
    targets = [
        str(DATASET_ROOT / s / "sequences" / q / "ground_truth" / "meta.json")
        for s, q in SEQUENCES
        if (s, q) in SYNTH_SEQUENCES
    ]
    targets.append("resources/head/proxy-v1/head.obj")
    targets += expand_sequences("results/targets/{subject}/{seq}")
    return targets
