"""Real-image path of the front stages on skimage's astronaut photo, and clear input errors."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

pytest.importorskip("mediapipe")

from vid2haircut.camera import Camera, intrinsics_from_fov, save_cameras  # noqa: E402
from vid2haircut.io.atomic import write_image  # noqa: E402

# Hand-checked boxes on skimage.data.astronaut() (x0, y0, x1, y1), pixels.
HAIR_TOP_BOX = (190, 25, 270, 60)   # crown of the hair, above the forehead
HAIR_SIDE_BOX = (160, 60, 175, 110)  # hair at the subject's right temple (image left)
FACE_BOX = (205, 110, 245, 150)      # nose and cheeks


def _box(m: np.ndarray, b) -> np.ndarray:
    x0, y0, x1, y1 = b
    return m[y0:y1, x0:x1]


def make_photo_sequence(root, images, serial="0", fov_deg=30.0, seq="PHOTO", subject="astro"):
    """Write a sequence folder with one frame per image and a guessed camera at the origin."""
    h, w = images[0].shape[:2]
    cam = Camera(intrinsics_from_fov(w, h, fov_deg), np.eye(4), w, h)
    save_cameras(root / subject / "calibration" / "camera_params.json", {serial: cam})
    for t, img in enumerate(images):
        write_image(root / subject / "sequences" / seq / "images" / f"cam_{serial}" / f"frame_{t:05d}.png", img)
    return root


@pytest.fixture(scope="module")
def astronaut():
    from skimage import data

    return data.astronaut()


@pytest.fixture(scope="module")
def photo_run(tmp_path_factory, astronaut):
    from vid2haircut.front.keyframes import KeyframeConfig
    from vid2haircut.front.stages import run_fit_head, run_keyframes, run_targets

    root = make_photo_sequence(tmp_path_factory.mktemp("astro"), [astronaut])
    out = tmp_path_factory.mktemp("out")
    run_keyframes(root, "astro", "PHOTO", out / "keyframes", cfg=KeyframeConfig(num_keyframes=1))
    fit = run_fit_head(root, "astro", "PHOTO", out / "keyframes" / "keyframes.json", out / "head")
    run_targets(root, "astro", "PHOTO", out / "head" / "head.npz", out / "targets", depth_source="auto")
    return out, fit


def test_facemesh_table_matches_derivation(astronaut):
    from vid2haircut.front.facemesh_ibug import IBUG68_FROM_FACEMESH, derive_ibug68_indices
    from vid2haircut.front.landmarks import FaceMeshDetector

    with FaceMeshDetector() as det:
        mesh = det.mesh(astronaut)
    assert mesh is not None and mesh.shape == (468, 3)
    assert derive_ibug68_indices(mesh) == IBUG68_FROM_FACEMESH
    assert len(set(IBUG68_FROM_FACEMESH)) == 68


def test_landmarks_semantics(astronaut):
    from vid2haircut.front.landmarks import FaceMeshDetector

    with FaceMeshDetector() as det:
        lmk = det.landmarks68(astronaut)
    assert lmk.shape == (68, 2)
    # image-left first: subject's right eye outer corner (36) left of the left eye outer corner (45)
    assert lmk[36, 0] < lmk[39, 0] < lmk[42, 0] < lmk[45, 0]
    assert lmk[0, 0] < lmk[8, 0] < lmk[16, 0]
    assert lmk[8, 1] > lmk[57, 1] > lmk[51, 1] > lmk[33, 1] > lmk[27, 1]  # chin below mouth below nose
    assert np.all(lmk[17:27, 1] < lmk[36:48, 1].min())  # brows above the eyes
    # the face sits where it is in the photo
    assert 170 < lmk[:, 0].min() and lmk[:, 0].max() < 285 and 75 < lmk[:, 1].min() and lmk[:, 1].max() < 200


def test_photo_pipeline(photo_run, astronaut):
    out, fit = photo_run
    kf = json.loads((out / "keyframes" / "keyframes.json").read_text())
    assert kf["frames"] == [0] and kf["reference"] == 0 and kf["landmark_source"] == "mediapipe"
    assert (out / "keyframes" / "keyframes.png").is_file()
    # face found, pose plausible, small reprojection error for a rigid neutral proxy head
    assert fit.frames.tolist() == [0]
    assert fit.reprojection_error_px[0] < 5.0, fit.reprojection_error_px
    assert (fit.inliers[0].sum()) >= 60
    z = fit.world_from_head[0][2, 3]
    assert 0.5 < z < 3.0
    with np.load(out / "head" / "head.npz") as h:
        assert h["world_from_head"].shape == (1, 4, 4) and str(h["head_model"]) == "proxy-v1"
    assert (out / "head" / "head_overlay.png").is_file()
    # targets: mask covers the hand-checked hair boxes and not the face
    with np.load(out / "targets" / "frame_00000.npz") as t:
        mask, conf, angle = t["mask"], t["confidence"], t["angle"]
        assert t["depth_valid"].sum() == 0  # one frame, no depth maps -> no depth target
        assert str(t["mask_source"]) == "fallback"
    assert mask.shape == astronaut.shape[:2] and mask.dtype == np.float32
    assert _box(mask, HAIR_TOP_BOX).mean() > 0.9
    assert _box(mask, HAIR_SIDE_BOX).mean() > 0.8
    assert _box(mask, FACE_BOX).mean() < 0.05
    assert mask.mean() < 0.1  # not the whole picture
    assert np.all((angle >= 0) & (angle < np.pi))
    assert conf[mask < 0.5].max() == 0.0 and conf[mask >= 0.5].mean() > 0.1
    summary = json.loads((out / "targets" / "targets.json").read_text())
    assert summary["depth_source"] == "none"
    assert (out / "targets" / "orientation_00000.png").is_file()


def test_frame_without_face_is_skipped(tmp_path, astronaut, caplog):
    from vid2haircut.front.keyframes import KeyframeConfig
    from vid2haircut.front.stages import run_fit_head, run_keyframes

    blank = np.full_like(astronaut, 128)
    root = make_photo_sequence(tmp_path / "data", [astronaut, blank])
    with caplog.at_level(logging.WARNING):
        sel = run_keyframes(root, "astro", "PHOTO", tmp_path / "kf", cfg=KeyframeConfig(num_keyframes=2))
    assert sel.frames == [0] and sel.rejected["no_face"] == [1]
    assert any("no face" in r.message for r in caplog.records)
    # a keyframes file naming the faceless frame: skipped with a warning ...
    kf = tmp_path / "kf2" / "keyframes.json"
    kf.parent.mkdir()
    kf.write_text(json.dumps({"frames": [0, 1], "reference": 0, "serial": "0"}))
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        fit = run_fit_head(root, "astro", "PHOTO", kf, tmp_path / "head")
    assert fit.frames.tolist() == [0]
    assert any("frame 1" in r.message and "no face" in r.message for r in caplog.records)
    # ... unless too few remain
    with pytest.raises(ValueError, match="usable face"):
        run_fit_head(root, "astro", "PHOTO", kf, tmp_path / "head2", min_frames=2)
    assert not (tmp_path / "head2" / "head.npz").exists()


def test_no_face_anywhere(tmp_path, astronaut):
    from vid2haircut.front.stages import run_keyframes

    root = make_photo_sequence(tmp_path / "data", [np.full_like(astronaut, 90)])
    with pytest.raises(ValueError, match="no frame .* shows a face"):
        run_keyframes(root, "astro", "PHOTO", tmp_path / "kf")


def test_input_errors(tmp_path, astronaut):
    from vid2haircut.front.stages import run_keyframes

    root = make_photo_sequence(tmp_path / "data", [astronaut])
    # serial not in the calibration
    with pytest.raises(ValueError, match="serial '9' not in the calibration"):
        run_keyframes(root, "astro", "PHOTO", tmp_path / "kf", serial="9")
    # mismatched image size
    write_image(root / "astro" / "sequences" / "PHOTO" / "images" / "cam_0" / "frame_00001.png", astronaut[:256])
    with pytest.raises(ValueError, match=r"frame_00001.png: image size 512x256 does not match"):
        run_keyframes(root, "astro", "PHOTO", tmp_path / "kf")
    # unreadable video
    root2 = make_photo_sequence(tmp_path / "data2", [astronaut], serial="1")
    img_dir = root2 / "astro" / "sequences" / "PHOTO" / "images"
    for p in (img_dir / "cam_1").iterdir():
        p.unlink()
    (img_dir / "cam_1").rmdir()
    (img_dir / "cam_1.mp4").write_bytes(b"this is not a video")
    with pytest.raises(ValueError, match=r"cam_1.mp4: unreadable video"):
        run_keyframes(root2, "astro", "PHOTO", tmp_path / "kf")
    assert not (tmp_path / "kf").exists()


def test_cli_modules(tmp_path, astronaut):
    """The three sub-command modules parse and run (registered on a local parser)."""
    import argparse

    from vid2haircut.cli import fit_head, keyframes, targets

    root = make_photo_sequence(tmp_path / "data", [astronaut])
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command", required=True)
    for mod in (keyframes, fit_head, targets):
        mod.register(sub)
    common = ["--dataset-root", str(root), "--subject", "astro", "--sequence", "PHOTO"]
    out = tmp_path / "res"
    for argv in (["keyframes", *common, "--out", str(out / "kf"), "--num-keyframes", "1"],
                 ["fit_head", *common, "--out", str(out / "head"), "--keyframes", str(out / "kf" / "keyframes.json")],
                 ["targets", *common, "--out", str(out / "tg"), "--head", str(out / "head" / "head.npz"),
                  "--depth-source", "none"]):
        args = parser.parse_args(argv)
        assert args.func(args) == 0
    assert (out / "tg" / "frame_00000.npz").is_file()
