"""Metrics table of the report: the metrics of one sequence (rows = stage / variant) as a PNG
table figure, an RST table (Snakemake report captions) or Markdown.

Values use the display units of :func:`vid2haircut.evaluate.aggregate.format_value` (Chamfer pts
in m², Chamfer angle in radians, F1 as fractions); runs without ground truth show ``n/a``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from vid2haircut.evaluate.aggregate import (MAIN_METRICS, collect_metrics, format_value, markdown_table,
                                            metric_title)
from vid2haircut.io.atomic import write_image, write_text
from vid2haircut.report.common import figure_rgb, trim_white

__all__ = ["table_cells", "rst_table", "metrics_table_rst", "metrics_table_image", "write_metrics_table"]


def table_cells(df: pd.DataFrame, metrics: Sequence[str] = MAIN_METRICS) -> tuple[list[str], list[list[str]]]:
    """Header and display strings of a per-run frame (:func:`~vid2haircut.evaluate.aggregate.collect_metrics`).

    The label columns shown are ``stage, variant``, preceded by ``subject, seq`` when the frame
    holds more than one sequence.
    """
    several = df[["subject", "seq"]].drop_duplicates().shape[0] > 1
    labels = ["subject", "seq", "stage", "variant"] if several else ["stage", "variant"]
    header = labels + [metric_title(m) for m in metrics]
    rows = [[str(r[c]) for c in labels] + [format_value(m, r[m] if m in df else np.nan) for m in metrics]
            for _, r in df.iterrows()]
    return header, rows


def rst_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """An RST grid table (docutils renders it in Snakemake captions)."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    sep = "+" + "+".join("-" * (w + 2) for w in widths) + "+"

    def line(cells: Sequence[str]) -> str:
        return "|" + "|".join(f" {str(c):<{w}} " for c, w in zip(cells, widths)) + "|"

    out = [sep, line(header), sep.replace("-", "=")]
    for r in rows:
        out += [line(r), sep]
    if not rows:
        out.append(sep)
    return "\n".join(out) + "\n"


def metrics_table_rst(df: pd.DataFrame, metrics: Sequence[str] = MAIN_METRICS) -> str:
    """RST grid table of the runs in ``df``."""
    return rst_table(*table_cells(df, metrics))


def metrics_table_image(df: pd.DataFrame, title: str = "", metrics: Sequence[str] = MAIN_METRICS,
                        dpi: int = 100) -> np.ndarray:
    """The runs in ``df`` drawn as a table figure -> (H, W, 3) uint8 RGB (header row shaded,
    runs without ground truth in grey, white border trimmed)."""
    from matplotlib.figure import Figure

    header, rows = table_cells(df, metrics)
    n = max(1, len(rows))
    width = 1.2 + 1.15 * len(header)
    fig = Figure(figsize=(width, 0.8 + 0.3 * (n + 1)), dpi=dpi)
    ax = fig.add_axes((0.01, 0.01, 0.98, 0.8))
    ax.axis("off")
    table = ax.table(cellText=rows or [["n/a"] * len(header)], colLabels=header, loc="upper center", cellLoc="center")
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    table.scale(1.0, 1.3)
    has_gt = df["has_ground_truth"].to_numpy(bool)
    for (r, _), cell in table.get_celld().items():
        if r == 0:
            cell.set_facecolor((0.85, 0.88, 0.93))
            cell.set_text_props(weight="bold")
        elif r - 1 < len(has_gt) and not has_gt[r - 1]:
            cell.get_text().set_color((0.45, 0.45, 0.45))
    if title:
        ax.set_title(title, fontsize=9)
    return trim_white(figure_rgb(fig))


def write_metrics_table(out: str | os.PathLike, inputs: Sequence[str | os.PathLike],
                        labels: Sequence[str] | None = None, no_gt: Sequence[str] = (), title: str = "",
                        metrics: Sequence[str] = MAIN_METRICS) -> Path:
    """Read metrics files (see :func:`~vid2haircut.evaluate.aggregate.collect_metrics`) and write
    the table atomically; the format follows ``out``'s suffix: ``.png`` (figure), ``.rst`` or ``.md``."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".png", ".rst", ".md"):
        raise ValueError(f"{out}: metrics table output must end in .png, .rst or .md")
    df = collect_metrics(inputs, labels, no_gt)
    if suffix == ".png":
        write_image(out, metrics_table_image(df, title, metrics))
    elif suffix == ".rst":
        write_text(out, (f"{title}\n{'-' * len(title)}\n\n" if title else "") + metrics_table_rst(df, metrics))
    else:
        write_text(out, (f"## {title}\n\n" if title else "") + markdown_table(*table_cells(df, metrics)))
    return out
