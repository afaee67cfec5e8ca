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
    with pytest.raises(ValueError, match="s1/B, but .*B has no images/"):
        select_sequences(tmp_path, set(), ["s1/B"])
    with pytest.raises(ValueError, match=r"\['s1/C'\], found neither"):
        select_sequences(tmp_path, set(), ["s1/C"])
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


def _base_config(root) -> dict:
    import yaml

    cfg = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    cfg["dataset_root"] = str(root)
    return cfg


def test_check_config_names_the_key(tmp_path):
    """What the schema cannot say is refused when the config is read, naming the key (a job's
    outputs are deleted when it starts, so a value only the command refuses would cost them)."""
    from vid2haircut.workflow_support import check_config

    check_config(_base_config(tmp_path))
    cases = [
        (("fit", "stage1"), {"iteration": 100}, r"fit\.stage1: settings: unknown key 'iteration'"),
        (("fit", "stage2"), {"lr_z": -1}, r"fit\.stage2: settings: 'lr_z' must be in"),
        (("variants",), {"full": {}, "mine": {"weights": {"depth": float("nan")}}}, r"variants\.mine\.weights\.depth: not a finite"),
        (("variants",), {"full": {}, "k10": {"n_keyframes": 10}}, r"variants\.k10 \(over fit\.stage2\): n_keyframes 10 is more"),
        (("variants",), {"full": False}, "every variant is set to false"),
        (("device",), "gpu", "config: device: "),
        (("synth", "sequences"), [{"subject": "a", "seq": "b", "family": "wavvy", "seed": 1}], "unknown family 'wavvy'"),
        (("head", "model"), str(tmp_path / "missing.pkl"), "head.model: .*missing.pkl: neither a built-in head"),
        (("sequences",), [], r"sequences: \[\] lists no sequence"),
    ]
    for keys, value, message in cases:
        cfg = _base_config(tmp_path)
        node = cfg
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value
        with pytest.raises(ValueError, match=message):
            check_config(cfg)
    cfg = _base_config(tmp_path)
    cfg["device"], cfg["fit"]["stage2"] = "cuda", {"render": {"compositing": "exact"}}
    with pytest.raises(ValueError, match=r"fit\.stage2: render\.compositing 'exact' runs on the CPU only"):
        check_config(cfg)
    pkl = tmp_path / "flame.pkl"
    pkl.write_bytes(b"x")
    cfg = _base_config(tmp_path)
    cfg["head"]["model"] = str(pkl)
    with pytest.raises(ValueError, match="set head.landmark_embedding"):
        check_config(cfg)
    cfg = _base_config(tmp_path / "afile")
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ValueError, match="dataset_root: .*afile is a file"):
        check_config(cfg)
    real = tmp_path / "synth_0000" / "sequences" / "HAIR"
    (real / "images").mkdir(parents=True)
    with pytest.raises(ValueError, match="synth.sequences names synth_0000/HAIR, but .* did not write"):
        check_config(_base_config(tmp_path))
    # a synthesis that was interrupted before meta.json: its marker says the folder is the synthesiser's
    from vid2haircut.synth.sequence import SYNTH_MARKER

    (real / SYNTH_MARKER).write_text("x")
    check_config(_base_config(tmp_path))


