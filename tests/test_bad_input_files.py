"""Bad input files: calibration, keyframes, head fits, targets, landmark embeddings and strand files
give a clear error naming the file and what is wrong."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vid2haircut.camera import load_cameras
from vid2haircut.front.keyframes import load_keyframes

EYE4 = np.eye(4).tolist()
K = [[500.0, 0, 255.5], [0, 500.0, 255.5], [0, 0, 1]]

CAM, KF = "camera_params.json", "keyframes.json"
LOADERS = {CAM: load_cameras, KF: load_keyframes}


def cal(**kw) -> dict:
    """A valid calibration with the entries of ``kw`` replaced."""
    return {"intrinsics": K, "world_2_cam": {"c": EYE4}, "width": 512, "height": 512, **kw}


@pytest.mark.parametrize("name, content, message", [
    (CAM, 5, "expected a JSON object"),
    (CAM, None, "expected a JSON object"),
    (CAM, cal(world_2_cam=[EYE4]), "'world_2_cam' must map"),
    (CAM, cal(width=None), "'width' must be a positive"),
    (CAM, cal(width="big"), "'width' must be a positive"),
    (CAM, cal(height=0), "'height' must be a positive"),
    (CAM, cal(intrinsics="abc"), "'intrinsics' must be a 3x3"),
    (CAM, cal(intrinsics=[[1, 0, 0], [0, "x", 0], [0, 0, 1]]), "'intrinsics' must be a 3x3"),
    (CAM, cal(intrinsics=[[float("nan"), 0, 0], [0, 1, 0], [0, 0, 1]]), "'intrinsics' has non-finite"),
    (CAM, cal(world_2_cam={"c": [[1, 2], [3, 4]]}), r"world_2_cam\['c'\] must be 4x4"),
    (CAM, cal(intrinsics=[[0.0, 0, 255.5], [0, 500.0, 255.5], [0, 0, 1]]), "'intrinsics' must be a pinhole matrix"),
    (CAM, cal(intrinsics=[[-500.0, 0, 255.5], [0, 500.0, 255.5], [0, 0, 1]]), "'intrinsics' must be a pinhole"),
    (CAM, cal(intrinsics=[[500.0, 0, 255.5], [0, 500.0, 255.5], [0, 1, 1]]), "'intrinsics' must be a pinhole"),
    (CAM, cal(world_2_cam={"c": np.zeros((4, 4)).tolist()}), r"world_2_cam\['c'\] must be a rigid transform"),
    (CAM, cal(world_2_cam={"c": (2 * np.eye(4)).tolist()}), r"world_2_cam\['c'\] must be a rigid transform"),
    (CAM, cal(world_2_cam={"c": np.diag([1.0, 1, -1, 1]).tolist()}), r"world_2_cam\[.c.\] must be a rigid"),
    (KF, 5, "expected a JSON object"),
    (KF, {"frames": 5, "reference": 5, "serial": "c"}, "'frames' must be a list of frame numbers"),
    (KF, {"frames": [[1, 2], [3, 4]], "reference": 1, "serial": "c"}, "'frames' must be a list of frame numbers"),
    (KF, {"frames": ["a"], "reference": 1, "serial": "c"}, "'frames' must be a list of frame numbers"),
    (KF, {"frames": [1.5, 2], "reference": 2, "serial": "c"}, "'frames' must be a list of frame numbers"),
    (KF, {"frames": [True, 2], "reference": 2, "serial": "c"}, "'frames' must be a list of frame numbers"),
    (KF, {"frames": [1, 2], "reference": "a", "serial": "c"}, "'reference' 'a' must be one of"),
    (KF, {"frames": [1, 1, 2], "reference": 1, "serial": "c"}, r"'frames' lists frames \[1\] more than once"),
    (KF, {"frames": [1], "reference": 1, "serial": "c", "scores": []}, "'scores' must map frame numbers"),
    (KF, {"frames": [1], "reference": 1, "serial": "c", "scores": {"a": {}}}, "'scores' must map frame numbers"),
    (KF, {"frames": [1], "reference": 1, "serial": "c", "scores": {"1": {"yaw_deg": "x"}}}, "'scores' must map"),
    (KF, {"frames": [1], "reference": 1, "serial": "c", "rejected": [1]}, "'rejected' must map reasons"),
    (KF, {"frames": [1], "reference": 1, "serial": "c", "rejected": {"blur": [0.5]}}, "'rejected' must map"),
    (KF, {"frames": [1], "reference": 1, "serial": "c", "num_frames": "x"}, "'num_frames' must be a whole number"),
])
def test_json_input_errors_name_the_file(tmp_path, name, content, message):
    """Calibration and keyframe files of the wrong types, shapes or values: a ValueError naming the file."""
    path = tmp_path / name
    path.write_text(json.dumps(content))
    with pytest.raises(ValueError, match=f"{name}: {message}"):
        LOADERS[name](path)


def test_calibration_accepts_whole_float_sizes(tmp_path):
    path = tmp_path / CAM
    path.write_text(json.dumps(cal(width=512.0, height=256)))
    cam = load_cameras(path)["c"]
    assert (cam.width, cam.height) == (512, 256)


def test_head_fit_file_checks(tmp_path):
    from vid2haircut.front.headfile import load_head_fit
    from vid2haircut.io.atomic import write_npz

    def head(**kw):
        d = dict(head_model=np.array("proxy-v1"), shape=np.ones(3), frames=np.arange(2),
                 world_from_head=np.repeat(np.eye(4)[None], 2, 0), reprojection_error_px=np.zeros(2))
        d.update(kw)
        write_npz(tmp_path / "head.npz", **d)

    head()
    assert load_head_fit(tmp_path / "head.npz")[0].frames.tolist() == [0, 1]
    poses = np.repeat(np.eye(4)[None], 2, 0)
    poses[1, 0, 3] = np.nan
    for kw, message in [(dict(shape=np.ones(7)), "shape must be 3 positive factors"),
                        (dict(shape=np.array([1.0, 0.0, 1.0])), "shape must be 3 positive factors"),
                        (dict(world_from_head=poses), "'world_from_head' has non-finite"),
                        (dict(world_from_head=np.zeros((2, 4, 4))), r"world_from_head of frames \[0, 1\] is not a rigid"),
                        (dict(world_from_head=np.repeat(2 * np.eye(4)[None], 2, 0)), "world_from_head of frames .* is not a rigid"),
                        (dict(frames=np.arange(0), world_from_head=np.zeros((0, 4, 4)),
                              reprojection_error_px=np.zeros(0)), "no frames"),
                        (dict(frames=np.array([0.0, 1.5])), r"'frames' must hold whole frame numbers, got \[1.5\]"),
                        (dict(frames=np.array(3)), "'frames' must be a 1-D array"),
                        (dict(frames=np.array([4, 4])), r"'frames' lists frames \[4\] more than once"),
                        (dict(head_model=np.array("bogus")), "unknown head model 'bogus'"),
                        (dict(reprojection_error_px=np.zeros(3)), r"'reprojection_error_px' must have shape \(2,\)"),
                        (dict(inliers=np.ones((2, 5), bool)), r"'inliers' must have shape \(2, 68\)"),
                        (dict(landmarks_2d=np.zeros((2, 68))), r"'landmarks_2d' must have shape \(2, 68, 2\)")]:
        head(**kw)
        with pytest.raises(ValueError, match=f"head.npz: {message}"):
            load_head_fit(tmp_path / "head.npz")


def test_landmark_embedding_junk_names_the_file(tmp_path):
    from vid2haircut.head.flame_head import load_landmark_embedding

    bad = tmp_path / "emb.npz"
    bad.write_bytes(b"not a zip file at all")
    with pytest.raises(ValueError, match=r"emb\.npz: not a readable \.npz landmark embedding"):
        load_landmark_embedding(bad)


def test_landmark_embedding_with_the_built_in_head_is_refused():
    from vid2haircut.front.headfile import base_landmarks

    assert base_landmarks("proxy-v1").shape == (68, 3)
    with pytest.raises(ValueError, match=r"emb\.npz: a landmark embedding is for a FLAME model"):
        base_landmarks("proxy-v1", "emb.npz")


def _targets(path, **kw):
    from vid2haircut.io.atomic import write_npz

    hw = (8, 10)
    d = dict(mask=np.zeros(hw, np.float32), angle=np.zeros(hw, np.float32), confidence=np.zeros(hw, np.float32),
             depth=np.full(hw, np.nan, np.float32), depth_valid=np.zeros(hw, bool), frame=np.int64(3),
             mask_source=np.array("hair_masks"))
    d.update(kw)
    write_npz(path, **d)


def test_targets_file_checks(tmp_path):
    """Target arrays of other shapes, non-numeric or non-finite values, a frame not that of the
    file name: a ValueError naming the file and the key (they had surfaced as broadcasting errors
    or a non-finite loss at step 0)."""
    from vid2haircut.front.targets.build import load_targets

    path = tmp_path / "frame_00003.npz"
    _targets(path)
    assert load_targets(path)["mask"].shape == (8, 10)  # NaN depth where depth_valid is False is fine
    bad_depth = np.zeros((8, 10), np.float32)
    bad_depth[2, 2] = np.nan
    valid = np.zeros((8, 10), bool)
    valid[2, 2] = True
    for kw, message in [(dict(mask=np.full((8, 10), np.nan, np.float32)), "'mask' has non-finite"),
                        (dict(mask=np.full((8, 10), 255.0, np.float32)), r"'mask' must lie in \[0, 1\]"),
                        (dict(mask=np.full((8, 10), "a")), "'mask' must be numeric"),
                        (dict(angle=np.zeros((4, 10), np.float32)), r"'angle' must have shape \(8, 10\)"),
                        (dict(depth_valid=np.zeros((8, 4), bool)), r"'depth_valid' must have shape \(8, 10\)"),
                        (dict(depth=bad_depth, depth_valid=valid), "'depth' has non-finite entries where"),
                        (dict(frame=np.int64(4)), "'frame' is 4, not the frame of the file name")]:
        _targets(path, **kw)
        with pytest.raises(ValueError, match=f"frame_00003.npz: {message}"):
            load_targets(path)


def test_targets_of_another_size_than_the_camera_name_both(tmp_path):
    from vid2haircut.fit.data import load_fit_data
    from vid2haircut.io.atomic import write_npz

    (tmp_path / "subj" / "calibration").mkdir(parents=True)
    (tmp_path / "subj" / "calibration" / CAM).write_text(json.dumps(cal()))
    (tmp_path / KF).write_text(json.dumps({"frames": [3], "reference": 3, "serial": "c"}))
    write_npz(tmp_path / "head.npz", head_model=np.array("proxy-v1"), shape=np.ones(3), frames=np.array([3]),
              world_from_head=np.eye(4)[None], reprojection_error_px=np.zeros(1))
    (tmp_path / "targets").mkdir()
    _targets(tmp_path / "targets" / "frame_00003.npz")
    with pytest.raises(ValueError, match=r"frame_00003\.npz: target size \(10, 8\) does not match the camera "
                                         r"\(512x512\) of .*camera_params\.json"):
        load_fit_data(tmp_path, "subj", tmp_path / KF, tmp_path / "head.npz", tmp_path / "targets")


def test_an_empty_strand_file_is_named(tmp_path):
    from vid2haircut.evaluate.metrics import evaluate_files
    from vid2haircut.export.export import export_files
    from vid2haircut.io.strand_formats import save_strands
    from vid2haircut.strands import StrandSet

    empty = save_strands(tmp_path / "empty.npz", StrandSet(points=np.zeros((0, 4, 3), np.float32)))
    full = save_strands(tmp_path / "full.npz", StrandSet(points=np.ones((2, 4, 3), np.float32)))
    with pytest.raises(ValueError, match=r"empty\.npz: the strand file holds no strands"):
        evaluate_files(empty, full, tmp_path / "m.json")
    with pytest.raises(ValueError, match=r"empty\.npz: the strand file holds no strands"):
        export_files(empty, tmp_path / "out")
    assert not (tmp_path / "m.json").exists() and not (tmp_path / "out").exists()


def test_strand_files_with_bad_values_are_named(tmp_path):
    """NaN points in .data, a .hair header claiming more points than the file holds (it had tried
    a 32 GiB allocation), per-strand colours / widths / transparencies of the wrong shape or NaN
    (export had written hair.usda before failing at hair.hair): a ValueError naming the file. Such
    attributes do not stop reading (other tools store per-point colours): only exporting."""
    import struct

    from vid2haircut.export.export import export_files
    from vid2haircut.io.atomic import write_npz
    from vid2haircut.io.strand_formats import load_strands

    data = tmp_path / "nan.data"
    pts = np.ones((2, 3), np.float32)
    pts[1, 0] = np.nan
    data.write_bytes(struct.pack("<i", 1) + struct.pack("<i", 2) + pts.tobytes())
    with pytest.raises(ValueError, match=r"nan\.data: StrandSet: points contain NaN"):
        load_strands(data)
    hair = tmp_path / "big.hair"
    hair.write_bytes(b"HAIR" + struct.pack("<IIIIfff3f", 0xFFFFFFFF, 4, 2, 3, 1e-4, 0, 0, 0, 0, 0) + bytes(88))
    with pytest.raises(ValueError, match=r"big\.hair: malformed: the header says 4294967295 strands"):
        load_strands(hair)
    good = np.zeros((5, 4, 3), np.float32)
    good[:, :, 2] = np.arange(4) * 0.01
    for key, value, message in [("color", np.zeros(5), r"'color' must be numeric of shape \(5, 3\)"),
                                ("color", np.zeros((5, 4)), r"'color' must be numeric of shape \(5, 3\)"),
                                ("width", np.zeros((5, 2)), r"'width' must be numeric of shape \(5,\)"),
                                ("transparency", np.zeros((5, 2)), r"'transparency' must be numeric"),
                                ("color", np.full((5, 3), np.nan), "'color' has NaN")]:
        write_npz(tmp_path / "s.npz", points=good, **{key: value})
        with pytest.raises(ValueError, match=rf"s\.npz: .*{message}"):
            export_files(tmp_path / "s.npz", tmp_path / "out")
        assert not (tmp_path / "out").exists()
        assert load_strands(tmp_path / "s.npz").n_strands == 5
