"""Keyframe selection: most frontal reference, pose coverage, blur rejection, determinism."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vid2haircut.geometry import axis_angle_to_matrix, make_transform

SUBJECT, SEQ = "synth_kf", "HAIR"


@pytest.fixture(scope="module")
def synth_root(tmp_path_factory):
    from vid2haircut.synth.sequence import SynthConfig, synthesize_sequence

    root = tmp_path_factory.mktemp("kf")
    cfg = SynthConfig(family="bob", seed=1, n_frames=14, width=192, height=192, n_strands=800, n_points=16,
                      image_format="png")
    synthesize_sequence(root, SUBJECT, SEQ, cfg)
    return root


def _true_view(root):
    from vid2haircut.front.pose import view_angles
    from vid2haircut.io.sequence import open_sequence

    seq = open_sequence(root, SUBJECT, SEQ)
    tr = seq.tracking()
    poses = make_transform(axis_angle_to_matrix(tr["rotation"]), tr["translation"])
    return {int(t): view_angles(seq.camera, p) for t, p in zip(tr["frames"], poses)}


def test_keyframes_stage(synth_root, tmp_path):
    from vid2haircut.front.keyframes import KeyframeConfig, load_keyframes
    from vid2haircut.front.stages import run_keyframes

    sel = run_keyframes(synth_root, SUBJECT, SEQ, tmp_path / "a", cfg=KeyframeConfig(num_keyframes=6))
    view = _true_view(synth_root)
    off = {t: v[2] for t, v in view.items()}
    # the reference is a frontal frame (within the 3 degree tolerance), and it is a keyframe
    assert sel.reference in sel.frames and len(sel.frames) == 6 and sel.frames == sorted(sel.frames)
    assert off[sel.reference] <= min(off.values()) + 3.0
    # of the two frontal ends of the turn it is the still start, not the end where the hair still swings
    assert sel.reference < 3
    # the keyframes spread over the head turn: both sides, near the extremes
    yaws = [view[t][0] for t in sel.frames]
    true_max = max(abs(v[0]) for v in view.values())
    assert max(yaws) > 0.8 * true_max and min(yaws) < -0.8 * true_max
    # estimated view angles agree with the truth
    for t, s in sel.scores.items():
        assert abs(s["yaw_deg"] - view[t][0]) < 3.0 and abs(s["pitch_deg"] - view[t][1]) < 3.0
    # files: json round trip, contact sheet, deterministic bytes
    js = json.loads((tmp_path / "a" / "keyframes.json").read_text())
    assert js["frames"] == sel.frames and js["reference"] == sel.reference and js["serial"] == "222200037"
    assert js["landmark_source"] == "file" and len(js["scores"]) == 14
    assert load_keyframes(tmp_path / "a" / "keyframes.json").frames == sel.frames
    assert (tmp_path / "a" / "keyframes.png").stat().st_size > 1000
    run_keyframes(synth_root, SUBJECT, SEQ, tmp_path / "b", cfg=KeyframeConfig(num_keyframes=6))
    assert (tmp_path / "a" / "keyframes.json").read_bytes() == (tmp_path / "b" / "keyframes.json").read_bytes()


def test_m_one_and_more_than_frames(synth_root, tmp_path):
    from vid2haircut.front.keyframes import KeyframeConfig
    from vid2haircut.front.stages import run_keyframes

    one = run_keyframes(synth_root, SUBJECT, SEQ, tmp_path / "one", cfg=KeyframeConfig(num_keyframes=1))
    assert one.frames == [one.reference]
    view = _true_view(synth_root)
    assert view[one.reference][2] <= min(v[2] for v in view.values()) + 3.0
    many = run_keyframes(synth_root, SUBJECT, SEQ, tmp_path / "many", cfg=KeyframeConfig(num_keyframes=40))
    assert len(many.frames) == 14


def test_blurred_frame_rejected(synth_root, tmp_path):
    """A strongly blurred copy of the most lateral frame is not picked; its sharp twin would be."""
    import shutil

    import cv2

    from vid2haircut.front.keyframes import KeyframeConfig
    from vid2haircut.front.stages import run_keyframes

    root = tmp_path / "data"
    shutil.copytree(synth_root, root)
    base = KeyframeConfig(num_keyframes=4)
    sharp = run_keyframes(root, SUBJECT, SEQ, tmp_path / "sharp", cfg=base)
    victim = next(t for t in sharp.frames if t != sharp.reference)
    p = root / SUBJECT / "sequences" / SEQ / "images" / "cam_222200037" / f"frame_{victim:05d}.png"
    img = cv2.imread(str(p))
    cv2.imwrite(str(p), cv2.GaussianBlur(img, (0, 0), 4.0))
    blurred = run_keyframes(root, SUBJECT, SEQ, tmp_path / "blurred", cfg=base)
    assert victim not in blurred.frames and victim in blurred.rejected["blurred"]
    assert blurred.scores[victim]["sharpness"] < 0.35 * np.median([s["sharpness"] for s in blurred.scores.values()])


def test_choose_keyframes_pure():
    from vid2haircut.front.keyframes import choose_keyframes

    frames = np.arange(9)
    yaw = np.array([0, 10, 20, 30, 40, 30, 20, -30, -45], float)
    pitch = np.zeros(9)
    off = np.abs(yaw)
    sharp = np.ones(9)
    chosen, ref, blurred = choose_keyframes(frames, yaw, pitch, off, sharp, 3)
    assert ref == 0 and chosen == [0, 4, 8] and blurred == []
    sharp[4] = 0.1  # the +40 frame is blurred -> the next best spread
    chosen, ref, blurred = choose_keyframes(frames, yaw, pitch, off, sharp, 3)
    assert blurred == [4] and chosen == [0, 3, 8]
    with pytest.raises(ValueError, match=">= 1"):
        choose_keyframes(frames, yaw, pitch, off, sharp, 0)
    with pytest.raises(ValueError, match="no candidate"):
        choose_keyframes(frames[:0], yaw[:0], pitch[:0], off[:0], sharp[:0], 2)


def test_reference_is_the_stillest_frontal_frame():
    """Hair lags the head: of two frontal frames the one after a still stretch is the reference."""
    from vid2haircut.front.keyframes import choose_keyframes, head_speed

    frames = np.arange(12)
    # still and frontal at the start, a turn, then back to frontal at speed (frame 11 the most frontal)
    yaw = np.array([0.5, 0.6, 0.4, 10, 25, 40, 45, 40, 25, 10, 4, 0.0])
    pitch = np.zeros(12)
    off = np.abs(yaw)
    sharp = np.ones(12)
    speed = head_speed(frames, yaw, pitch, 3)
    # frame 0 looks forward to frame 1; frame 2 averages 0 -> 1 -> 2; frame 11 averages 8 -> 11
    assert speed[:3] == pytest.approx([0.1, 0.1, 0.15]) and speed[11] == pytest.approx(25 / 3)
    _, ref, _ = choose_keyframes(frames, yaw, pitch, off, sharp, 3, still_frames=3)
    assert ref == 2                       # still (< 0.5 deg/frame), then the most frontal of 0, 1, 2
    _, ref0, _ = choose_keyframes(frames, yaw, pitch, off, sharp, 3, still_frames=0)
    assert ref0 == 11                     # without the look-back: simply the most frontal frame
    # a still frame outside the frontal tolerance is not taken
    _, ref_tight, _ = choose_keyframes(frames, yaw, pitch, off, sharp, 3, still_frames=3, frontal_tolerance=0.3)
    assert ref_tight == 11
    # thinned candidates: the speed is per frame of the video, not per candidate
    sp = head_speed(np.array([0, 10, 20]), np.array([0.0, 5.0, 5.0]), np.zeros(3), 3)
    assert sp == pytest.approx([0.5, 0.5, 0.0])
