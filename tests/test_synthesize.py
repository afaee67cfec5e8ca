"""Synthetic sequences (vid2haircut.synth.sequence / motion / photo): files, geometry, determinism."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vid2haircut.camera import Camera, look_at
from vid2haircut.geometry import axis_angle_to_matrix, make_transform
from vid2haircut.io.sequence import open_sequence
from vid2haircut.synth.motion import MotionParams, moved_strands, sway_points
from vid2haircut.synth.photo import PhotoStyle, render_photo
from vid2haircut.synth.photo_raster import rasterize_mesh
from vid2haircut.synth.sequence import SynthConfig, synthesize_sequence

CFG = SynthConfig(family="shoulder_straight", seed=3, n_frames=6, width=96, height=96, n_strands=500, n_points=24,
                  landmark_noise_px=0.0, image_format="png", save_frame_points=True)
SERIAL = CFG.serial


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[Path, Path]:
    """The same tiny sequence written twice into two dataset roots."""
    roots = []
    for name in ("a", "b"):
        root = tmp_path_factory.mktemp(name)
        synthesize_sequence(root, "synth_0001", "HAIR", CFG, workers=2 if name == "a" else 1)
        roots.append(root)
    return roots[0], roots[1]


@pytest.fixture(scope="module")
def seq(runs):
    return open_sequence(runs[0], "synth_0001", "HAIR")


@pytest.fixture(scope="module")
def head():
    from vid2haircut.head import get_head

    return get_head("proxy-v1")


def test_every_spec_file_exists_with_shapes(seq) -> None:
    root = seq.root
    assert (root.parent.parent / "calibration" / "camera_params.json").is_file()
    from vid2haircut.synth.sequence import SYNTH_MARKER

    assert (root / SYNTH_MARKER).is_file()  # the workflow knows the folder as the synthesiser's
    assert seq.serial == SERIAL and seq.frame_indices == list(range(6))
    assert (seq.camera.width, seq.camera.height) == (96, 96)
    for t in range(6):
        for rel in (f"images/cam_{SERIAL}/frame_{t:05d}.png", f"alpha_maps/cam_{SERIAL}/frame_{t:05d}.png",
                    f"hair_masks/cam_{SERIAL}/frame_{t:05d}.png", f"depth_maps/cam_{SERIAL}/frame_{t:05d}.npz"):
            assert (root / rel).is_file(), rel
        assert seq.read_image(t).shape == (96, 96, 3)
        assert seq.read_alpha(t).shape == (96, 96) and seq.read_hair_mask(t).shape == (96, 96)
        assert seq.read_depth(t)[0].shape == (96, 96)
    frames, lmk, valid = seq.landmarks()
    assert frames.tolist() == list(range(6)) and lmk.shape == (6, 68, 2) and valid.all()
    tr = seq.tracking()
    assert tr["rotation"].shape == (6, 3) and tr["translation"].shape == (6, 3) and tr["scale"].shape == (1,)
    with np.load(seq.ground_truth_strands_path) as z:
        assert z["points"].shape == (500, 24, 3) and z["points"].dtype == np.float32
        assert str(z["head_model"]) == "proxy-v1"
        assert z["frame_points_00003"].shape == (500, 24, 3)
    meta = seq.meta()
    assert meta["family"] == "shoulder_straight" and meta["seed"] == 3 and meta["n_frames"] == 6
    assert meta["image_size"] == [96, 96] and meta["motion"]["yaw_max_deg"] == 60.0
    assert meta["head"]["model"] == "proxy-v1" and "software_version" in meta


def test_head_turns_and_images_show_hair(seq) -> None:
    yaw = np.degrees(np.linalg.norm(seq.tracking()["rotation"], axis=1))
    assert yaw[0] < 1e-6 and yaw.max() > 45.0
    first, side = seq.read_image(0).astype(float), seq.read_image(1).astype(float)
    assert np.abs(first - side).mean() > 3.0  # the view changes
    hair = seq.read_hair_mask(0)
    alpha = seq.read_alpha(0)
    assert 0.03 < hair.mean() < 0.6 and alpha.mean() > hair.mean()
    img = seq.read_image(0).astype(float)
    # background is a smooth grey gradient; hair (dark brown palettes or not) differs from it
    bg = img[alpha == 0]
    assert bg.size and np.abs(img[hair > 0.9].mean(0) - bg.mean(0)).max() > 10


def test_landmarks_match_projected_head_landmarks(seq, head) -> None:
    frames, lmk, _ = seq.landmarks()
    tr = seq.tracking()
    for i, t in enumerate(frames):
        pose = make_transform(axis_angle_to_matrix(tr["rotation"][i]), tr["translation"][i])
        world = head.landmarks.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
        uv, z = seq.camera.project(world)
        assert (z > 0).all()
        np.testing.assert_allclose(lmk[i], uv, atol=1e-3)


def test_cli_writes_noisy_landmarks_and_refuses_to_overwrite(tmp_path: Path) -> None:
    from vid2haircut.cli import main
    from vid2haircut.head import get_head

    args = ["synthesize", "--root", str(tmp_path), "--subject", "s", "--seq", "N", "--family", "bob",
            "--seed", "1", "--frames", "2", "--size", "64", "--strands", "50", "--points", "8",
            "--landmark-noise", "2.0"]
    assert main(args) == 0
    noisy = open_sequence(tmp_path, "s", "N")
    assert noisy.meta()["family"] == "bob" and noisy.meta()["landmark_noise_px"] == 2.0
    assert (noisy.root / "images" / f"cam_{SERIAL}" / "frame_00001.jpg").is_file()  # jpg by default
    _, lmk, _ = noisy.landmarks()
    tr = noisy.tracking()
    pose = make_transform(axis_angle_to_matrix(tr["rotation"][1]), tr["translation"][1])
    uv, _ = noisy.camera.project(get_head().landmarks.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3])
    assert 1.0 < (lmk[1] - uv).std() < 3.0
    with np.load(noisy.ground_truth_strands_path) as z:
        assert not any(k.startswith("frame_points_") for k in z.files)  # off unless asked
    before = (noisy.root / "ground_truth" / "meta.json").read_bytes()
    assert main(args) == 2  # exists: refused, nothing touched
    assert (noisy.root / "ground_truth" / "meta.json").read_bytes() == before
    assert main(["synthesize", "--subject", "s"]) == 2  # --root/--seq missing


def test_hair_mask_inside_alpha_and_depth_normalised(seq) -> None:
    for t in seq.frame_indices:
        alpha, hair = seq.read_alpha(t), seq.read_hair_mask(t)
        assert (hair <= alpha + 1e-6).all()
        depth, valid = seq.read_depth(t)
        assert valid.any() and (hair[valid] >= 0.5 - 1e-6).all()
        d = depth[valid]
        assert d.min() == 0.0 and d.max() == 1.0
        assert (depth[~valid] == 0).all()


def test_determinism_identical_bytes(runs) -> None:
    a, b = runs
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert files_a == files_b and len(files_a) > 20
    for rel in files_a:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel


def test_moved_strands_reproduce_and_sway_bounds(seq, head) -> None:
    from vid2haircut.io.strand_formats import load_strands

    rest = load_strands(seq.ground_truth_strands_path)
    meta = seq.meta()
    with np.load(seq.ground_truth_strands_path) as z:
        stored = {t: z[f"frame_points_{t:05d}"] for t in seq.frame_indices}
    biggest = 0.0
    for t in seq.frame_indices:
        moved = moved_strands(rest, meta, t, head)
        np.testing.assert_array_equal(moved, stored[t])
        off = np.linalg.norm(moved - rest.points, axis=-1)
        assert off[:, 0].max() == 0.0  # roots pinned
        assert off.max() <= CFG.sway_max_m + 1e-6
        assert head.sdf_np(moved).min() > -5e-4
        biggest = max(biggest, float(off.max()))
    assert biggest > 2e-3  # the hair does sway


def test_sway_is_tip_weighted_smooth_and_lags() -> None:
    from vid2haircut.synth.motion import angular_velocity, frame_time

    p = MotionParams(n_frames=48)
    n = 60
    rest = np.zeros((1, n, 3), np.float32)
    rest[0, :, 1] = -np.linspace(0, 0.3, n)  # a 30 cm strand hanging down behind the head
    rest[0, :, 2] = -0.1
    traj = np.stack([sway_points(rest, p, t) for t in range(48)])  # (T, 1, n, 3)
    off = np.linalg.norm(traj - rest, axis=-1)[:, 0]  # (T, n)
    assert off[:, 0].max() == 0 and off.max() <= 0.015 and off[:, -1].max() > 5e-3
    assert off[0, -1] < 1e-4  # (nearly) at rest before the head moves
    assert (np.diff(off.max(0)) >= -1e-7).all()  # grows towards the tip
    assert np.abs(np.diff(traj[:, 0, -1], axis=0)).max() < 0.006  # smooth in time
    # the sway follows the head's angular velocity of a few frames earlier, not the current one
    lever = rest[0, -1] - rest[0, 0]
    s = frame_time(p, np.arange(48))
    now = np.linalg.norm(np.cross(angular_velocity(p, s), lever), axis=-1)
    lagged = np.linalg.norm(np.cross(angular_velocity(p, s - p.sway_lag), lever), axis=-1)
    c_now, c_lag = np.corrcoef(off[:, -1], now)[0, 1], np.corrcoef(off[:, -1], lagged)[0, 1]
    assert c_lag > 0.95 and c_lag > c_now


def test_sway_gain_scales_the_sway_and_is_recorded() -> None:
    from vid2haircut.synth.sequence import SynthConfig

    rest = np.zeros((1, 40, 3), np.float32)
    rest[0, :, 1] = -np.linspace(0, 0.2, 40)
    rest[0, :, 2] = -0.1
    weak, strong = (SynthConfig(sway_gain=g, sway_max_m=1.0).motion() for g in (0.01, 0.02))
    assert strong.sway_gain == 0.02 and strong.to_dict()["sway_gain"] == 0.02
    d = [np.abs(sway_points(rest, m, 12) - rest).max() for m in (weak, strong)]
    assert d[0] > 1e-3 and abs(d[1] / d[0] - 2.0) < 0.05  # far from the soft bound: linear in the gain
    with pytest.raises(ValueError, match="sway_gain"):
        SynthConfig(sway_gain=-1.0).validate()


def test_rasterizer_depth_of_a_sphere() -> None:
    import trimesh

    m = trimesh.creation.icosphere(4, radius=0.1)
    k = np.array([[300.0, 0, 63.5], [0, 300.0, 63.5], [0, 0, 1]])
    cam = Camera(k, look_at(np.array([0, 0, 1.0]), np.zeros(3)), 128, 128)
    uv, z = cam.project(m.vertices)
    frag = rasterize_mesh(np.c_[uv, z], m.faces, 128, 128)
    ys, xs = np.nonzero(frag.face >= 0)
    assert abs(len(ys) - np.pi * (0.1 * 300 / np.sqrt(1 - 0.01)) ** 2) < 0.03 * len(ys)
    rays = np.linalg.inv(k) @ np.stack([xs, ys, np.ones_like(xs)]).astype(float)
    d = rays / np.linalg.norm(rays, axis=0)
    b = d[2] * 1.0
    hit = (b - np.sqrt(np.maximum(b**2 - (1 - 0.01), 0))) * d[2]  # front intersection depth
    assert np.abs(hit - frag.depth[ys, xs]).max() < 2e-3


def test_hair_behind_head_is_hidden_and_nearer_strand_wins(head) -> None:
    k = np.array([[200.0, 0, 31.5], [0, 200.0, 31.5], [0, 0, 1]])
    cam = Camera(k, look_at(np.array([0, 0, 0.7]), np.zeros(3)), 64, 64)
    flat = PhotoStyle(ambient=1.0, spec_primary=0.0, spec_secondary=0.0)
    vertical = np.stack([np.zeros(20), np.linspace(-0.05, 0.05, 20), np.zeros(20)], -1)
    behind = (vertical + [0.0, 0.0, -0.2])[None].astype(np.float32)  # behind the head, seen from the front
    near = (vertical + [0.0, 0.0, 0.25])[None].astype(np.float32)
    pose = np.eye(4)
    bald = render_photo(cam, head, pose, None, None, flat)
    hidden = render_photo(cam, head, pose, behind, np.array([[1.0, 0.0, 0.0]]), flat)
    assert hidden.hair.max() == 0.0 and np.array_equal(hidden.image, bald.image)
    shown = render_photo(cam, head, pose, near, np.array([[1.0, 0.0, 0.0]]), flat)
    assert shown.hair.max() > 0.4 and np.isfinite(shown.hair_depth[shown.hair > 0]).all()
    # crossing strands: the nearer (green, vertical) one colours the crossing, whatever the order
    horizontal = np.stack([np.linspace(-0.05, 0.05, 20), np.zeros(20), np.full(20, 0.2)], -1)
    strands = np.stack([near[0], horizontal]).astype(np.float32)
    cols = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    one_x = PhotoStyle(supersample=1, ambient=1.0, spec_primary=0.0, spec_secondary=0.0)
    for order in ([0, 1], [1, 0]):
        img = render_photo(cam, head, pose, strands[order], cols[order], one_x).image.astype(int)
        assert img[32, 32, 1] > img[32, 32, 2] + 50  # crossing: green
        assert img[32, 20, 2] > img[32, 20, 1] + 50  # elsewhere on the far strand: blue


def test_contact_sheet(tmp_path: Path) -> None:
    import cv2

    from vid2haircut.synth.preview import contact_sheet

    out = contact_sheet(tmp_path / "sheet.png", families=["buzz", "bob"], n_strands=200, n_points=16, size=48)
    img = cv2.imread(str(out))
    assert img.shape == (48, 2 * 2 * 48, 3)
