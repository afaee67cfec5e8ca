"""benchmarks/quality.py variants and its report tables (the fitting itself is covered by the stage tests)."""

import json
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from bench_loader import load_benchmark  # noqa: E402


@pytest.fixture(scope="module")
def quality():
    return load_benchmark("quality")


@pytest.fixture(scope="module")
def quality_data():
    return load_benchmark("quality_data")


@pytest.fixture(scope="module")
def quality_jobs():
    return load_benchmark("quality_jobs")


@pytest.fixture(scope="module")
def quality_report():
    return load_benchmark("quality_report")


def _record(path: Path, sil: float, direc: float, depth: float, total: float) -> None:
    path.mkdir(parents=True)
    rec = {"config": {"weights": {"silhouette": 1.0, "direction": 0.8, "depth": 0.1}},
           "history": {"terms": {"silhouette": [0.5, sil], "direction": [0.5, direc], "depth": [0.5, depth]},
                       "total": [9.0, total]}}
    (path / "stage2.json").write_text(json.dumps(rec))


def test_loss_table_splits_image_terms_and_keeps_one_objective(quality_report, tmp_path):
    seqs = ["a_1", "b_2"]
    for s in seqs:
        _record(tmp_path / "runs" / s / "stage2", 0.1, 0.2, 0.3, 1.0)
        _record(tmp_path / "runs" / s / "stage2_oracle", 0.05, 0.1, 0.2, 2.0)
        _record(tmp_path / "runs" / s / "no_smoothness", 0.0, 0.0, 0.0, 0.0)  # another objective
    _record(tmp_path / "runs" / "a_1" / "no_visibility", 0.0, 0.0, 0.0, 0.0)  # missing for b_2
    text = quality_report.loss_table(tmp_path, seqs, ["stage2", "stage2_oracle", "no_smoothness", "no_visibility"])
    rows = [line for line in text.splitlines() if line.startswith("| ") and "method" not in line]
    assert len(rows) == 2
    # image terms: 1 * 0.1 + 0.8 * 0.2 + 0.1 * 0.3 = 0.29; all terms: the recorded final total
    assert rows[0] == f"| {quality_report.LABELS['stage2']} | 0.2900 / 1.0000 | 0.2900 / 1.0000 | 0.2900 / 1.0000 |"
    assert rows[1].startswith(f"| {quality_report.LABELS['stage2_oracle']} | 0.1500 / 2.0000 |")
    assert quality_report.loss_table(tmp_path, seqs, ["no_smoothness"]) == ""


def test_stage2_oracle_starts_from_the_encoded_ground_truth(quality):
    assert quality.STAGE2_FROM["stage2_oracle"] == "oracle"
    assert quality.STAGE2_VARIANTS["stage2_oracle"] == {}
    assert "stage2_oracle" not in quality.DEFAULT_VARIANTS


def test_region_bound_puts_the_seen_regions_at_the_floor(quality_report):
    def m(front, side, back):
        return {"chamfer_pts_front": front * 1e-4, "chamfer_pts_side": side * 1e-4,
                "chamfer_pts_back": back * 1e-4, "chamfer_pts": (front + side + back) * 1e-4}

    seqs = ["a_1", "b_2"]
    results = {("a_1", "oracle"): m(0.01, 0.02, 0.03), ("b_2", "oracle"): m(0.01, 0.02, 0.05),
               ("a_1", "stage1"): m(0.1, 0.1, 0.1), ("b_2", "stage1"): m(0.1, 0.1, 0.1),
               ("a_1", "stage2"): m(0.05, 0.05, 0.08), ("b_2", "stage2"): m(0.05, 0.05, 0.12)}
    text = quality_report.region_bound(results, seqs)
    # bound = floor front + side (0.03) + fitted back (0.10) = 0.13; Stage 1 0.3 -> at most 2.31x; measured 0.2 -> 1.50x
    assert "would reach 0.130" in text and "at most 2.31x" in text and "measured 0.200, 1.50x" in text
    del results[("b_2", "oracle")]
    assert quality_report.region_bound(results, seqs) == ""


