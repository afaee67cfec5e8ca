"""Collect many ``metrics.json`` files into one table: ``metrics.csv`` (one row per subject /
sequence / stage / variant) and a Markdown table of the means per stage and variant.

A metrics file is found at ``.../evaluate/{subject}/{seq}/{stage}/{variant}/metrics.json`` (the
labels are read from the last four folders) or given explicit labels
``"subject/seq/stage/variant"``. Runs without ground truth appear as rows whose metric cells are
empty (NaN): either their metrics file holds no metric keys (e.g. ``{"ground_truth": null}``), or
they are listed as ``no_gt`` labels with no file at all.

Example:
    >>> from vid2haircut.evaluate.aggregate import parse_label
    >>> parse_label("synth_0000/HAIR/stage2/default")
    RunLabel(subject='synth_0000', seq='HAIR', stage='stage2', variant='default')
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Iterable, NamedTuple, Sequence

import numpy as np
import pandas as pd

from vid2haircut.io.atomic import write_text

__all__ = ["LABEL_COLUMNS", "MAIN_METRICS", "RunLabel", "label_from_path", "parse_label", "read_metrics",
           "collect_metrics", "means_table", "means_markdown", "markdown_table", "format_value", "metric_title",
           "aggregate_metrics"]

LABEL_COLUMNS: tuple[str, ...] = ("subject", "seq", "stage", "variant")
#: metric columns of the summary tables, in display order (the paper's Table 1 plus F1).
MAIN_METRICS: tuple[str, ...] = ("chamfer_pts", "chamfer_angle", "f1_2mm_20deg", "f1_3mm_30deg", "f1_4mm_40deg")
#: evaluation settings stored in metrics.json: kept in the CSV, never averaged or shown.
SETTING_KEYS: frozenset[str] = frozenset({"points_per_strand", "max_points", "seed"})
_TITLES = {"chamfer_pts": "Chamfer pts (m²)", "chamfer_angle": "Chamfer angle (rad)"}


class RunLabel(NamedTuple):
    """Identity of one evaluated run (one row of ``metrics.csv``)."""

    subject: str
    seq: str
    stage: str
    variant: str


def parse_label(text: str) -> RunLabel:
    """``"subject/seq/stage/variant"`` -> :class:`RunLabel` (ValueError names the bad label)."""
    parts = str(text).strip().split("/")
    if len(parts) != 4 or not all(parts):
        raise ValueError(f"label {text!r} must have the form subject/seq/stage/variant")
    return RunLabel(*parts)


def label_from_path(path: str | os.PathLike) -> RunLabel:
    """Labels from the layout ``.../{subject}/{seq}/{stage}/{variant}/metrics.json``."""
    parts = Path(path).parts
    if len(parts) < 5:
        raise ValueError(f"{path}: cannot read subject/seq/stage/variant from the path; expected "
                         ".../{subject}/{seq}/{stage}/{variant}/metrics.json, or pass labels explicitly")
    return RunLabel(*parts[-5:-1])


def read_metrics(path: str | os.PathLike) -> dict[str, float]:
    """Numeric scalar entries of one metrics JSON object (``null`` -> NaN; strings and lists dropped).

    Raises FileNotFoundError / ValueError naming the file (also when it holds neither ``chamfer_pts``
    nor ``ground_truth``, or a ``chamfer_pts`` that is not a number or null).
    """
    path = Path(path)
    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: metrics file not found") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(record, dict):
        raise ValueError(f"{path}: expected a JSON object of metrics, got {type(record).__name__}")
    if "chamfer_pts" not in record and "ground_truth" not in record:
        raise ValueError(f"{path}: not a metrics file of `vid2haircut evaluate` (neither 'chamfer_pts' nor "
                         "'ground_truth')")
    cp = record.get("chamfer_pts")
    if isinstance(cp, bool) or not (cp is None or isinstance(cp, (int, float))):
        raise ValueError(f"{path}: 'chamfer_pts' must be a number (or null), got {cp!r:.40}")
    out: dict[str, float] = {}
    for key, val in record.items():
        if isinstance(val, bool):
            continue
        if isinstance(val, (int, float)):
            out[str(key)] = float(val)
        elif val is None and key != "ground_truth":
            out[str(key)] = math.nan
    return out


def _column_order(columns: Iterable[str]) -> list[str]:
    """Main metrics first, then the other metrics (sorted), then the evaluation settings."""
    cols = set(columns)
    main = [c for c in MAIN_METRICS if c in cols]
    rest = sorted(c for c in cols if c not in MAIN_METRICS and c not in SETTING_KEYS)
    return main + rest + sorted(c for c in cols if c in SETTING_KEYS)


def collect_metrics(inputs: Sequence[str | os.PathLike], labels: Sequence[str | RunLabel] | None = None,
                    no_gt: Sequence[str | RunLabel] = ()) -> pd.DataFrame:
    """Read metrics files into one frame.

    Args:
        inputs: metrics JSON paths (any order).
        labels: one ``"subject/seq/stage/variant"`` (or :class:`RunLabel`) per input; None reads
            them from the paths (:func:`label_from_path`).
        no_gt: labels of runs without ground truth and without a metrics file (rows with NaNs).

    Returns:
        DataFrame, one row per run sorted by the labels: columns ``subject, seq, stage, variant,
        has_ground_truth`` (bool, True when the file holds ``chamfer_pts``), then the metric
        columns (:data:`MAIN_METRICS` first), float, NaN where a run has no value.
    """
    if labels is not None and len(labels) != len(inputs):
        raise ValueError(f"got {len(labels)} labels for {len(inputs)} metrics files; give one label per file")
    rows: dict[RunLabel, dict[str, float]] = {}
    where: dict[RunLabel, str] = {}
    runs = [(label_from_path(p) if labels is None else _as_label(labels[i]), str(p), read_metrics(p))
            for i, p in enumerate(inputs)]
    runs += [(_as_label(lab), "--no-gt", {}) for lab in no_gt]
    for label, src, record in runs:
        if label in rows:
            raise ValueError(f"run {'/'.join(label)} appears twice ({where[label]} and {src})")
        rows[label], where[label] = record, src
    if not rows:
        raise ValueError("no metrics files (and no runs without ground truth) to aggregate")
    metric_cols = _column_order({k for r in rows.values() for k in r})
    table = {c: [] for c in (*LABEL_COLUMNS, "has_ground_truth", *metric_cols)}
    for label in sorted(rows):
        record = rows[label]
        for c, v in zip(LABEL_COLUMNS, label):
            table[c].append(v)
        table["has_ground_truth"].append(bool(np.isfinite(record.get("chamfer_pts", math.nan))))
        for c in metric_cols:
            table[c].append(record.get(c, math.nan))
    df = pd.DataFrame(table)
    for c in metric_cols:
        df[c] = df[c].astype(np.float64)
    return df


def _as_label(x: str | RunLabel) -> RunLabel:
    return x if isinstance(x, RunLabel) else parse_label(x)


def means_table(df: pd.DataFrame, metrics: Sequence[str] = MAIN_METRICS) -> pd.DataFrame:
    """Means per stage and variant over the runs that have ground truth.

    Args:
        df: the frame of :func:`collect_metrics`.
        metrics: metric columns to average (missing ones come out as NaN).

    Returns:
        DataFrame with columns ``stage, variant, sequences`` (runs in the group), ``with_gt`` (runs
        with ground truth, i.e. averaged), then one column per metric; sorted by stage, variant.
    """
    out = []
    for (stage, variant), g in df.groupby(["stage", "variant"], sort=True):
        gt = g[g["has_ground_truth"]]
        row = {"stage": stage, "variant": variant, "sequences": int(len(g)), "with_gt": int(len(gt))}
        for m in metrics:
            vals = gt[m].to_numpy(np.float64) if m in gt else np.array([])
            vals = vals[np.isfinite(vals)]
            row[m] = float(vals.mean()) if len(vals) else math.nan
        out.append(row)
    return pd.DataFrame(out, columns=["stage", "variant", "sequences", "with_gt", *metrics])


def format_value(metric: str, value: float) -> str:
    """Display string of one metric value in the paper's units: ``chamfer_pts`` in m² with 6
    decimals, angles in radians with 4, fractions with 3; ``n/a`` for NaN."""
    if value is None or not np.isfinite(value):
        return "n/a"
    if metric.startswith("chamfer_pts"):
        return f"{value:.6f}"
    if metric.startswith("chamfer_angle"):
        return f"{value:.4f}"
    if metric.split("_")[0] in ("precision", "recall", "f1"):
        return f"{value:.3f}"
    return f"{value:g}"


def metric_title(metric: str) -> str:
    """Column title: ``f1_2mm_20deg`` -> ``F1 2mm/20°``, ``chamfer_pts`` -> ``Chamfer pts (m²)``."""
    if metric in _TITLES:
        return _TITLES[metric]
    head, _, tag = metric.partition("_")
    if head in ("precision", "recall", "f1") and tag.endswith("deg"):
        dist, _, ang = tag.partition("_")
        name = {"f1": "F1", "precision": "Precision", "recall": "Recall"}[head]
        return f"{name} {dist}/{ang[:-3]}°"
    return metric


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A GitHub-flavoured Markdown table (first columns left-aligned text, numbers right-aligned)."""
    numeric = [all(_is_number(r[j]) for r in rows) and bool(rows) for j in range(len(header))]
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join("---:" if n else ":---" for n in numeric) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _is_number(s: str) -> bool:
    if s == "n/a":
        return True
    try:
        float(s)
    except ValueError:
        return False
    return True


