"""Tests of the learned hair prior: network shapes, input crop, tiny training, cache reuse."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from vid2haircut.camera import look_at
from vid2haircut.prior.model import PriorConfig, PriorNet, load_prior, prior_input
from vid2haircut.prior.views import CROP_CENTER, CROP_HALF_EXTENT, crop_affine


def test_forward_shapes_default_and_tiny():
    for cfg in (PriorConfig(), PriorConfig.tiny()):
        net = PriorNet(cfg)
        z, logits = net(torch.zeros(2, cfg.in_channels, cfg.input_size, cfg.input_size))
        assert z.shape == (2, cfg.k, cfg.map_res, cfg.map_res)
        assert logits.shape == (2, cfg.map_res, cfg.map_res)
        assert torch.isfinite(z).all() and torch.isfinite(logits).all()
    # "a few MB of weights"
    assert 0.2e6 < PriorNet(PriorConfig()).n_parameters() < 2.5e6
    with pytest.raises(ValueError, match="expected input"):
        PriorNet(PriorConfig.tiny())(torch.zeros(1, 6, 32, 32))
    with pytest.raises(ValueError):
        PriorConfig(input_size=100)


def _disc_view(distance: float, size: int, shift: tuple[int, int], yaw: float = 0.0):
    """Analytic view of a disc (radius 8 cm) in the plane through the crop centre, facing the camera."""
    f = 0.6 * size * 0.7 / 0.25                         # the synthetic camera's lens, scaled
    K = np.array([[f, 0, size - 0.5 + shift[0]], [0, f, size - 0.5 + shift[1]], [0, 0, 1.0]])
    w2c = look_at(np.array([0.0, 0.0, distance]), np.zeros(3))
    c, s = np.cos(yaw), np.sin(yaw)
    pose = np.eye(4)
    pose[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    pose[:3, 3] = [0.01, -0.02, 0.0]
    centre = (w2c @ pose @ np.r_[np.asarray(CROP_CENTER), 1.0])[:3]
    h, w = 2 * size + 2 * abs(shift[1]), 2 * size + 2 * abs(shift[0])     # the crop fits inside
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    X = (xs - K[0, 2]) / f * centre[2] - centre[0]      # back-projection onto the plane z = centre z
    Y = (ys - K[1, 2]) / f * centre[2] - centre[1]
    r2 = X ** 2 + Y ** 2
    mask = (r2 < 0.08 ** 2).astype(np.float32)
    angle = np.full((h, w), 0.3, np.float32)
    depth = np.clip(r2 / 0.08 ** 2, 0, 1).astype(np.float32)
    return mask, angle, depth, mask > 0, K, w2c, pose


def test_prior_input_same_crop_when_head_shifted_in_image():
    a = _disc_view(0.7, 96, (0, 0))
    b = _disc_view(0.7, 96, (13, -7))                  # the head elsewhere in a larger image
    xa, xb = prior_input(*a, size=64), prior_input(*b, size=64)
    assert xa.shape == (1, 6, 64, 64)
    assert float(xa[0, 0].sum()) > 50
    assert torch.allclose(xa, xb, atol=1e-5)
    assert float(xa[0, 5].min()) == 1.0                # the whole crop lies inside the image
    part = prior_input(*[m[:96, :96] for m in a[:4]], *a[4:], size=64)     # a cut-off image
    assert 0.05 < float(part[0, 5].mean()) < 0.95
    assert float((part[0, 0] * (1 - part[0, 5])).max()) < 0.5     # outside: at most a bilinear border


def test_prior_input_centre_and_scale_invariance():
    near = prior_input(*_disc_view(0.6, 128, (5, 3)), size=64)
    far = prior_input(*_disc_view(0.8, 256, (-20, 9)), size=64)       # other distance and resolution
    m_near, m_far = near[0, 0].numpy(), far[0, 0].numpy()
    assert np.abs(m_near - m_far).mean() < 0.02
    # the disc is centred on the crop and has the expected radius in crop pixels
    ys, xs = np.mgrid[0:64, 0:64]
    cy, cx = (m_near * ys).sum() / m_near.sum(), (m_near * xs).sum() / m_near.sum()
    assert abs(cx - 31.5) < 0.5 and abs(cy - 31.5) < 0.5
    radius_px = np.sqrt(m_near.sum() / np.pi)
    assert abs(radius_px - 0.08 / (2 * CROP_HALF_EXTENT) * 64) < 0.5
    # channels: direction encoded as mask * (cos 2a, sin 2a); depth only where valid
    inside = m_near > 0.5
    assert np.allclose(near[0, 1].numpy()[inside] / m_near[inside], np.cos(0.6), atol=1e-4)
    assert np.allclose(near[0, 2].numpy()[inside] / m_near[inside], np.sin(0.6), atol=1e-4)
    no_depth = prior_input(*_disc_view(0.7, 96, (0, 0))[:3], None, *_disc_view(0.7, 96, (0, 0))[4:], size=64)
    assert float(no_depth[0, 3:5].abs().sum()) == 0.0 and float(no_depth[0, 5].min()) == 1.0


def test_prior_input_bad_input():
    mask, angle, depth, valid, K, w2c, pose = _disc_view(0.7, 64, (0, 0))
    with pytest.raises(ValueError, match="angle"):
        prior_input(mask, angle[:-1], depth, valid, K, w2c, pose)
    behind = look_at(np.array([0.0, 0.0, -0.7]), np.array([0.0, 0.0, -2.0]))
    with pytest.raises(ValueError, match="behind the camera"):
        crop_affine(K, behind, pose, 64)


def test_tiny_training_lowers_loss_and_artifact_is_reused(tmp_path):
    from vid2haircut.prior.train import train_prior

    out = tmp_path / "prior"
    t0 = time.perf_counter()
    res = train_prior(out, "tiny", seed=0, cache_dir=tmp_path / "cache", progress=False, num_threads=1)
    elapsed = time.perf_counter() - t0
    assert not res.reused and elapsed < 60.0
    rec = json.loads((out / "prior.json").read_text())
    assert rec["final_losses"]["total"] < 0.8 * rec["initial_losses"]["total"]
    assert rec["final_losses"]["points_cm"] < rec["initial_losses"]["points_cm"]
    assert rec["seed"] == 0 and rec["corpus"]["n_styles"] == 4 and rec["environment"]["torch"] == torch.__version__
    net, codec, record = load_prior(out)
    assert record["fingerprint"] == rec["fingerprint"] and codec.k == net.cfg.k == 16
    z, logits = net(torch.zeros(1, net.cfg.in_channels, net.cfg.input_size, net.cfg.input_size))
    assert z.shape == (1, 16, 16, 16) and logits.shape == (1, 16, 16)

    # cached: the second call returns without training and touches nothing
    stamps = {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.is_file()}
    t0 = time.perf_counter()
    again = train_prior(out, "tiny", seed=0, cache_dir=tmp_path / "cache", progress=False)
    assert again.reused and time.perf_counter() - t0 < 1.0
    assert stamps == {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.is_file()}

    # deterministic: same config and seed (views from the cache) -> identical weights
    twin = train_prior(tmp_path / "twin", "tiny", seed=0, cache_dir=tmp_path / "cache", progress=False,
                       num_threads=1)
    assert twin.record["fingerprint"] == rec["fingerprint"]
    sa = torch.load(out / "prior.pt", weights_only=True)["state_dict"]
    sb = torch.load(tmp_path / "twin" / "prior.pt", weights_only=True)["state_dict"]
    assert all(torch.equal(sa[k], sb[k]) for k in sa)

    # a different seed is a different artifact: retrained, not reused
    other = train_prior(out, "tiny", seed=1, cache_dir=tmp_path / "cache", progress=False, num_threads=1)
    assert not other.reused and other.record["seed"] == 1

    # the evaluation runs on unseen seeds and scores the prior and both baselines
    from vid2haircut.evaluate.prior_eval import METHODS, evaluate_prior, markdown_summary
    from vid2haircut.prior.train import SETTINGS

    net, codec, _ = load_prior(out)
    rows = evaluate_prior(net, codec, ["bob"], [1000], view_cfg=SETTINGS["tiny"].data.view, strands_per_style=300,
                          n_dense=300, progress=False)
    assert len(rows) == 1 and all(np.isfinite(rows[0].chamfer[m]) and rows[0].chamfer[m] > 0 for m in METHODS)
    assert "| bob |" in markdown_summary(rows)


def test_load_prior_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="misses"):
        load_prior(tmp_path)
    for name in ("codec.npz", "prior.pt"):
        (tmp_path / name).write_bytes(b"junk")
    (tmp_path / "prior.json").write_text("{}")
    with pytest.raises(ValueError, match="prior.pt"):
        load_prior(tmp_path)


def test_render_large_setting_is_render_with_more_styles_and_steps():
    from dataclasses import replace

    from vid2haircut.prior.train import SETTINGS, config_fingerprint

    large, default = SETTINGS["render_large"], SETTINGS["render"]
    assert large.data.train_seeds == tuple(range(24)) and large.steps == 5000
    assert replace(large, data=replace(large.data, train_seeds=default.data.train_seeds), steps=default.steps) == default
    assert max(large.data.train_seeds) < 1000                      # evaluation seeds stay unseen
    assert config_fingerprint(large, 0) != config_fingerprint(default, 0)


def test_photo_view_is_made_like_the_pipeline_targets():
    """A "photo" training view: the photo's hair coverage is the mask, the Gabor orientation of the
    photo follows the strands, and it lines up with the direct render of the same strands."""
    from vid2haircut.head import get_head
    from vid2haircut.prior.corpus import generate_style
    from vid2haircut.prior.views import ViewConfig, photo_view, random_pose, render_view

    head = get_head("proxy-v1")
    pts = generate_style("bob", 3, 1500, 40, head).points
    pose = random_pose(np.random.default_rng(1))
    cfg = ViewConfig(source="photo", photo_size=192, render_size=192, render_strands=1500)
    photo = photo_view(pts, head, pose, cfg, distance=0.7)
    direct = render_view(pts, head, pose, cfg, distance=0.7)
    assert photo.mask.shape == (192, 192) and np.allclose(photo.K, direct.K) and np.allclose(photo.world_2_cam,
                                                                                         direct.world_2_cam)
    a, b = photo.mask >= 0.5, direct.mask >= 0.5
    assert a.sum() > 500 and (a & b).sum() / (a | b).sum() > 0.6            # the same hair, drawn two ways
    both = a & b
    diff = np.abs(photo.angle[both] - direct.angle[both])
    diff = np.minimum(diff, np.pi - diff)                                      # undirected
    assert np.median(diff) < np.radians(20.0)                                  # Gabor follows the strands
    dv = photo.depth[photo.depth_valid]
    assert dv.size > 500 and np.isfinite(dv).all() and 0.0 < float(np.median(dv)) < 1.0   # quantile-normalised
    x = prior_input(*photo.as_tuple(), photo.K, photo.world_2_cam, pose, size=64)
    assert x.shape == (1, 6, 64, 64) and torch.isfinite(x).all()
    with pytest.raises(ValueError, match="N,P,3"):
        photo_view(pts[0], head, pose, cfg)
    with pytest.raises(ValueError, match="source"):
        ViewConfig(source="video")


def test_bundled_prior_is_the_default_setting():
    """The packaged artifact records the fingerprint of SETTINGS["default"] (so `train_prior --setting
    default` rebuilds it, and new, unused config fields do not silently change the default)."""
    import vid2haircut
    from vid2haircut.prior.train import SETTINGS, config_fingerprint
    from vid2haircut.prior.views import ViewConfig

    rec = json.loads((Path(vid2haircut.__file__).parent / "data/prior/default/prior.json").read_text())
    assert rec["fingerprint"] == config_fingerprint(SETTINGS["default"], rec["seed"])
    assert SETTINGS["default"].to_dict()["data"]["view"]["source"] == "photo"
    assert "source" not in SETTINGS["render"].to_dict()["data"]["view"]     # direct-render records unchanged
    assert config_fingerprint(SETTINGS["render"], 0) == "39c5569719b450ee"    # the earlier default's
    view = ViewConfig.from_dict(rec["config"]["data"]["view"])
    assert view == SETTINGS["default"].data.view
    assert ViewConfig.from_dict(SETTINGS["render"].to_dict()["data"]["view"]) == ViewConfig()
    with pytest.raises(ValueError, match="unknown keys"):
        ViewConfig.from_dict({"size": 3})