def test_unseen_bound_puts_what_the_keyframes_show_at_the_floor(quality_report):
    def m(total, unseen):
        return {"chamfer_pts": total * 1e-4, "chamfer_pts_unseen": unseen * 1e-4}

    seqs = ["a_1", "b_2"]
    results = {("a_1", "oracle"): m(0.05, 0.02), ("b_2", "oracle"): m(0.03, 0.02),
               ("a_1", "stage1"): m(0.3, 0.1), ("b_2", "stage1"): m(0.3, 0.1),
               ("a_1", "stage2"): m(0.2, 0.08), ("b_2", "stage2"): m(0.2, 0.12)}
    text = quality_report.unseen_bound(results, seqs)
    # bound = floor seen part (0.04 - 0.02 = 0.02) + fitted unseen part (0.10) = 0.12; 0.3 / 0.12 = 2.50x
    assert "would reach 0.1200" in text and "at most 2.50x" in text and "measured 0.2000, 1.50x" in text
    del results[("a_1", "stage2")]["chamfer_pts_unseen"]
    assert quality_report.unseen_bound(results, seqs) == ""


def test_unseen_test_marks_the_back_and_what_leaves_every_frame(quality, tmp_path, monkeypatch):
    import numpy as np
    from vid2haircut.camera import Camera, intrinsics_from_fov, look_at

    cam = Camera(intrinsics_from_fov(64, 64, 30.0), look_at(np.array([0.0, 0.0, 1.0]), np.zeros(3)), 64, 64)

    class Fit:
        world_from_head = np.eye(4)[None]

    monkeypatch.setattr("vid2haircut.front.headfile.load_head_fit", lambda path: (Fit, {"serial": "c0"}))
    monkeypatch.setattr("vid2haircut.camera.load_cameras", lambda path: {"c0": cam})
    test = load_benchmark("quality_score").unseen_test({"head": tmp_path / "head.npz", "root": tmp_path, "subject": "s_1000"})
    pts = np.array([[0.0, 0.0, 0.1],      # in front, in the image
                    [0.0, 0.0, -0.1],     # behind: back region
                    [0.0, -2.0, 0.1],     # in front, far below the image
                    [0.1, 0.0, 0.0]])     # side (azimuth 90), in the image
    assert test(pts).tolist() == [False, True, True, False]


def test_sequence_names_take_any_family_and_an_evaluation_seed(quality_data):
    assert quality_data.parse_sequence("short_straight_1015") == ("short_straight", 1015)
    with pytest.raises(SystemExit, match="training hairstyles"):
        quality_data.parse_sequence("bob_12")
    with pytest.raises(SystemExit, match="expected <family>_<seed>"):
        quality_data.parse_sequence("mullet_1000")


def test_cached_sequences_of_another_capture_are_refused(quality_data, tmp_path):
    seq = quality_data.seq_files(tmp_path, "bob_1000")
    seq["gt"].parent.mkdir(parents=True)
    meta = {"motion": {"sway_gain": 0.03, "yaw_max_deg": 60.0}, "config": {"head_fill": 0.6}}
    seq["gt"].with_name("meta.json").write_text(json.dumps(meta))
    with pytest.raises(SystemExit, match="yaw_max_deg 60.0, not 90.0"):
        quality_data.prepare(tmp_path, "bob", 1000, 48, sway_gain=0.03, yaw_max=90.0)
    with pytest.raises(SystemExit, match="head_fill 0.6, not 0.5"):
        quality_data.prepare(tmp_path, "bob", 1000, 48, sway_gain=0.03, head_fill=0.5)


def test_gap_profile_parts_add_up_and_find_the_tips():
    gap = load_benchmark("gap_profile")
    s = 3
    t = np.linspace(0.0, 1.0, gap.N_POINTS)
    gt = np.concatenate([np.stack([np.full_like(t, 0.01 * k), -0.2 * t, np.zeros_like(t)], 1) for k in range(s)])
    sdf = 0.1 * np.tile(t, s)                                # distance from the head grows along each strand
    total, by_sdf, by_arc = gap.profile(sdf, np.zeros(len(gt)))
    assert total == 0.0 and not any(by_sdf) and not any(by_arc)
    short = gt.reshape(s, gap.N_POINTS, 3)[:, :60].reshape(-1, 3)   # the prediction stops at 60% of each strand
    total, by_sdf, by_arc = gap.profile(sdf, cKDTree(short).query(gt)[0] ** 2)
    assert total > 0.0
    assert np.isclose(sum(by_sdf), total) and np.isclose(sum(by_arc), total)
    assert by_arc[0] == by_arc[1] == 0.0 and by_arc[3] > by_arc[2] > 0.0
    assert by_sdf[-1] == max(by_sdf)                          # the missing ends lie beyond 5 cm