def means_markdown(means: pd.DataFrame, metrics: Sequence[str] = MAIN_METRICS) -> str:
    """Markdown of :func:`means_table`'s frame with a short heading."""
    header = ["stage", "variant", "sequences", "with GT", *(metric_title(m) for m in metrics)]
    rows = [[str(r["stage"]), str(r["variant"]), str(r["sequences"]), str(r["with_gt"]),
             *(format_value(m, r[m]) for m in metrics)] for _, r in means.iterrows()]
    note = ("Means over the sequences with ground truth, per stage and variant "
            "(Chamfer pts in squared metres, Chamfer angle in radians, F1 of oriented points).\n\n")
    return "# Reconstruction metrics\n\n" + note + markdown_table(header, rows)


def aggregate_metrics(inputs: Sequence[str | os.PathLike], out_csv: str | os.PathLike,
                      out_md: str | os.PathLike | None = None, labels: Sequence[str] | None = None,
                      no_gt: Sequence[str] = (), metrics: Sequence[str] = MAIN_METRICS) -> pd.DataFrame:
    """Collect metrics files (:func:`collect_metrics`), write ``out_csv`` (every row and column;
    empty cells for missing values) and ``out_md`` (means per stage/variant), both atomically.

    Returns the per-run frame.
    """
    df = collect_metrics(inputs, labels, no_gt)
    write_text(out_csv, df.to_csv(index=False, lineterminator="\n"))
    if out_md is not None:
        write_text(out_md, means_markdown(means_table(df, metrics), metrics))
    return df
