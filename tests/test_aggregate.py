"""Aggregation of hand-made metrics.json files into metrics.csv and the Markdown table of means."""

import argparse
import json
import math

import numpy as np
import pandas as pd
import pytest

from vid2haircut.cli import aggregate as cli_aggregate
from vid2haircut.evaluate.aggregate import (RunLabel, collect_metrics, format_value, label_from_path,
                                            means_table, metric_title, parse_label)


def _metrics(cpts, cang, f1):
    return {"chamfer_pts": cpts, "chamfer_angle": cang, "f1_2mm_20deg": f1, "f1_3mm_30deg": f1 + 0.1,
            "f1_4mm_40deg": f1 + 0.2, "precision_2mm_20deg": f1, "recall_2mm_20deg": f1,
            "n_strands_pred": 100, "points_per_strand": 100, "max_points": 200000, "seed": 0,
            "pred_file": "strands.npz", "gt_file": "strands.npz"}


@pytest.fixture()
def tree(tmp_path):
    """results/evaluate/{subject}/{seq}/{stage}/{variant}/metrics.json for 2 subjects x 2 stages,
    a second variant for one run, and one sequence without ground truth (stub file)."""
    root = tmp_path / "results" / "evaluate"
    runs = {
        ("s1", "HAIR", "stage1", "default"): _metrics(4e-4, 0.40, 0.30),
        ("s1", "HAIR", "stage2", "default"): _metrics(1e-4, 0.25, 0.50),
        ("s2", "HAIR", "stage1", "default"): _metrics(2e-4, 0.30, 0.40),
        ("s2", "HAIR", "stage2", "default"): _metrics(3e-4, 0.35, 0.70),
        ("s2", "HAIR", "stage2", "no_prior"): _metrics(9e-4, 0.60, 0.10),
        ("real", "FREE", "stage2", "default"): {"ground_truth": None, "pred_file": "strands.npz"},
    }
    paths = []
    for label, rec in runs.items():
        p = root.joinpath(*label, "metrics.json")
        p.parent.mkdir(parents=True)
        p.write_text(json.dumps(rec))
        paths.append(p)
    return paths[::-1]          # any input order


def test_rows_and_means(tree, tmp_path):
    df = collect_metrics(tree)
    assert list(df.columns[:5]) == ["subject", "seq", "stage", "variant", "has_ground_truth"]
    assert list(df.columns[5:10]) == ["chamfer_pts", "chamfer_angle", "f1_2mm_20deg", "f1_3mm_30deg", "f1_4mm_40deg"]
    assert "pred_file" not in df.columns and list(df.columns[-3:]) == ["max_points", "points_per_strand", "seed"]
    labels = [tuple(r) for r in df[["subject", "seq", "stage", "variant"]].itertuples(index=False)]
    assert labels == sorted(labels) and len(labels) == 6
    no_gt = df[df.subject == "real"].iloc[0]
    assert not no_gt.has_ground_truth and math.isnan(no_gt.chamfer_pts) and math.isnan(no_gt.f1_2mm_20deg)

    means = means_table(df)
    assert [tuple(r) for r in means[["stage", "variant"]].itertuples(index=False)] == [
        ("stage1", "default"), ("stage2", "default"), ("stage2", "no_prior")]
    m = means.set_index(["stage", "variant"])
    assert m.loc[("stage1", "default"), "chamfer_pts"] == pytest.approx(3e-4)
    assert m.loc[("stage2", "default"), "chamfer_pts"] == pytest.approx(2e-4)          # NaN run skipped
    assert m.loc[("stage2", "default"), "f1_4mm_40deg"] == pytest.approx(0.8)
    assert m.loc[("stage2", "default"), "sequences"] == 3 and m.loc[("stage2", "default"), "with_gt"] == 2
    assert m.loc[("stage2", "no_prior"), "chamfer_angle"] == pytest.approx(0.6)


def test_cli_writes_csv_and_markdown(tree, tmp_path):
    parser = argparse.ArgumentParser()
    cli_aggregate.register(parser.add_subparsers(dest="command"))
    out_csv, out_md = tmp_path / "summary" / "metrics.csv", tmp_path / "summary" / "metrics.md"
    args = parser.parse_args(["aggregate", "--inputs", *map(str, tree), "--out-csv", str(out_csv),
                              "--out-md", str(out_md)])
    assert args.func(args) == 0
    csv = pd.read_csv(out_csv)
    assert len(csv) == 6 and csv["chamfer_pts"].isna().sum() == 1
    assert csv.loc[csv.subject == "s1", "chamfer_pts"].tolist() == pytest.approx([4e-4, 1e-4])
    md = out_md.read_text()
    assert "| stage2 | default | 3 | 2 | 0.000200 | 0.3000 | 0.600 | 0.700 | 0.800 |" in md
    assert "| stage2 | no_prior | 1 | 1 | 0.000900 |" in md
    first = out_csv.read_bytes()
    assert args.func(args) == 0 and out_csv.read_bytes() == first                     # deterministic
    assert not list(out_csv.parent.glob(".*"))                                         # no temp files left


def test_explicit_labels_and_runs_without_files(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(_metrics(1e-4, 0.2, 0.5)))
    b.write_text(json.dumps(_metrics(3e-4, 0.4, 0.7)))
    df = collect_metrics([a, b], labels=["x/S/stage2/v1", "y/S/stage2/v1"], no_gt=["z/S/stage2/v1"])
    assert df["subject"].tolist() == ["x", "y", "z"]
    assert df["has_ground_truth"].tolist() == [True, True, False]
    means = means_table(df)
    assert means["chamfer_pts"].iloc[0] == pytest.approx(2e-4) and means["sequences"].iloc[0] == 3


def test_labels_and_errors(tmp_path):
    assert label_from_path("results/evaluate/s/Q/stage1/v/metrics.json") == RunLabel("s", "Q", "stage1", "v")
    with pytest.raises(ValueError, match="subject/seq/stage/variant"):
        parse_label("a/b/c")
    with pytest.raises(ValueError, match="cannot read"):
        label_from_path("x/metrics.json")
    bad = tmp_path / "e" / "s" / "Q" / "st" / "v" / "metrics.json"
    bad.parent.mkdir(parents=True)
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="metrics.json: not valid JSON"):
        collect_metrics([bad])
    with pytest.raises(FileNotFoundError, match="missing.json"):
        collect_metrics([tmp_path / "missing.json"], labels=["a/b/c/d"])
    empty = tmp_path / "empty.json"
    empty.write_text("{}")
    with pytest.raises(ValueError, match="empty.json: not a metrics file"):
        collect_metrics([empty], labels=["a/b/c/d"])
    text = tmp_path / "text.json"
    text.write_text('{"chamfer_pts": "0.1"}')
    with pytest.raises(ValueError, match="text.json: 'chamfer_pts' must be a number"):
        collect_metrics([text], labels=["a/b/c/d"])
    good = tmp_path / "g.json"
    good.write_text('{"ground_truth": null}')
    with pytest.raises(ValueError, match="appears twice"):
        collect_metrics([good, good], labels=["a/b/c/d", "a/b/c/d"])
    with pytest.raises(ValueError, match="one label per file"):
        collect_metrics([good], labels=["a/b/c/d", "a/b/c/e"])


def test_formatting():
    assert format_value("chamfer_pts", 3.3e-5) == "0.000033"
    assert format_value("chamfer_angle", 0.24781) == "0.2478"
    assert format_value("f1_2mm_20deg", np.nan) == "n/a"
    assert metric_title("f1_3mm_30deg") == "F1 3mm/30°"