def test_gap_profile_shell_split_finds_hair_that_lies_too_flat():
    gap = load_benchmark("gap_profile")
    rng = np.random.default_rng(0)
    # ground truth: points on a sphere of radius 10 cm around the head centre, all heights and azimuths
    d = rng.normal(size=(4000, 3))
    gt = 0.10 * d / np.linalg.norm(d, axis=1, keepdims=True)
    back = (np.abs(np.degrees(np.arctan2(gt[:, 0], gt[:, 2]))) >= 120.0) & (gt[:, 1] > gap.UPPER_Y_M)
    # the prediction: the same, but the upper back lies 3 mm closer to the head
    pred = np.where(back[:, None], gt * 0.097 / 0.10, gt)
    sdf = np.linalg.norm(gt, axis=1) - 0.09
    dist, j = cKDTree(pred).query(gt)
    parts = gap.shell_split(gt, sdf, dist ** 2, np.linalg.norm(pred[j], axis=1) - 0.09)
    assert len(parts) == 12 and np.isclose(sum(parts), (dist ** 2).mean() * 1e4)
    # order: (front, side, back) x (upper, lower) x (outside, inside); only "back upper outside" is off
    assert parts[8] > 0.0 and parts[8] == max(parts) and sum(parts) - parts[8] < 0.05 * parts[8]


def test_gap_profile_standoff_sees_a_flat_back():
    gap = load_benchmark("gap_profile")
    rng = np.random.default_rng(1)
    d = rng.normal(size=(20000, 3))
    gt = 0.10 * d / np.linalg.norm(d, axis=1, keepdims=True)       # head surface at 9 cm: 10 mm off it
    back = np.abs(np.degrees(np.arctan2(gt[:, 0], gt[:, 2]))) >= 120.0
    flat = np.where(back[:, None], gt * 0.097 / 0.10, gt)           # the back 3 mm closer to the head
    side_gt, p90_gt, back_gt, _ = gap.standoff(gt, np.linalg.norm(gt, axis=1) - 0.09)
    side, _, back_mm, back_p90 = gap.standoff(flat, np.linalg.norm(flat, axis=1) - 0.09)
    assert np.isclose(side_gt, 10.0) and np.isclose(p90_gt, 10.0) and np.isclose(back_gt, 10.0)
    assert np.isclose(side, 10.0) and np.isclose(back_mm, 7.0) and np.isclose(back_p90, 7.0)
    low = gt[:, 1] < gap.UPPER_Y_M                                  # only the hair above the split counts
    assert np.isnan(gap.standoff(gt[low], np.zeros(int(low.sum())))[0])


def test_gap_profile_length_errors_match_strands_by_uv_and_region():
    from vid2haircut.strands import StrandSet

    gap = load_benchmark("gap_profile")
    t = np.linspace(0.0, 1.0, 10)[:, None]
    down = np.array([0.0, -1.0, 0.0])

    def strand(root, length):
        return np.asarray(root) + t * length * down

    # roots: one at the front (+z), one at the back (-z) of the head frame
    gt = np.stack([strand([0.0, 0.1, 0.1], 0.30), strand([0.0, 0.1, -0.1], 0.20)])
    gt_uv = np.array([[0.5, 0.2], [0.5, 0.8]])
    pred = np.stack([strand([0.0, 0.1, -0.1], 0.25), strand([0.0, 0.1, 0.1], 0.26)])   # listed back first
    pred_uv = np.array([[0.5, 0.79], [0.5, 0.21]])
    front, side, back = gap.length_errors(StrandSet(gt, {"uv": gt_uv}), StrandSet(pred, {"uv": pred_uv}))
    assert np.isclose(front, -4.0) and np.isclose(back, 5.0) and np.isnan(side)