def test_config_check_imports_no_torch(tmp_path):
    """The Snakefile checks the config every time Snakemake reads it (dry runs included): the check
    must not import torch, which took ~1.5 s of the ~3.5 s a dry run of the default config took."""
    code = ("import json, sys; from vid2haircut.workflow_support import check_config; "
            "check_config(json.loads(sys.argv[1])); print(sorted({'torch', 'numba', 'cv2', 'trimesh'} & set(sys.modules)))")
    cfg = json.dumps(_base_config(tmp_path))
    out = subprocess.run([sys.executable, "-c", code, cfg], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_variant_settings_merge_key_by_key():
    from vid2haircut.workflow_support import active_variants, variant_settings

    merged = variant_settings({"switches": {"use_smoothness": False}, "weights.depth": 0.5},
                              {"switches": {"use_deformation": False}})
    assert merged == {"switches.use_smoothness": False, "switches.use_deformation": False, "weights.depth": 0.5}
    assert active_variants({"full": False, "mine": None, "b": {"x": 1}}) == {"mine": {}, "b": {"x": 1}}


def test_dry_run_quotes_paths_and_leaves_real_sequences_alone(tmp_path):
    """A dataset folder with a space, a subject with regex characters, a real sequence with ground
    truth but no synthesiser record: every path quoted in the commands, no synthesize job."""
    import yaml

    from vid2haircut.camera import intrinsics_from_fov, look_at, Camera, save_cameras
    from vid2haircut.io.atomic import write_image
    from vid2haircut.io.sequence import frame_path
    from vid2haircut.io.strand_formats import save_strands
    from vid2haircut.strands import StrandSet

    root = tmp_path / "user data"
    seq = root / "subj(1)" / "sequences" / "S1"
    cam = Camera(intrinsics_from_fov(64, 64, 30.0), look_at(np.array([0.0, 0.0, 0.7]), np.zeros(3)), 64, 64)
    save_cameras(root / "subj(1)" / "calibration" / "camera_params.json", {"c1": cam})
    write_image(frame_path(seq, "images", "c1", 0, "png"), np.zeros((64, 64, 3), np.uint8))
    save_strands(seq / "ground_truth" / "strands.npz", StrandSet(np.ones((2, 4, 3), np.float32)))
    cfg = _base_config(root)
    cfg["synth"]["sequences"] = []
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    cmd = [sys.executable, "-m", "snakemake", "-n", "-p", "--cores", "1", "-s", str(REPO / "workflow" / "Snakefile"),
           "--configfile", str(tmp_path / "c.yaml"), "--directory", str(tmp_path / "work")]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert f"--root '{root}' --subject 'subj(1)' --seq S1" in out
    assert "rule synthesize" not in out and "rule evaluate" in out


def test_schema_refuses_unknown_top_level_keys(tmp_path):
    from snakemake.utils import validate

    schema = str(REPO / "workflow" / "schemas" / "config.schema.yaml")
    cfg = _base_config(tmp_path)
    cfg["camera"] = 220700191  # NeRSemble serials are numbers: read as their digits
    validate(cfg, schema)
    cfg["datset_root"] = "typo"
    with pytest.raises(Exception, match="datset_root"):
        validate(cfg, schema)


def test_synth_note_when_the_demo_joins_own_sequences(tmp_path):
    from vid2haircut.workflow_support import skipped_note, synth_note

    assert synth_note(tmp_path, {("synth_0000", "HAIR")}) is None
    (tmp_path / "mine" / "sequences" / "A" / "images").mkdir(parents=True)
    assert "synthesising synth_0000/HAIR into" in synth_note(tmp_path, {("synth_0000", "HAIR")})
    assert synth_note(tmp_path, set()) is None
    (tmp_path / "mine" / "sequences" / "B").mkdir()
    (tmp_path / "synth_0000" / "sequences" / "HAIR").mkdir(parents=True)  # made by the synthesize rule later
    assert skipped_note(tmp_path, {("synth_0000", "HAIR")}) == (
        f"skipping {tmp_path / 'mine' / 'sequences' / 'B'}: no images/ folder (not a sequence)")


def test_schema_errors_are_one_line_each(tmp_path):
    from vid2haircut.workflow_support import schema_errors

    schema = REPO / "workflow" / "schemas" / "config.schema.yaml"
    cfg = _base_config(tmp_path)
    assert schema_errors(cfg, schema) == []
    cfg["keyframes"]["n_keyframes"] = 0
    cfg["seed"] = "1"
    cfg["datset_root"] = "x"
    errors = schema_errors(cfg, schema)
    assert errors[0].startswith("(top level): Additional properties are not allowed ('datset_root'")
    assert "keyframes.n_keyframes: 0 is less than the minimum of 1" in errors
    assert "seed: '1' is not of type 'integer'" in errors
    assert all("\n" not in e for e in errors)
