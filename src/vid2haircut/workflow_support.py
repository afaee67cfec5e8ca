"""Logic behind `workflow/rules/common.smk`: sequence discovery and selection (testable without Snakemake)."""

from __future__ import annotations

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
    missing = [f"{a}/{b}" for a, b in chosen if (a, b) not in known]
    if missing:
        raise ValueError(f"config 'sequences' names {missing}, found neither under {dataset_root} "
                         "nor in synth.sequences")
    return sorted(set(chosen))


def bundled_prior_dir() -> Path:
    """Folder of the prior committed with the package (codec.npz, prior.pt, prior.json)."""
    return Path(__file__).resolve().parent / "data" / "prior" / "default"