def test_gap_profile_projects_tips_into_the_reference_view():
    from vid2haircut.camera import Camera

    gap = load_benchmark("gap_profile")
    K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]])
    cam = Camera(K=K, world_2_cam=np.eye(4), width=100, height=100)
    pose = np.eye(4)
    pose[2, 3] = 1.0                                       # the head 1 m in front of the camera
    mask = np.zeros((100, 100), bool)
    mask[60:, :] = True                                    # hair in the lower part of the image
    tips = np.array([[0.0, 0.2, 0.0], [0.0, 0.3, 0.0], [0.0, 0.1, 0.0], [0.0, 0.9, 0.0]])   # rows 70, 80, 60, 140
    inside, on_mask, row = gap.tip_rows(tips, cam, pose, mask)
    assert inside == 0.75 and on_mask == 1.0 and row == 70.0
    assert gap.tip_rows(tips[3:], cam, pose, mask)[0] == 0.0


def test_redecode_writes_what_the_stage_wrote(tmp_path):
    """benchmarks/redecode.py decodes a fitted run as the stage did (its keyframes, size, seed), so
    with the same settings the strands are bit for bit the stage's, and a new carving setting is
    applied and recorded. benchmarks/stage2_sweep.py, scoring a run of which only the hair map and
    record came back from another machine, decodes the same strands too."""
    import shutil

    from vid2haircut.fit.pipeline import run_stage1, run_stage2
    from vid2haircut.fit.toy import toy_problem, write_toy_files
    from vid2haircut.io.strand_formats import load_strands

    redecode = load_benchmark("redecode")
    name = "toy_1000"
    work = tmp_path / "work"
    files = write_toy_files(toy_problem(size=40, n_frames=3, map_res=12, k=12), work / "data", subject=name)
    (work / "front").mkdir(parents=True)
    shutil.move(str(files["keyframes"].parent), str(work / "front" / name))
    seq = redecode.quality_data.seq_files(work, name)
    common = (seq["root"], name, seq["keyframes"], seq["head"], seq["targets"])
    small = {"render": {"n_points": 16, "size": 40}, "n_dense": 200}
    s1, s2 = work / "runs" / name / "stage1", work / "runs" / name / "stage2"
    run_stage1(*common, s1, codec_path=work / "front" / name / "codec.npz", progress=False,
               settings={**small, "iterations": 2, "map_res": 12})
    run_stage2(*common, s1, s2, progress=False,
               settings={**small, "iterations": 3, "canonical_steps": 1, "ramp_steps": 1})
    same = {"length_spread": 0.04, "tip_scatter": 0.0, "carve_tolerance": 1.0, "carve_min_fraction": 0.5}
    dst = tmp_path / "dst"
    done = redecode.redecode_sequence((str(work), str(dst), name, same, ()))
    assert len(done) == 2
    for run in ("stage1", "stage2"):
        a = load_strands(work / "runs" / name / run / "strands.npz").points
        assert np.array_equal(load_strands(dst / "runs" / name / run / "strands.npz").points, a)
    off = {**same, "carve_tolerance": 0.0}
    redecode.redecode_sequence((str(work), str(tmp_path / "off"), name, off, ("stage2",)))
    rec = json.loads((tmp_path / "off" / "runs" / name / "stage2" / "stage2.json").read_text())
    assert rec["carved_fraction"] == 0.0 and rec["config"]["carve_tolerance"] == 0.0
    assert not (tmp_path / "off" / "runs" / name / "stage1").exists()
    sweep = work / "sweep" / name / "back"
    sweep.mkdir(parents=True)
    for f in load_benchmark("stage2_sweep").KEEP:
        shutil.copy2(s2 / f, sweep / f)
    path = load_benchmark("stage2_sweep").decoded(work, name, "back")
    assert np.array_equal(load_strands(path).points, load_strands(s2 / "strands.npz").points)


def test_length_spread_standoff_deviation_is_per_texel():
    spread = load_benchmark("length_spread")
    # two styles' strands in the same texel, and one texel of style 0 elsewhere: depth at 3 points
    uv = np.array([[0.01, 0.01]] * 4 + [[0.5, 0.5]] * 3)
    style = np.array([0, 0, 0, 1, 0, 0, 0])
    groups = spread.texel_groups(uv, style, 32)                     # style 1's lone strand has no group
    assert sorted(len(g) for g in groups) == [3, 3]
    sdf = np.array([[0.0, 1.0, 2.0], [0.0, 2.0, 4.0], [0.0, 3.0, 9.0], [0.0, 50.0, 50.0],
                    [0.0, 5.0, 5.0], [0.0, 5.0, 7.0], [0.0, 5.0, 3.0]]) * 1e-3
    dev = spread.standoff_deviation(sdf, groups, 2)
    assert sorted(np.round(dev * 1e3, 6)) == [-2.0, -2.0, 0.0, 0.0, 2.0, 5.0]
    assert np.allclose(spread.standoff_deviation(sdf, groups, 0), 0.0)


