"""Loss terms, visibility gate and config overrides of vid2haircut.fit (tiny tensors, physical checks)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from vid2haircut.fit.components import LossWeights
from vid2haircut.fit.config import Stage1Config, Stage2Config
from vid2haircut.fit.settings import apply_overrides, load_settings
from vid2haircut.fit.data import downsample_targets, order_keyframes, scale_intrinsics
from vid2haircut.fit.image_terms import depth_loss, direction_loss, silhouette_loss
from vid2haircut.fit.losses import motion_loss, pca_consistency_loss, penetration_loss
from vid2haircut.fit.trainer import History, lr_decay_factor, weighted_total
from vid2haircut.fit.visibility import VisibilityGate, point_visibility


def _doubled(angle: torch.Tensor) -> torch.Tensor:
    return torch.stack([torch.cos(2 * angle), torch.sin(2 * angle)], -1)


def test_silhouette_l1():
    a = torch.zeros(1, 4, 4)
    b = torch.zeros(1, 4, 4)
    b[0, :2] = 1.0
    assert float(silhouette_loss(a, a)) == 0.0
    assert float(silhouette_loss(a, b)) == pytest.approx(0.5)


def test_direction_is_undirected_and_weighted():
    ang = torch.tensor([[[0.3, 1.2], [2.0, 0.1]]])
    mask = torch.ones(1, 2, 2, dtype=torch.bool)
    w = torch.ones(1, 2, 2)
    # the same direction, and the opposite direction (a + pi has the same doubled angle): zero loss
    assert float(direction_loss(_doubled(ang), mask, _doubled(ang + math.pi), w)) == pytest.approx(0.0, abs=1e-6)
    # perpendicular: o=(1,0), o_hat=(0,1): min(|o-o_hat|_1, |o+o_hat|_1) = 2
    zero, right = torch.zeros(1, 1, 1), torch.full((1, 1, 1), math.pi / 2)
    one = torch.ones(1, 1, 1)
    assert float(direction_loss(_doubled(zero), one.bool(), _doubled(right), one)) == pytest.approx(2.0, abs=1e-5)
    # a zero-weight pixel does not count; an empty rendered pixel gives no NaN gradient
    pred = _doubled(torch.tensor([[[0.0, 0.0]]])).clone()
    pred[0, 0, 1] = 0.0
    pred.requires_grad_(True)
    tgt = _doubled(torch.tensor([[[0.0, 1.0]]]))
    loss = direction_loss(pred, torch.tensor([[[True, False]]]), tgt, torch.tensor([[[1.0, 1.0]]]))
    loss.backward()
    assert float(loss.detach()) == pytest.approx(0.0, abs=1e-6) and torch.isfinite(pred.grad).all()


def test_depth_invariant_to_scale_and_offset():
    g = torch.Generator().manual_seed(0)
    tgt = torch.rand(1, 8, 8, generator=g)
    valid = torch.ones(1, 8, 8, dtype=torch.bool)
    lo, hi = torch.quantile(tgt.flatten(), torch.tensor([0.05, 0.95]))
    tgt_n = (tgt - lo) / (hi - lo)
    pred = 0.7 + 0.05 * tgt                      # metres: an affine copy of the target
    assert float(depth_loss(pred, valid, tgt_n, valid)) == pytest.approx(0.0, abs=1e-5)
    assert float(depth_loss(0.7 - 0.05 * tgt, valid, tgt_n, valid)) > 0.3      # reversed order is wrong
    # too few common pixels: zero, still differentiable
    small = torch.zeros_like(valid)
    small[0, 0, :3] = True
    assert float(depth_loss(pred, small, tgt_n, small)) == 0.0


def test_affine_depth_alignment_ignores_scale_shift_and_where_the_masks_differ():
    g = torch.Generator().manual_seed(1)
    z = 0.7 + 0.05 * torch.rand(2, 12, 12, generator=g, dtype=torch.float64)
    valid = torch.ones(2, 12, 12, dtype=torch.bool)
    target = (z - 0.71) / 0.04                         # relative depth made over a larger region
    part = valid.clone()
    part[:, :, 8:] = False                             # the render covers only part of it
    assert float(depth_loss(z, part, target, valid, align="affine")) == pytest.approx(0.0, abs=1e-12)
    assert float(depth_loss(z, part, target, valid)) > 0.05                   # the quantiles see the region
    noisy = target + 0.05 * torch.randn(2, 12, 12, generator=g, dtype=torch.float64)
    a = depth_loss(z, valid, noisy, valid, align="affine")
    assert float(depth_loss(3.0 * z + 1.0, valid, noisy, valid, align="affine")) == pytest.approx(float(a), rel=1e-9)
    # a reversed depth order is not fitted by a negative scale: it pays as with the quantiles
    rev = 1.5 - z
    assert float(depth_loss(rev, valid, target, valid, align="affine")) == pytest.approx(
        float(depth_loss(rev, valid, target, valid)), rel=1e-12)
    assert float(depth_loss(rev, valid, target, valid, align="affine")) > 0.3
    x = z.clone().requires_grad_(True)                 # the gradient matches finite differences
    depth_loss(x, valid, noisy, valid, align="affine").backward()
    i = (0, 3, 4)
    e = torch.zeros_like(z)
    e[i] = 1e-7
    fd = (depth_loss(z + e, valid, noisy, valid, align="affine") - depth_loss(z - e, valid, noisy, valid,
                                                                              align="affine")) / 2e-7
    assert float(x.grad[i]) == pytest.approx(float(fd), rel=1e-4, abs=1e-9)
    with pytest.raises(ValueError, match="depth alignment"):
        depth_loss(z, valid, target, valid, align="median")


def test_penetration_counts_only_inside():
    sdf = (lambda p: p.norm(dim=-1) - 0.1)       # sphere of 10 cm
    inside = torch.tensor([[0.0, 0.0, 0.05]])
    outside = torch.tensor([[0.0, 0.0, 0.2]])
    assert float(penetration_loss(outside, sdf)) == 0.0
    assert float(penetration_loss(torch.cat([inside, outside]), sdf)) == pytest.approx(0.025)
    # a margin tolerates that depth: 5 cm inside with a 2 cm margin counts 3 cm; 1 cm inside counts 0
    assert float(penetration_loss(torch.cat([inside, outside]), sdf, margin=0.02)) == pytest.approx(0.015)
    assert float(penetration_loss(torch.tensor([[0.0, 0.0, 0.09]]), sdf, margin=0.02)) == 0.0


def test_pca_consistency_flows_from_observed_to_unobserved():
    z = torch.zeros(2, 3, 3)
    z[:, 1, 1] = 1.0
    z.requires_grad_(True)
    hair = torch.ones(3, 3, dtype=torch.bool)
    everything = torch.ones(3, 3, dtype=torch.bool)
    assert float(pca_consistency_loss(z, hair, everything).detach()) == 0.0
    observed = torch.ones(3, 3, dtype=torch.bool)
    observed[1, 1] = False                        # the centre is unseen: pulled to its neighbours' mean (0)
    loss = pca_consistency_loss(z, hair, observed)
    loss.backward()
    assert float(loss.detach()) == pytest.approx(1.0)
    assert float(z.grad[:, 1, 1].abs().sum()) > 0
    grad_obs = z.grad.clone()
    grad_obs[:, 1, 1] = 0
    assert float(grad_obs.abs().sum()) == 0.0      # observed neighbours are not pulled towards the unseen texel


def test_motion_loss():
    assert float(motion_loss(torch.full((2, 3, 3), 0.01))) == pytest.approx(3e-4)


def test_visibility_gate_masks_gradient_per_frame():
    canon = torch.randn(4, 5, 3, requires_grad=True)
    gate = VisibilityGate()
    per_frame = gate(canon[None].expand(2, -1, -1, -1))
    seg_vis = torch.zeros(2, 4, 4, dtype=torch.bool)
    seg_vis[0, 1, 2] = True                       # frame 0 sees segment 2 of strand 1 (points 2, 3)
    seg_vis[1, 3] = True                          # frame 1 sees strand 3 entirely
    gate.set_visibility(seg_vis)
    (per_frame * torch.arange(1.0, 3.0)[:, None, None, None]).sum().backward()
    expect = torch.zeros(4, 5)
    expect[1, 2:4] += 1.0
    expect[3] += 2.0
    assert torch.equal(canon.grad[..., 0], expect)
    assert torch.equal(point_visibility(torch.tensor([[True, False, False]])),
                       torch.tensor([[True, True, False, False]]))
    # without set_visibility the backward refuses to run silently
    per_frame = gate(canon[None].expand(2, -1, -1, -1))
    with pytest.raises(RuntimeError, match="set_visibility"):
        per_frame.sum().backward()
    off = VisibilityGate(enabled=False)
    canon.grad = None
    off(canon[None].expand(2, -1, -1, -1)).sum().backward()
    assert torch.equal(canon.grad, torch.full_like(canon, 2.0))


def test_overrides_nested_dotted_and_errors(tmp_path):
    cfg = apply_overrides(Stage2Config(), {"switches": {"use_deformation": False}, "weights.depth": 0.5,
                                           "iterations": 7})
    assert cfg.switches.use_deformation is False and cfg.weights.depth == 0.5 and cfg.iterations == 7
    assert Stage2Config().switches.use_deformation is True          # the default is untouched
    with pytest.raises(ValueError, match="unknown key 'switches.use_magic'"):
        apply_overrides(Stage2Config(), {"switches.use_magic": True})
    with pytest.raises(ValueError, match="true or false"):
        apply_overrides(Stage2Config(), {"switches.use_visibility": 1})
    with pytest.raises(ValueError, match="integer"):
        apply_overrides(Stage2Config(), {"iterations": 2.5})
    with pytest.raises(ValueError, match=r"'length_spread' must be in \[0, 0.333333\)"):
        apply_overrides(Stage1Config(), {"length_spread": -0.01})
    assert apply_overrides(Stage2Config(), {"length_spread": 0}).length_spread == 0.0
    with pytest.raises(ValueError, match="'tip_scatter' must be in"):
        apply_overrides(Stage2Config(), {"tip_scatter": 0.1})
    # counts, sizes, rates and weights out of range; NaN anywhere (each had run, some writing an unfitted output)
    for key, value, message in [("iterations", -5, r"'iterations' must be in \[1, inf\)"),
                                ("n_dense", -3, r"'n_dense' must be in \[1, inf\)"),
                                ("render", {"size": 0}, r"'render.size' must be in \[8, 4097\)"),
                                ("seed", -1, r"'seed' must be in \[0, "),
                                ("weights.depth", -0.1, r"'weights.depth' must be in \[0, inf\)"),
                                ("lr_z", float("nan"), "'lr_z' must be a finite number"),
                                ("weights.silhouette", float("inf"), "'weights.silhouette' must be a finite")]:
        with pytest.raises(ValueError, match=message):
            apply_overrides(Stage2Config(), {key: value})
    assert apply_overrides(Stage2Config(), {"dense_from_step": -1, "weights.outside": 0}).dense_from_step == -1
    p = tmp_path / "s.json"
    p.write_text('{"iterations": 3}')
    assert load_settings(str(p)) == {"iterations": 3} and load_settings('{"a": 1}') == {"a": 1}
    with pytest.raises(ValueError, match="not valid JSON"):
        load_settings("{nope")


def test_weighted_total_and_history():
    w = LossWeights()
    total = weighted_total({"silhouette": torch.tensor(2.0), "depth": torch.tensor(1.0)}, w)
    assert float(total) == pytest.approx(2.0 + w.depth)
    with pytest.raises(ValueError, match="no weight"):
        weighted_total({"bogus": torch.tensor(1.0)}, w)
    h = History()
    h.add(0, {"a": 1.0}, 1.0)
    h.add(1, {"a": 2.0, "b": 3.0}, 5.0)
    assert np.isnan(h.terms["b"][0]) and History.from_dict(h.to_dict()).terms["a"] == [1.0, 2.0]


def test_downsample_targets_and_intrinsics():
    h = w = 8
    ang = np.full((h, w), 0.25 * math.pi, np.float32)
    ang[:, 4:] = 0.25 * math.pi + math.pi - 1e-3       # nearly the same undirected direction across the wrap
    t = {"mask": np.ones((h, w), np.float32), "angle": ang, "confidence": np.ones((h, w), np.float32),
         "depth": np.linspace(0, 1, h * w, dtype=np.float32).reshape(h, w), "depth_valid": np.ones((h, w), bool)}
    lo = downsample_targets(t, 4, 4)
    a = np.remainder(0.5 * np.arctan2(lo["direction"][..., 1], lo["direction"][..., 0]), math.pi)
    assert np.allclose(a, 0.25 * math.pi, atol=2e-3) and lo["confidence"].min() > 0.99
    assert lo["depth_valid"].all() and lo["mask"].shape == (4, 4)
    K = np.array([[100.0, 0, 3.5], [0, 100.0, 3.5], [0, 0, 1]])
    Ks = scale_intrinsics(K, 0.5, 0.5)
    assert Ks[0, 0] == 50.0 and Ks[0, 2] == pytest.approx(1.5)     # the image centre stays the centre
    scores = {1: {"yaw_deg": 0.0}, 2: {"yaw_deg": 10.0}, 3: {"yaw_deg": 50.0}, 4: {"yaw_deg": -40.0}}
    assert order_keyframes([1, 2, 3, 4], 1, scores) == [1, 3, 4, 2]
    assert order_keyframes([1, 2, 3, 4], 2, {}, 2) == [2, 1]


def test_shared_adam_moves_weak_texels_slowly():
    from vid2haircut.fit.optim import SharedAdam

    p = torch.zeros(1, 2, 2, requires_grad=True)
    ref = torch.zeros(1, 2, 2, requires_grad=True)
    opt, adam = SharedAdam([p], lr=0.1), torch.optim.Adam([ref], lr=0.1)
    g = torch.tensor([[[1.0, 1.0], [1.0, 1e-3]]])   # one texel barely constrained
    for _ in range(3):
        for o, t in ((opt, p), (adam, ref)):
            o.zero_grad()
            (t * g).sum().backward()
            o.step()
    assert torch.allclose(p[0, 0], ref[0, 0], atol=1e-6)          # typical texels: exactly Adam
    assert abs(float(p[0, 1, 1].detach())) < 0.01 * abs(float(ref[0, 1, 1].detach()))  # Adam would move it as far


def test_extend_map_and_push_out_of_head():
    from vid2haircut.fit.outputs import extend_map, push_out_of_head

    z = torch.zeros(2, 4, 4)
    hair = torch.zeros(4, 4, dtype=torch.bool)
    hair[1:3, 1:3] = True
    z[:, hair] = torch.tensor([1.0, 2.0, 3.0, 4.0])
    ext = extend_map(z, hair)
    assert torch.equal(ext[:, hair], z[:, hair])
    assert float(ext[0, 0, 0]) == pytest.approx(1.0) and float(ext[0, 3, 3]) == pytest.approx(4.0)
    assert float(ext[0, 0, 1]) == pytest.approx(1.5)              # mean of its two guide neighbours

    class Sphere:                                                 # head of radius 10 cm
        @staticmethod
        def sdf(p):
            return p.norm(dim=-1) - 0.1

    pts = torch.tensor([[[0.0, 0.1, 0.0], [0.0, 0.05, 0.02], [0.0, 0.3, 0.0]]])
    out = push_out_of_head(pts, Sphere(), margin=1e-3)
    assert torch.equal(out[:, 0], pts[:, 0]) and torch.equal(out[0, 2], pts[0, 2])
    assert float(Sphere.sdf(out[0, 1])) == pytest.approx(1e-3, abs=1e-5)


def _arc(radius: float, length: float, n: int = 50) -> torch.Tensor:
    """(n,3) points on a circle of ``radius`` over an arc of ``length`` (metres)."""
    t = torch.linspace(0.0, length / radius, n, dtype=torch.float64)
    return torch.stack([radius * torch.sin(t), radius * (1 - torch.cos(t)), torch.zeros_like(t)], -1)


def test_bend_loss_counts_only_bends_tighter_than_the_radius():
    from vid2haircut.fit.losses import bend_loss

    zeros = torch.zeros(50, dtype=torch.float64)
    straight = torch.stack([torch.linspace(0, 0.2, 50, dtype=torch.float64), zeros, zeros], -1)
    assert float(bend_loss(straight, 0.003)) == 0.0
    assert float(bend_loss(_arc(0.02, 0.05), 0.003)) == 0.0            # a 2 cm wave: left alone
    tight = bend_loss(_arc(0.001, 0.02, 200), 0.003)                     # a 1 mm coil
    assert float(tight) > 0.0
    # one turn of theta per segment of length l: |du|^2 = 2 (1 - cos theta), allowed (l / r)^2
    l, theta = 0.0005, 0.3
    d = torch.tensor([[l, 0.0, 0.0], [l * math.cos(theta), l * math.sin(theta), 0.0]], dtype=torch.float64)
    pts = torch.cat([torch.zeros(1, 3, dtype=torch.float64), d.cumsum(0)])
    expect = 2 * (1 - math.cos(theta)) - (l / 0.003) ** 2
    assert float(bend_loss(pts, 0.003)) == pytest.approx(expect, rel=1e-9)
    # a millimetre zigzag is penalised and its gradient straightens it; a straight strand has none
    zig = straight.clone() * 0.1                                           # a 2 cm strand, 0.4 mm segments
    zig[1::2, 1] = 0.0002
    zig.requires_grad_(True)
    before = bend_loss(zig, 0.003)
    before.backward()
    with torch.no_grad():
        after = bend_loss(zig - 1e-8 * zig.grad, 0.003)
        amp = (zig - 1e-8 * zig.grad)[1:-1, 1].std()
    assert float(before.detach()) > 0.1 and float(after) < float(before.detach()) and float(amp) < float(zig.detach()[1:-1, 1].std())
    s = straight.clone().requires_grad_(True)
    bend_loss(s, 0.003).backward()
    assert torch.isfinite(s.grad).all() and float(s.grad.abs().max()) == 0.0


def test_gravity_loss_charges_only_rising_segments_and_pulls_them_down():
    from vid2haircut.fit.losses import gravity_loss

    t = torch.linspace(0, 0.1, 20, dtype=torch.float64)
    zeros = torch.zeros_like(t)
    hanging = torch.stack([zeros, -t, zeros], -1)                       # straight down
    level = torch.stack([t, zeros, zeros], -1)                          # along x
    wave = torch.stack([zeros, -t, 0.01 * torch.sin(t * 200)], -1)      # a wave that never climbs
    for pts in (hanging, level, wave):
        assert float(gravity_loss(pts)) == 0.0
    up30 = torch.stack([t * math.cos(math.pi / 6), t * math.sin(math.pi / 6), zeros], -1)
    assert float(gravity_loss(up30)) == pytest.approx(0.5, rel=1e-12)    # the sine of the climb
    both = torch.stack([hanging, up30])                                 # the mean over all segments
    assert float(gravity_loss(both)) == pytest.approx(0.25, rel=1e-12)
    assert float(gravity_loss(up30[..., [1, 0, 2]], up=0)) == pytest.approx(0.5, rel=1e-12)
    x = up30.clone().requires_grad_(True)
    gravity_loss(x).backward()
    with torch.no_grad():
        after = gravity_loss(x - 1e-3 * x.grad)
    assert float(after) < 0.5 and float(x.grad[-1, 1]) > 0.0             # the tip is pulled down


def test_lr_decay_factor_is_a_half_cosine_over_the_last_steps():
    f = [lr_decay_factor(s, 10, 4, 0.1) for s in range(10)]
    assert f[:6] == [1.0] * 6                          # constant until the last 4 steps
    assert f[-1] == pytest.approx(0.1)                 # the final factor at the last step
    assert all(a > b for a, b in zip(f[5:], f[6:]))    # then strictly falling
    assert f[7] == pytest.approx(0.1 + 0.9 * 0.5)      # half-way through the cosine: the midpoint
    assert all(lr_decay_factor(s, 10, 0, 0.1) == 1.0 for s in range(10))
    with pytest.raises(ValueError, match="final factor"):
        lr_decay_factor(9, 10, 4, 0.0)
