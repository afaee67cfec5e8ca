"""Head pose fitting (robust PnP + joint shape/pose refinement) against ground-truth tracking."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vid2haircut.geometry import axis_angle_to_matrix, make_transform, rotation_angle_deg

SUBJECT, SEQ = "synth_pose", "HAIR"


@pytest.fixture(scope="module")
def synth_root(tmp_path_factory):
    """16 frames at 512 px (landmark noise 1 px, the generator's default); few strands: only the
    landmarks, the tracking and the images for the overlay matter here."""
    from vid2haircut.synth.sequence import SynthConfig, synthesize_sequence

    root = tmp_path_factory.mktemp("pose")
    cfg = SynthConfig(family="short_straight", seed=3, n_frames=16, width=512, height=512, n_strands=300,
                      n_points=16, image_format="png")
    synthesize_sequence(root, SUBJECT, SEQ, cfg)
    return root


@pytest.fixture(scope="module")
def truth(synth_root):
    from vid2haircut.io.sequence import open_sequence

    seq = open_sequence(synth_root, SUBJECT, SEQ)
    tr = seq.tracking()
    poses = make_transform(axis_angle_to_matrix(tr["rotation"]), tr["translation"])
    return seq, {int(t): p for t, p in zip(tr["frames"], poses)}


def _errors(fit, poses):
    rot = np.array([rotation_angle_deg(fit.world_from_head[i][:3, :3], poses[int(t)][:3, :3])
                    for i, t in enumerate(fit.frames)])
    trans = np.array([np.linalg.norm(fit.world_from_head[i][:3, 3] - poses[int(t)][:3, 3])
                      for i, t in enumerate(fit.frames)])
    return rot, trans


def test_fit_head_stage_accuracy(synth_root, truth, tmp_path):
    from vid2haircut.front.headfile import load_head_fit
    from vid2haircut.front.keyframes import KeyframeConfig
    from vid2haircut.front.stages import run_fit_head, run_keyframes

    _, poses = truth
    sel = run_keyframes(synth_root, SUBJECT, SEQ, tmp_path / "kf", cfg=KeyframeConfig(num_keyframes=6))
    fit = run_fit_head(synth_root, SUBJECT, SEQ, tmp_path / "kf" / "keyframes.json", tmp_path / "head")
    assert fit.frames.tolist() == sel.frames
    rot, trans = _errors(fit, poses)
    print("rotation error deg", np.round(rot, 2), "translation error mm", np.round(trans * 1000, 2))
    assert rot.max() < 2.0, rot
    assert trans.max() < 0.005, trans
    assert np.all(fit.reprojection_error_px < 2.5)  # 1 px noise -> ~1.25 px mean error
    assert np.allclose(fit.shape, 1.0, atol=0.03)
    # the file round-trips
    back, extra = load_head_fit(tmp_path / "head" / "head.npz")
    assert extra["source"] == "landmarks" and extra["serial"] == "222200037"
    np.testing.assert_allclose(back.world_from_head, fit.world_from_head)
    assert (tmp_path / "head" / "head_overlay.png").stat().st_size > 1000
    # deterministic
    fit2 = run_fit_head(synth_root, SUBJECT, SEQ, tmp_path / "kf" / "keyframes.json", tmp_path / "head2")
    assert (tmp_path / "head" / "head.npz").read_bytes() == (tmp_path / "head2" / "head.npz").read_bytes()
    del fit2
    # keyframes the sequence does not have: an error naming the keyframes file, before any work
    bad = tmp_path / "kf_bad.json"
    d = json.loads((tmp_path / "kf" / "keyframes.json").read_text())
    d["frames"] = d["frames"] + [999]
    bad.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=r"kf_bad\.json: keyframes \[999\] are not in the sequence"):
        run_fit_head(synth_root, SUBJECT, SEQ, bad, tmp_path / "head3")
    assert not (tmp_path / "head3" / "head.npz").exists()


def test_frames_numbered_from_100(synth_root, tmp_path):
    """A sequence whose frame files start at frame_00100 (a cut from a longer video): keyframes,
    head fit and targets work on its own frame numbers."""
    import shutil

    from vid2haircut.front.keyframes import KeyframeConfig
    from vid2haircut.front.stages import run_fit_head, run_keyframes, run_targets
    from vid2haircut.io.atomic import write_npz

    src = synth_root / SUBJECT
    dst = tmp_path / SUBJECT
    shutil.copytree(src / "calibration", dst / "calibration")
    for kind in ("images", "alpha_maps", "hair_masks", "depth_maps"):
        for f in sorted((src / "sequences" / SEQ / kind).glob("cam_*/frame_*.*")):
            t = int(f.stem.split("_")[1])
            out = dst / "sequences" / SEQ / kind / f.parent.name / f"frame_{t + 100:05d}{f.suffix}"
            out.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(f, out)
    for f in (src / "sequences" / SEQ / "landmarks").glob("cam_*.npz"):
        with np.load(f) as z:
            d = {k: z[k] for k in z.files}
        d["frames"] = d["frames"] + 100
        write_npz(dst / "sequences" / SEQ / "landmarks" / f.name, **d)
    sel = run_keyframes(tmp_path, SUBJECT, SEQ, tmp_path / "kf", cfg=KeyframeConfig(num_keyframes=4))
    assert min(sel.frames) >= 100
    fit = run_fit_head(tmp_path, SUBJECT, SEQ, tmp_path / "kf" / "keyframes.json", tmp_path / "head")
    assert fit.frames.tolist() == sel.frames and np.all(fit.reprojection_error_px < 2.5)
    summary = run_targets(tmp_path, SUBJECT, SEQ, tmp_path / "head" / "head.npz", tmp_path / "targets")
    assert sorted(int(p.stem.split("_")[1]) for p in (tmp_path / "targets").glob("frame_*.npz")) == sel.frames
    assert summary


def test_all_frames_with_smoothness(truth):
    """Consecutive frames get the temporal term; every frame stays within the error bounds."""
    from vid2haircut.front.headfile import base_landmarks
    from vid2haircut.front.pose import fit_head_poses

    seq, poses = truth
    frames, lmk, valid = seq.landmarks()
    fit = fit_head_poses(base_landmarks("proxy-v1"), lmk, valid, frames, seq.camera)
    rot, trans = _errors(fit, poses)
    assert len(fit.frames) == len(frames)
    assert rot.max() < 2.0 and trans.max() < 0.005


def test_noise_free_recovery_and_outliers(truth):
    from vid2haircut.front.headfile import base_landmarks
    from vid2haircut.front.pose import fit_head_poses, project_landmarks

    seq, poses = truth
    pts = base_landmarks("proxy-v1")
    frames = np.array([0, 4, 9])
    T = np.stack([poses[int(t)] for t in frames])
    uv = project_landmarks(seq.camera, T, pts)
    fit = fit_head_poses(pts, uv, np.ones(3, bool), frames, seq.camera)
    rot, trans = _errors(fit, poses)
    assert rot.max() < 0.05 and trans.max() < 2e-4
    # gross outliers on 8 landmarks per frame are rejected by RANSAC + the robust loss
    bad = uv.copy()
    rng = np.random.default_rng(0)
    for i in range(3):
        idx = rng.choice(68, 8, replace=False)
        bad[i, idx] += rng.uniform(30, 60, (8, 2))
    fit = fit_head_poses(pts, bad, np.ones(3, bool), frames, seq.camera)
    rot, trans = _errors(fit, poses)
    assert rot.max() < 0.5 and trans.max() < 0.002
    assert fit.inliers.sum(axis=1).min() <= 62


def test_use_tracking(synth_root, truth, tmp_path):
    from vid2haircut.front.stages import run_fit_head

    _, poses = truth
    kf = tmp_path / "keyframes.json"
    kf.write_text(json.dumps({"frames": [0, 5, 11], "reference": 0, "serial": "222200037"}))
    fit = run_fit_head(synth_root, SUBJECT, SEQ, kf, tmp_path / "head", use_tracking=True)
    rot, trans = _errors(fit, poses)
    assert rot.max() < 1e-6 and trans.max() < 1e-9
    assert np.all(fit.reprojection_error_px < 3.0)  # landmarks with 1 px noise vs the true pose
    with np.load(tmp_path / "head" / "head.npz") as z:
        assert str(z["source"]) == "tracking"


def test_bad_inputs(synth_root, tmp_path):
    from vid2haircut.front.stages import run_fit_head

    kf = tmp_path / "keyframes.json"
    kf.write_text(json.dumps({"frames": [0], "reference": 3, "serial": "222200037"}))
    with pytest.raises(ValueError, match="keyframes.json: 'reference' 3 must be one of"):
        run_fit_head(synth_root, SUBJECT, SEQ, kf, tmp_path / "head")
    with pytest.raises(FileNotFoundError, match="missing.json: keyframes file not found"):
        run_fit_head(synth_root, SUBJECT, SEQ, tmp_path / "missing.json", tmp_path / "head")
    kf.write_text(json.dumps({"frames": [0], "reference": 0, "serial": "123"}))
    with pytest.raises(ValueError, match="camera serial '123' not in the calibration"):
        run_fit_head(synth_root, SUBJECT, SEQ, kf, tmp_path / "head")
    kf.write_text(json.dumps({"frames": [0], "reference": 0, "serial": "222200037"}))
    with pytest.raises(FileNotFoundError, match="nope.pkl: FLAME model file not found"):
        run_fit_head(synth_root, SUBJECT, SEQ, kf, tmp_path / "head", head_model=str(tmp_path / "nope.pkl"))
    with pytest.raises(ValueError, match="unknown head model 'proxy-v9'"):
        run_fit_head(synth_root, SUBJECT, SEQ, kf, tmp_path / "head", head_model="proxy-v9")
    assert not (tmp_path / "head").exists()