def test_job_plan_runs_the_starts_first_then_one_job_per_stage2_row(quality):
    plan = quality.job_plan(["a", "b"], ["prior", "stage2", "no_pca", "stage2_ft"])
    assert plan[0] == [("a", ["prior", "stage1_ft", "stage1"]), ("b", ["prior", "stage1_ft", "stage1"])]
    assert plan[1] == [("a", ["stage2"]), ("b", ["stage2"]), ("a", ["no_pca"]), ("b", ["no_pca"]),
                       ("a", ["stage2_ft"]), ("b", ["stage2_ft"])]
    assert quality.job_plan(["a"], ["oracle"]) == [[("a", ["oracle"])]]


def test_jobs_forward_the_options_and_name_the_failed_log(quality_jobs, tmp_path, monkeypatch):
    import subprocess

    calls = []

    def fake_call(argv, stdout, stderr):
        calls.append(argv)
        return 1 if "b" in argv else 0

    monkeypatch.setattr(subprocess, "call", fake_call)
    argv = ["--work", str(tmp_path), "--sway-gain", "0.03", "--jobs", "2", "--threads", "1", "--sequences", "a,b",
            "--stage2-seeds", "0,1", "--variants=stage2", "--settings", '{"stage2": {}}', "--out", "t.md",
            "--depth-context"]
    with pytest.raises(SystemExit, match="b_stage2.log"):
        quality_jobs.run_jobs([[("a", ["stage1"])], [("a", ["stage2"]), ("b", ["stage2"])]], argv, str(tmp_path), 2,
                              "bench.py")
    assert len(calls) == 3 and calls[0][-4:] == ["--sequences", "a", "--variants", "stage1"]
    assert calls[0][:2] == [sys.executable, "bench.py"]
    flags = calls[0][2:-4]
    assert flags == ["--work", str(tmp_path), "--sway-gain", "0.03", "--threads", "1", "--stage2-seeds", "0,1",
                     "--settings", '{"stage2": {}}', "--depth-context"]   # every shared option, no per-job one
    with pytest.raises(SystemExit):        # a failed phase stops the next one
        quality_jobs.run_jobs([[("b", ["stage1"])], [("a", ["stage2"])]], argv, str(tmp_path), 2, "bench.py")
    assert calls[-1][-3] == "b"


def test_mix_components_takes_coarse_and_fine_components_from_two_runs(tmp_path):
    """benchmarks/mix_components.py: components < split from one run, the rest from the other, the
    first run's record; maps of different masks are refused."""
    import torch

    from vid2haircut.fit.outputs import load_hairmap, write_hairmap

    mixer = load_benchmark("mix_components")
    gen = torch.Generator().manual_seed(0)
    mask = (torch.rand(6, 6, generator=gen) > 0.3).float()
    runs = {}
    for s in ("a", "b"):
        d = tmp_path / "sweep" / "seq" / s
        d.mkdir(parents=True)
        runs[s] = torch.randn(8, 6, 6, generator=gen)
        write_hairmap(d / "hairmap.npz", runs[s], mask, "fp", "proxy-v1")
        (d / "stage2.json").write_text(json.dumps({"run": s}))
    out = mixer.mix(tmp_path, "seq", "a", "b", 3, "mix")
    z, m, fp = load_hairmap(out / "hairmap.npz")
    assert torch.equal(z[:3], runs["a"][:3]) and torch.equal(z[3:], runs["b"][3:])
    assert torch.equal(m, mask) and fp == "fp"
    assert json.loads((out / "stage2.json").read_text()) == {"run": "a"}
    write_hairmap(tmp_path / "sweep" / "seq" / "b" / "hairmap.npz", runs["b"], 1.0 - mask, "fp", "proxy-v1")
    with pytest.raises(ValueError, match="masks"):
        mixer.mix(tmp_path, "seq", "a", "b", 3, "mix2")

