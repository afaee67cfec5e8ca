"""Logic behind `workflow/rules/common.smk`: config checks, sequence discovery and selection
(testable without Snakemake).

Snakemake deletes a job's old outputs before it runs the job's command, so a bad value that only
the command would notice costs the previous results of that job. :func:`check_config` therefore
checks, when the config is read, everything the commands would refuse later: the fitting
settings of Stage 1 and of every Stage 2 variant, the device, the synthetic families, the head
model files, non-finite numbers, the dataset folder.
"""

from __future__ import annotations

import math
import re
from pathlib import Path


def discover_sequences(dataset_root: str | Path) -> set[tuple[str, str]]:
    """(subject, seq) pairs of the sequence folders under ``dataset_root`` that hold ``images/``."""
    root = Path(dataset_root)
    found = set()
    for seq_dir in root.glob("*/sequences/*"):
        if seq_dir.is_dir() and (seq_dir / "images").exists():
            found.add((seq_dir.parent.parent.name, seq_dir.name))
    return found


def select_sequences(dataset_root: str | Path, synthetic: set[tuple[str, str]],
                     requested: list[str] | None) -> list[tuple[str, str]]:
    """Sorted (subject, seq) pairs to run.

    Args:
        dataset_root: the config's ``dataset_root``.
        synthetic: pairs the ``synthesize`` rule will create (they need not exist yet).
        requested: the config's ``sequences`` list of "subject/SEQ" strings, or None for all.
    Raises:
        ValueError: a requested sequence is neither on disk nor synthesised.
    """
    known = set(synthetic) | discover_sequences(dataset_root)
    if not requested:
        return sorted(known)
    chosen = []
    for item in requested:
        subject, sep, seq = item.partition("/")
        if not sep or not subject or not seq:
            raise ValueError(f"config 'sequences': '{item}' is not of the form subject/SEQ")
        chosen.append((subject, seq))
    for a, b in chosen:
        folder = Path(dataset_root) / a / "sequences" / b
        if (a, b) not in known and folder.is_dir():
            raise ValueError(f"config 'sequences' names {a}/{b}, but {folder} has no images/ (a sequence needs "
                             "images/cam_<serial>.mp4 or images/cam_<serial>/frame_<t>.jpg|png)")
    missing = [f"{a}/{b}" for a, b in chosen if (a, b) not in known]
    if missing:
        raise ValueError(f"config 'sequences' names {missing}, found neither under {dataset_root} "
                         "nor in synth.sequences")
    return sorted(set(chosen))


def bundled_prior_dir() -> Path:
    """Folder of the prior committed with the package (codec.npz, prior.pt, prior.json)."""
    return Path(__file__).resolve().parent / "data" / "prior" / "default"


def flatten_settings(settings: dict | None, prefix: str = "") -> dict:
    """Nested ``{"weights": {"depth": 0.1}}`` and dotted ``{"weights.depth": 0.1}`` settings as one
    dotted dict (so that merging two keeps the sibling keys of a nested section)."""
    out = {}
    for key, value in (settings or {}).items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten_settings(value, name + "."))
        else:
            out[name] = value
    return out


def variant_settings(stage2: dict | None, variant: dict | None) -> dict:
    """Stage 2 settings of a variant: the config's ``fit.stage2`` with the variant's overrides on top,
    merged key by key (a variant's ``switches.use_deformation`` keeps ``fit.stage2``'s
    ``switches.use_smoothness``)."""
    return {**flatten_settings(stage2), **flatten_settings(variant)}


def active_variants(variants: dict) -> dict:
    """The config's variants without those set to ``false`` (a way to drop the default ``full``
    from a config file merged over ``config/config.yaml``)."""
    return {k: (v or {}) for k, v in variants.items() if v is not False}


def _non_finite(obj, path: str = "") -> list[str]:
    if isinstance(obj, float) and not math.isfinite(obj):
        return [path or "(top)"]
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in _non_finite(v, f"{path}.{k}" if path else str(k))]
    if isinstance(obj, list):
        return [p for i, v in enumerate(obj) for p in _non_finite(v, f"{path}[{i}]")]
    return []


def schema_errors(config: dict, schema_path: str | Path) -> list[str]:
    """The config's violations of the workflow's JSON schema, one short line each ("key.path: what"),
    where Snakemake's own check prints the whole schema with the first one."""
    import jsonschema
    import yaml

    schema = yaml.safe_load(Path(schema_path).read_text())
    validator = jsonschema.Draft202012Validator(schema)
    out = []
    for e in sorted(validator.iter_errors(config), key=lambda e: list(map(str, e.absolute_path))):
        where = ".".join(str(p) for p in e.absolute_path) or "(top level)"
        out.append(f"{where}: {e.message}")
    return out


def _check_compositing(cfg, device: str, where: str) -> None:
    """The exact compositing model runs in the CPU (numba) kernels only."""
    if cfg.render.compositing == "exact" and device != "cpu":
        raise ValueError(f"config: {where}: render.compositing 'exact' runs on the CPU only (device is {device!r})")


