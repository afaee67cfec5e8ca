"""Stage times of a Snakemake run, read from the rules' ``benchmark:`` files.

Every rule of the workflow writes ``benchmarks/rules/<rule>/<wildcards>.tsv`` (Snakemake's benchmark
format: wall seconds ``s``, ``max_rss`` in MB, ``cpu_time`` in seconds, ...). This prints one
Markdown row per file (rule, wildcards, wall s, CPU s, peak RSS) and the total of the fitting
stages (stage1 + stage2), e.g. after ``make demo``:

    .venv/bin/python benchmarks/stage_times.py [--root benchmarks/rules] [--subject synth_0000]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path


def read_benchmark(path: Path) -> dict:
    """The last row of a Snakemake benchmark TSV as a dict of floats (missing fields -> nan)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    if not rows:
        raise ValueError(f"{path}: benchmark file has no data row")
    out = {}
    for key in ("s", "max_rss", "cpu_time", "mean_load"):
        try:
            out[key] = float(rows[-1].get(key, "nan"))
        except ValueError:
            out[key] = float("nan")
    return out


def collect(root: Path, subject: str | None = None) -> list[tuple[str, str, dict]]:
    """(rule, wildcards, record) for every ``<root>/<rule>/**/*.tsv``, sorted by rule then path."""
    rows = []
    for path in sorted(root.glob("*/**/*.tsv")):
        rel = path.relative_to(root)
        rule, wild = rel.parts[0], str(Path(*rel.parts[1:]).with_suffix(""))
        if subject and subject not in wild and rule not in ("head_export", "aggregate", "train_prior"):
            continue
        rows.append((rule, wild, read_benchmark(path)))
    return rows


def table(rows: list[tuple[str, str, dict]]) -> str:
    lines = ["| rule | wildcards | wall s | CPU s | peak RSS MB |", "|---|---|---:|---:|---:|"]
    for rule, wild, r in rows:
        lines.append(f"| {rule} | {wild} | {r['s']:.1f} | {r['cpu_time']:.1f} | {r['max_rss']:.0f} |")
    fit = sum(r["s"] for rule, _, r in rows if rule in ("stage1", "stage2"))
    lines.append(f"\nstage1 + stage2 wall time: {fit:.1f} s")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default="benchmarks/rules", help="folder holding the rules' benchmark files")
    ap.add_argument("--subject", default=None, help="only files whose wildcards name this subject")
    args = ap.parse_args(argv)
    rows = collect(Path(args.root), args.subject)
    if not rows:
        raise SystemExit(f"{args.root}: no benchmark files (run the workflow first)")
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
