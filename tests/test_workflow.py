"""End-to-end: the whole Snakemake chain on the tiny `.test/config.yaml`, in a scratch folder."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vid2haircut.workflow_support import select_sequences

sys.path.insert(0, str(Path(__file__).parent))
from bench_loader import load_benchmark  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def _snakemake(workdir: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", "--cores", "2", "-s", str(REPO / "workflow" / "Snakefile"),
           "--configfile", str(REPO / ".test" / "config.yaml"), "--directory", str(workdir), *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def workflow_run(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("wf")
    proc = _snakemake(workdir)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    return workdir


def test_synthesize_rule_writes_a_sequence(workflow_run):
    seq = workflow_run / "resources/test_data/synth_t000/sequences/HAIR"
    meta = json.loads((seq / "ground_truth/meta.json").read_text())
    assert meta["family"] == "short_straight"
    gt = np.load(seq / "ground_truth/strands.npz")
    assert gt["points"].shape == (400, 24, 3)
    assert len(list((seq / "images").rglob("frame_*"))) == 8
    assert (workflow_run / "logs/synthesize/synth_t000/HAIR.log").exists()
    assert (workflow_run / "benchmarks/rules/synthesize/synth_t000/HAIR.tsv").exists()
    assert (workflow_run / "resources/head/proxy-v1/head.obj").exists()


def test_front_stages_write_their_artifacts(workflow_run):
    res = workflow_run / "results"
    kf = json.loads((res / "keyframes/synth_t000/HAIR/keyframes.json").read_text())
    assert len(kf["frames"]) == 3 and kf["reference"] in kf["frames"]
    head = np.load(res / "fit_head/synth_t000/HAIR/head.npz")
    assert head["world_from_head"].shape == (3, 4, 4)
    assert np.all(head["reprojection_error_px"] < 5.0)
    for t in kf["frames"]:
        tg = np.load(res / f"targets/synth_t000/HAIR/frame_{t:05d}.npz")
        assert tg["mask"].shape == (96, 96) and tg["mask"].max() > 0


def test_fitting_evaluation_and_summary(workflow_run):
    import pandas as pd

    res = workflow_run / "results"
    for path in ("stage1/synth_t000/HAIR/strands.npz", "stage1/synth_t000/HAIR/prior_strands.npz",
                 "stage2/synth_t000/HAIR/full/strands.npz", "stage2/synth_t000/HAIR/no_deformation/strands.npz",
                 "figures/synth_t000/HAIR/coverage.png", "figures/synth_t000/HAIR/full/turntable.png"):
        assert (res / path).stat().st_size > 0, path
    strands = np.load(res / "stage2/synth_t000/HAIR/full/strands.npz")
    assert strands["points"].ndim == 3 and strands["points"].shape[2] == 3
    df = pd.read_csv(res / "summary/metrics.csv")
    runs = {("prior", "single_view"), ("stage1", "single_view"), ("stage2", "full"), ("stage2", "no_deformation")}
    sequences = {("synth_t000", "HAIR"), ("synth_t001", "HAIR"), ("synth_t002", "FREE")}
    assert set(zip(df["subject"], df["seq"], df["stage"], df["variant"])) == {s + r for s in sequences for r in runs}
    assert len(df) == 12
    assert np.isfinite(df["chamfer_pts"]).all() and (df["chamfer_pts"] > 0).all()
    assert (workflow_run / "resources/prior/tiny/prior.json").exists()


def test_report_html(workflow_run):
    proc = _snakemake(workflow_run, "--report", "report.html")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    html = (workflow_run / "report.html").read_text(errors="replace")
    assert "turntable" in html and "coverage" in html and "metrics.csv" in html


def test_second_run_has_nothing_to_do(workflow_run):
    proc = _snakemake(workflow_run, "-n")
    assert proc.returncode == 0
    assert "Nothing to be done" in proc.stdout + proc.stderr


def test_lint_has_no_findings_beyond_environments():
    proc = subprocess.run([sys.executable, "-m", "snakemake", "--lint", "-s", str(REPO / "workflow" / "Snakefile")],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    findings = [ln.strip() for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip().startswith("* ")]
    assert all("conda environment or container" in f for f in findings), findings


def test_select_sequences(tmp_path):
    (tmp_path / "s1/sequences/A/images").mkdir(parents=True)
    (tmp_path / "s1/sequences/B").mkdir(parents=True)  # no images/: not a sequence
    assert select_sequences(tmp_path, {("syn", "X")}, None) == [("s1", "A"), ("syn", "X")]
    assert select_sequences(tmp_path, set(), ["s1/A"]) == [("s1", "A")]
    with pytest.raises(ValueError, match="s1/B"):
        select_sequences(tmp_path, set(), ["s1/B"])
    with pytest.raises(ValueError, match="subject/SEQ"):
        select_sequences(tmp_path, set(), ["nosl"])


def test_stage_times_reads_the_benchmark_files(workflow_run):
    """benchmarks/stage_times.py turns the run's Snakemake benchmark files into the README table."""
    stage_times = load_benchmark("stage_times")
    rows = stage_times.collect(workflow_run / "benchmarks" / "rules", "synth_t000")
    rules = {rule for rule, _, _ in rows}
    assert {"synthesize", "stage1", "stage2", "evaluate"} <= rules
    assert all(r["s"] > 0 for _, _, r in rows)
    text = stage_times.table(rows)
    fit = sum(r["s"] for rule, _, r in rows if rule in ("stage1", "stage2"))
    assert f"stage1 + stage2 wall time: {fit:.1f} s" in text
    assert "| stage2 | synth_t000/HAIR/full |" in text