def check_config(config: dict) -> None:
    """Check a validated workflow config for what its schema cannot express.

    Raises:
        ValueError naming the config key and what is wrong.
    """
    from vid2haircut.fit.config import Stage1Config, Stage2Config
    from vid2haircut.fit.settings import apply_overrides
    from vid2haircut.head import HEAD_NAMES
    from vid2haircut.synth.hairstyles import FAMILIES

    bad = _non_finite(config)
    if bad:
        raise ValueError(f"config: {', '.join(bad)}: not a finite number")
    dev = str(config.get("device", "cpu"))
    if not re.fullmatch(r"cpu|cuda(:\d+)?", dev):  # (whether CUDA is there is the job's machine's business)
        raise ValueError(f"config: device: {dev!r} is not a device (cpu, cuda or cuda:N)")
    fit = config.get("fit", {})
    try:
        cfg = apply_overrides(Stage1Config(), fit.get("stage1"))
    except ValueError as e:
        raise ValueError(f"config: fit.stage1: {e}") from None
    _check_compositing(cfg, dev, "fit.stage1")
    variants = active_variants(config.get("variants", {"full": {}}))
    if not variants:
        raise ValueError("config: variants: every variant is set to false; at least one Stage 2 variant must run")
    n_keyframes = config.get("keyframes", {}).get("n_keyframes", 6)
    for name, overrides in variants.items():
        where = "fit.stage2" if not overrides else f"variants.{name} (over fit.stage2)"
        merged = variant_settings(fit.get("stage2"), overrides)
        try:
            cfg = apply_overrides(Stage2Config(), merged)
        except ValueError as e:
            raise ValueError(f"config: {where}: {e}") from None
        _check_compositing(cfg, dev, where)
        if "n_keyframes" in merged and cfg.n_keyframes > n_keyframes:  # (the default: every keyframe there is)
            raise ValueError(f"config: {where}: n_keyframes {cfg.n_keyframes} is more than the "
                             f"{n_keyframes} keyframes chosen (keyframes.n_keyframes)")
    for i, entry in enumerate(config.get("synth", {}).get("sequences", [])):
        if entry["family"] not in FAMILIES:
            raise ValueError(f"config: synth.sequences[{i}]: unknown family {entry['family']!r} "
                             f"(one of {', '.join(FAMILIES)})")
    head = config.get("head", {})
    model = str(head.get("model", "proxy-v1"))
    emb = head.get("landmark_embedding")
    if model in HEAD_NAMES:
        if emb:
            raise ValueError(f"config: head.landmark_embedding is for a FLAME model; the built-in head {model!r} "
                             "has its own landmarks")
    else:
        if not Path(model).is_file():
            raise ValueError(f"config: head.model: {model}: neither a built-in head ({', '.join(HEAD_NAMES)}) "
                             "nor an existing FLAME .pkl file")
        if not emb:
            raise ValueError(f"config: head.model is a FLAME model ({model}): set head.landmark_embedding to its "
                             "landmark embedding file (.npz / .pkl with lmk_face_idx, lmk_b_coords)")
        if not Path(emb).is_file():
            raise ValueError(f"config: head.landmark_embedding: {emb}: file not found")
    root = Path(config["dataset_root"])
    if root.exists() and not root.is_dir():
        raise ValueError(f"config: dataset_root: {root} is a file, not a folder")
    synth = config.get("synth", {}).get("sequences", [])
    if not root.exists() and not synth:
        raise ValueError(f"config: dataset_root: {root}: no such folder (and synth.sequences is empty)")
    from vid2haircut.synth.sequence import SYNTH_MARKER

    for entry in synth:
        seq = root / entry["subject"] / "sequences" / entry["seq"]
        ours = (seq / "ground_truth" / "meta.json").is_file() or (seq / SYNTH_MARKER).is_file()
        if seq.is_dir() and any(seq.iterdir()) and not ours:
            raise ValueError(f"config: synth.sequences names {entry['subject']}/{entry['seq']}, but {seq} holds a "
                             "sequence the synthesiser did not write (no ground_truth/meta.json); it would be "
                             "replaced. Remove the entry, or the folder")
    if config.get("sequences") == []:
        raise ValueError("config: sequences: [] lists no sequence; leave it out (or null) to run every sequence found")


def skipped_note(dataset_root: str | Path, synthetic: set[tuple[str, str]]) -> str | None:
    """A note naming the folders under ``<root>/*/sequences/`` that are not run because they have no
    ``images/`` (and are not synthesised), else None."""
    skipped = sorted(str(p) for p in Path(dataset_root).glob("*/sequences/*")
                     if p.is_dir() and not (p / "images").exists() and (p.parent.parent.name, p.name) not in synthetic)
    if not skipped:
        return None
    more = f" and {len(skipped) - 5} more" if len(skipped) > 5 else ""
    return f"skipping {', '.join(skipped[:5])}{more}: no images/ folder (not a sequence)"


def synth_note(dataset_root: str | Path, synthetic: set[tuple[str, str]]) -> str | None:
    """A note when demo sequences will be synthesised next to a user's own sequences (a config file
    that sets ``dataset_root`` keeps ``config/config.yaml``'s ``synth.sequences``), else None."""
    own = discover_sequences(dataset_root) - set(synthetic)
    if own and synthetic:
        names = ", ".join(f"{a}/{b}" for a, b in sorted(synthetic))
        return (f"synthesising {names} into {dataset_root} beside its own sequences (synth.sequences); "
                "set `synth: {sequences: []}` to run only yours")
    return None
