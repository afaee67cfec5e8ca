"""Sequence-folder reader (vid2haircut.io.sequence) on hand-made folders: data, video, errors."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from vid2haircut.camera import Camera, intrinsics_from_fov, look_at, save_cameras
from vid2haircut.io.atomic import write_image, write_npz
from vid2haircut.io.sequence import (frame_path, open_sequence, write_depth, write_landmarks, write_mask,
                                     write_tracking)

W, H = 40, 32


def _camera(z: float = 0.7) -> Camera:
    return Camera(intrinsics_from_fov(W, H, 30.0), look_at(np.array([0.0, 0.0, z]), np.zeros(3)), W, H)


def _frame(t: int) -> np.ndarray:
    img = np.zeros((H, W, 3), np.uint8)
    img[..., 0] = 10 * t
    img[..., 1] = np.arange(W)[None, :] * 3
    img[..., 2] = 200
    return img


@pytest.fixture()
def dataset(tmp_path: Path) -> Path:
    """<root>/subj/ with two calibrated cameras; only camera 'b2' has images (PNG, 3 frames)."""
    save_cameras(tmp_path / "subj" / "calibration" / "camera_params.json", {"b2": _camera(0.7), "c3": _camera(0.9)})
    seq = tmp_path / "subj" / "sequences" / "SEQ"
    for t in range(3):
        write_image(frame_path(seq, "images", "b2", t, "png"), _frame(t))
        write_mask(seq, "alpha_maps", "b2", t, np.full((H, W), 0.5))
    return tmp_path


def test_reads_frames_masks_and_defaults(dataset: Path) -> None:
    seq = open_sequence(dataset, "subj", "SEQ")
    assert seq.serial == "b2"  # first sorted serial that has images
    assert seq.frame_indices == [0, 1, 2] and seq.num_frames == 3
    assert seq.root == dataset / "subj" / "sequences" / "SEQ"
    np.testing.assert_allclose(seq.camera.world_2_cam, _camera(0.7).world_2_cam)
    img = seq.read_image(2)
    assert img.dtype == np.uint8 and img.shape == (H, W, 3)
    np.testing.assert_array_equal(img, _frame(2))  # RGB order preserved through PNG
    alpha = seq.read_alpha(1)
    assert alpha.dtype == np.float32 and alpha.shape == (H, W)
    assert abs(float(alpha.mean()) - 128 / 255) < 1e-6
    # optional parts absent -> None
    assert seq.read_hair_mask(0) is None and seq.read_depth(0) is None
    assert seq.landmarks() is None and seq.tracking() is None
    assert seq.meta() is None and seq.ground_truth_strands_path is None


def test_writers_round_trip(dataset: Path) -> None:
    root = dataset / "subj" / "sequences" / "SEQ"
    rng = np.random.default_rng(0)
    depth = rng.random((H, W)).astype(np.float32)
    valid = depth > 0.3
    write_depth(root, "b2", 1, depth, valid)
    write_mask(root, "hair_masks", "b2", 1, valid.astype(np.float32))
    lmk = rng.random((3, 68, 2)).astype(np.float32) * 30
    write_landmarks(root, "b2", np.arange(3), lmk, np.array([True, False, True]))
    rot, trans = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    write_tracking(root, np.arange(3), rot, trans, 1.5)
    (root / "ground_truth").mkdir()
    (root / "ground_truth" / "meta.json").write_text(json.dumps({"family": "bob"}))
    seq = open_sequence(dataset, "subj", "SEQ", serial="b2")
    d, v = seq.read_depth(1)
    np.testing.assert_array_equal(d, depth)
    np.testing.assert_array_equal(v, valid)
    np.testing.assert_array_equal(seq.read_hair_mask(1), valid.astype(np.float32))
    frames, lm, ok = seq.landmarks()
    np.testing.assert_array_equal(frames, [0, 1, 2])
    np.testing.assert_array_equal(lm, lmk)
    np.testing.assert_array_equal(ok, [True, False, True])
    tr = seq.tracking()
    np.testing.assert_array_equal(tr["rotation"], rot)
    np.testing.assert_array_equal(tr["translation"], trans)
    assert tr["scale"].tolist() == [1.5]
    assert seq.meta() == {"family": "bob"}


def test_video_frames(tmp_path: Path) -> None:
    save_cameras(tmp_path / "s" / "calibration" / "camera_params.json", {"v1": _camera()})
    video = tmp_path / "s" / "sequences" / "Q" / "images" / "cam_v1.mp4"
    video.parent.mkdir(parents=True)
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (W, H))
    if not writer.isOpened():
        pytest.skip("OpenCV cannot write mp4v here")
    colours = [(200, 30, 30), (30, 200, 30), (30, 30, 200), (120, 120, 120)]
    for c in colours:
        writer.write(np.full((H, W, 3), c[::-1], np.uint8))  # BGR
    writer.release()
    seq = open_sequence(tmp_path, "s", "Q")
    assert seq.frame_indices == [0, 1, 2, 3]
    for t in (2, 0, 3, 1):  # random access
        img = seq.read_image(t)
        assert img.shape == (H, W, 3)
        assert np.abs(img.reshape(-1, 3).mean(0) - np.array(colours[t])).max() < 12
    seq.close()


def test_error_missing_calibration(tmp_path: Path) -> None:
    (tmp_path / "subj" / "sequences" / "SEQ" / "images").mkdir(parents=True)
    with pytest.raises(FileNotFoundError, match="camera_params.json"):
        open_sequence(tmp_path, "subj", "SEQ")


def test_error_missing_sequence(dataset: Path) -> None:
    with pytest.raises(FileNotFoundError, match="NOPE"):
        open_sequence(dataset, "subj", "NOPE")


def test_error_serial_not_in_calibration(dataset: Path) -> None:
    with pytest.raises(ValueError, match=r"camera_params\.json.*'zz9'"):
        open_sequence(dataset, "subj", "SEQ", serial="zz9")


def test_error_serial_without_images(dataset: Path) -> None:
    with pytest.raises(FileNotFoundError, match="cam_c3"):
        open_sequence(dataset, "subj", "SEQ", serial="c3")


def test_error_unreadable_video(tmp_path: Path) -> None:
    save_cameras(tmp_path / "s" / "calibration" / "camera_params.json", {"v1": _camera()})
    video = tmp_path / "s" / "sequences" / "Q" / "images" / "cam_v1.mp4"
    video.parent.mkdir(parents=True)
    video.write_bytes(b"this is not a video" * 10)
    with pytest.raises(ValueError, match=r"cam_v1\.mp4.*unreadable video"):
        open_sequence(tmp_path, "s", "Q")
    assert video.read_bytes().startswith(b"this is not")  # nothing destroyed


def test_error_mismatched_image_size(dataset: Path) -> None:
    root = dataset / "subj" / "sequences" / "SEQ"
    write_image(frame_path(root, "images", "b2", 1, "png"), np.zeros((H + 2, W, 3), np.uint8))
    write_mask(root, "hair_masks", "b2", 0, np.zeros((H, W + 4)))
    seq = open_sequence(dataset, "subj", "SEQ")
    seq.read_image(0)
    with pytest.raises(ValueError, match=r"frame_00001\.png.*40x34.*40x32"):
        seq.read_image(1)
    with pytest.raises(ValueError, match=r"hair_masks.*frame_00000\.png"):
        seq.read_hair_mask(0)
    with pytest.raises(FileNotFoundError, match="frame_00007"):
        seq.read_image(7)


def test_error_bad_npz_names_file(dataset: Path) -> None:
    root = dataset / "subj" / "sequences" / "SEQ"
    bad = root / "landmarks" / "cam_b2.npz"
    bad.parent.mkdir(parents=True)
    bad.write_bytes(b"PK\x03\x04 truncated")
    seq = open_sequence(dataset, "subj", "SEQ")
    with pytest.raises(ValueError, match=r"cam_b2\.npz.*not a readable"):
        seq.landmarks()
    write_npz(bad, frames=np.arange(3), lmk68=np.zeros((3, 5, 2)))
    with pytest.raises(ValueError, match=r"cam_b2\.npz.*lmk68"):
        seq.landmarks()
    write_npz(root / "tracking" / "head_tracking.npz", frames=np.arange(2), rotation=np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"head_tracking\.npz.*translation"):
        seq.tracking()
    rot = np.zeros((2, 3))
    rot[1, 2] = np.nan
    write_npz(root / "tracking" / "head_tracking.npz", frames=np.arange(2), rotation=rot, translation=np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"head_tracking\.npz: 'rotation' has non-finite"):
        seq.tracking()
    for scale in ([0.0], [1.0, 1.0, 1.0]):
        write_npz(root / "tracking" / "head_tracking.npz", frames=np.arange(2), rotation=np.zeros((2, 3)),
                  translation=np.zeros((2, 3)), scale=np.array(scale))
        with pytest.raises(ValueError, match=r"head_tracking\.npz: 'scale' must be one positive number"):
            seq.tracking()


def test_error_frames_and_values_of_npz_files(dataset: Path) -> None:
    """Frame numbers must be whole, distinct numbers; values numeric; translations metres."""
    root = dataset / "subj" / "sequences" / "SEQ"
    seq = open_sequence(dataset, "subj", "SEQ")
    lmk = root / "landmarks" / "cam_b2.npz"
    for frames, message in [(np.array([0.0, 1.6, 2.0]), r"'frames' must hold whole frame numbers, got \[1.6\]"),
                            (np.array([0, 1, 1]), r"'frames' lists frames \[1\] more than once"),
                            (np.array([0, -1, 2]), r"'frames' has negative frame numbers \[-1\]"),
                            (np.array(["a", "b", "c"]), "'frames' must hold frame numbers")]:
        write_npz(lmk, frames=frames, lmk68=np.zeros((3, 68, 2)))
        with pytest.raises(ValueError, match=rf"cam_b2\.npz: {message}"):
            seq.landmarks()
    write_npz(lmk, frames=np.arange(3), lmk68=np.full((3, 68, 2), "x"))
    with pytest.raises(ValueError, match=r"cam_b2\.npz: 'lmk68' must be numeric"):
        seq.landmarks()
    trk = root / "tracking" / "head_tracking.npz"
    write_npz(trk, frames=np.array([0.0, 0.5]), rotation=np.zeros((2, 3)), translation=np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"head_tracking\.npz: 'frames' must hold whole frame numbers"):
        seq.tracking()
    write_npz(trk, frames=np.arange(2), rotation=np.zeros((2, 3)), translation=np.full((2, 3), 1e9))
    with pytest.raises(ValueError, match=r"head_tracking\.npz: 'translation' is in metres"):
        seq.tracking()
    write_npz(trk, frames=np.arange(2), rotation=np.zeros((2, 3)), translation=np.zeros((2, 3)),
              scale=np.array(["x"]))
    with pytest.raises(ValueError, match=r"head_tracking\.npz: 'scale' must be numeric"):
        seq.tracking()


def test_error_landmark_file_of_other_frames(dataset: Path) -> None:
    from vid2haircut.front.landmarks import sequence_landmarks

    root = dataset / "subj" / "sequences" / "SEQ"
    write_landmarks(root, "b2", np.arange(100, 103), np.zeros((3, 68, 2)), np.ones(3, bool))
    seq = open_sequence(dataset, "subj", "SEQ")
    with pytest.raises(ValueError, match=r"cam_b2\.npz: none of the 3 frames asked for \(0\.\.2\) is in the "
                                         r"landmark file \(its frames: 100\.\.102\)"):
        sequence_landmarks(seq)
    assert sequence_landmarks(seq, [0, 101]).valid.tolist() == [False, True]


def test_error_masks_written_as_0_1(dataset: Path) -> None:
    root = dataset / "subj" / "sequences" / "SEQ"
    m = np.zeros((H, W), np.uint8)
    m[4:9, 5:20] = 1
    write_image(frame_path(root, "hair_masks", "b2", 0, "png"), m)
    write_image(frame_path(root, "alpha_maps", "b2", 1, "png"), m)
    seq = open_sequence(dataset, "subj", "SEQ")
    with pytest.raises(ValueError, match=r"hair_masks.*frame_00000\.png: values are only 0 and 1, but hair masks"):
        seq.read_hair_mask(0)
    with pytest.raises(ValueError, match=r"alpha_maps.*frame_00001\.png: values are only 0 and 1"):
        seq.read_alpha(1)
    write_image(frame_path(root, "hair_masks", "b2", 0, "png"), m * 255)
    assert seq.read_hair_mask(0).max() == 1.0
    write_image(frame_path(root, "hair_masks", "b2", 0, "png"), m * 0)  # an empty mask stays valid
    assert seq.read_hair_mask(0).max() == 0.0
    noise = np.zeros((H, W), np.uint8)
    noise[3, 4] = 1  # one pixel of compression noise in an empty mask
    write_image(frame_path(root, "hair_masks", "b2", 0, "png"), noise)
    assert seq.read_hair_mask(0).max() == 1 / 255
