# Shared set-up: config validation, sequence discovery, wildcard constraints, target lists.
import json
import re
import shlex
import sys
from pathlib import Path

from snakemake.utils import validate

from vid2haircut import workflow_support as ws


_problems = ws.schema_errors(config, Path(workflow.current_basedir) / ".." / "schemas" / "config.schema.yaml")
if _problems:
    raise ValueError("config does not match workflow/schemas/config.schema.yaml:\n  " + "\n  ".join(_problems))
validate(config, schema="../schemas/config.schema.yaml")  # (also fills the schema's defaults)
ws.check_config(config)  # what the schema cannot say, before any job (a job's old outputs go when it starts)

# Rules call the installed package through the interpreter that runs Snakemake. Every path and
# name that reaches a shell command is quoted (`{...:q}` in the rules, shlex.quote here).
CLI = f"{shlex.quote(sys.executable)} -m vid2haircut"
DATASET_ROOT = Path(config["dataset_root"])
SYNTH = config.get("synth", {})
CAMERA_ARG = f"--serial {shlex.quote(str(config['camera']))}" if config.get("camera") is not None else ""
EMBEDDING = config["head"].get("landmark_embedding")
EMBEDDING_ARG = f"--landmark-embedding {shlex.quote(str(EMBEDDING))}" if EMBEDDING else ""
SYNTH_SEQUENCES = {(s["subject"], s["seq"]): s for s in SYNTH.get("sequences", [])}
SEQUENCES = ws.select_sequences(DATASET_ROOT, set(SYNTH_SEQUENCES), config.get("sequences"))
VARIANTS = ws.active_variants(config["variants"])
for _note in (ws.synth_note(DATASET_ROOT, set(SYNTH_SEQUENCES)), ws.skipped_note(DATASET_ROOT, set(SYNTH_SEQUENCES))):
    if _note:
        print(f"vid2haircut: note: {_note}", file=sys.stderr)
if config["prior"]["source"] == "bundled":
    PRIOR_FILES = [str(ws.bundled_prior_dir() / n) for n in ("prior.pt", "codec.npz", "prior.json")]
else:
    PRIOR_FILES = [f"resources/prior/{config['prior']['setting']}/{n}" for n in ("prior.pt", "codec.npz", "prior.json")]
SUBJECTS = sorted({s for s, _ in SEQUENCES}) or ["none"]
SEQ_NAMES = sorted({q for _, q in SEQUENCES}) or ["none"]


def alternatives(names):
    """A wildcard pattern matching exactly ``names`` (regex characters in folder names escaped)."""
    return "|".join(re.escape(n) for n in names) or "(?!)"


wildcard_constraints:
    subject=alternatives(SUBJECTS),
    seq=alternatives(SEQ_NAMES),
    variant=alternatives(VARIANTS),


def synth_record(wildcards):
    key = (wildcards.subject, wildcards.seq)
    if key not in SYNTH_SEQUENCES:
        raise ValueError(f"{sequence_dir(wildcards)}: not in synth.sequences, the synthesize rule does not make it "
                         "(a sequence of your own needs ground_truth/strands.npz and its images in place)")
    return SYNTH_SEQUENCES[key]


def sequence_dir(wildcards):
    """The sequence folder of a (subject, seq) wildcard pair."""
    return DATASET_ROOT / wildcards.subject / "sequences" / wildcards.seq


def sequence_ready(wildcards):
    """File whose existence means the sequence folder is complete (made by `synthesize` for the demo)."""
    if (wildcards.subject, wildcards.seq) in SYNTH_SEQUENCES:
        return str(sequence_dir(wildcards) / "ground_truth" / "meta.json")
    return str(DATASET_ROOT / wildcards.subject / "calibration" / "camera_params.json")


def shell_json(obj):
    """A JSON object as one shell word (for `--settings`)."""
    return shlex.quote(json.dumps(obj, sort_keys=True, separators=(",", ":")))


def variant_settings(variant):
    """Stage-2 settings of an ablation variant: the config's stage2 settings plus its overrides."""
    return ws.variant_settings(config["fit"]["stage2"], VARIANTS[variant])


def gt_path(subject, seq):
    return DATASET_ROOT / subject / "sequences" / seq / "ground_truth" / "strands.npz"


def has_ground_truth(subject, seq):
    return (subject, seq) in SYNTH_SEQUENCES or gt_path(subject, seq).exists()


def ground_truth_strands(wildcards):
    return str(gt_path(wildcards.subject, wildcards.seq))


def gt_arg(wildcards):
    if has_ground_truth(wildcards.subject, wildcards.seq):
        return f"--gt {shlex.quote(str(gt_path(wildcards.subject, wildcards.seq)))}"
    return ""


def result_strands(wildcards):
    """Strand file that a (stage, variant) evaluation scores."""
    base = f"results/stage1/{wildcards.subject}/{wildcards.seq}"
    if wildcards.stage == "prior":
        return f"{base}/prior_strands.npz"
    if wildcards.stage == "stage1":
        return f"{base}/strands.npz"
    return f"results/stage2/{wildcards.subject}/{wildcards.seq}/{wildcards.variant}/strands.npz"


def _runs():
    """(subject, seq, stage, variant) of every reconstruction; prior and stage1 are variant 'single_view'."""
    runs = []
    for s, q in SEQUENCES:
        runs += [(s, q, "prior", "single_view"), (s, q, "stage1", "single_view")]
        runs += [(s, q, "stage2", v) for v in VARIANTS]
    return runs


def evaluation_targets():
    return [f"results/evaluate/{s}/{q}/{st}/{v}/metrics.json" for s, q, st, v in _runs() if has_ground_truth(s, q)]


def no_ground_truth_args():
    labels = [f"{s}/{q}/{st}/{v}" for s, q, st, v in _runs() if not has_ground_truth(s, q)]
    return " ".join(f"--no-gt {shlex.quote(lab)}" for lab in labels)


def expand_sequences(pattern):
    return [pattern.format(subject=s, seq=q) for s, q in SEQUENCES]


def all_targets():
    targets = [
        str(DATASET_ROOT / s / "sequences" / q / "ground_truth" / "meta.json")
        for s, q in SEQUENCES
        if (s, q) in SYNTH_SEQUENCES
    ]
    targets.append("resources/head/proxy-v1/head.obj")
    targets += expand_sequences("results/figures/{subject}/{seq}/coverage.png")
    targets += [f"results/figures/{s}/{q}/{v}/turntable.png" for s, q in SEQUENCES for v in VARIANTS]
    if SEQUENCES:
        targets.append("results/summary/metrics.csv")
    return targets
