"""Stage 2 (joint multi-keyframe refinement) on the toy problem: loss decreases, visibility masking,
deformation field properties, determinism, resume, file-level run through the command line."""

from __future__ import annotations

import argparse
import copy
import json

import numpy as np
import pytest
import torch

from vid2haircut.fit.config import Stage2Config
from vid2haircut.fit.losses import anchor_loss
from vid2haircut.fit.settings import apply_overrides
from vid2haircut.fit.deform import DeformationField, DeformConfig, deformation_weight
from vid2haircut.fit.scene import image_losses, render_frames
from vid2haircut.fit.stage2 import Stage2Model, checkpoint_state, fit_stage2, harmonic_extension
from vid2haircut.fit.toy import toy_problem, write_toy_files
from vid2haircut.fit.visibility import gate_visibility, point_visibility

FAST = {"iterations": 8, "canonical_steps": 3, "ramp_steps": 2, "lr_z": 0.1, "render": {"n_points": 16},
        "n_dense": 300, "checkpoint_every": 3}


@pytest.fixture(scope="module")
def toy():
    return toy_problem(size=40, n_frames=3, map_res=12, k=12)


def _cfg(**extra) -> Stage2Config:
    return apply_overrides(Stage2Config(), {**FAST, **extra})


def _start(toy):
    """Initial map: the mean strand on every scalp texel."""
    return torch.zeros_like(toy.z_gt), toy.mask.clone()


def test_loss_decreases(toy):
    z0, m0 = _start(toy)
    res = fit_stage2(toy.data, toy.codec, _cfg(iterations=12), z0, m0, progress=False)
    t = res.history.terms
    image = [sum(t[k][i] for k in ("silhouette", "direction")) for i in (0, -1)]
    assert image[1] < 0.8 * image[0]
    assert not np.isnan(t["motion"][-1]) and np.isnan(t["motion"][0])    # the MLP joins after the canonical steps
    assert res.render.silhouette.shape == (3, 40, 40)


def test_mlp_off_offsets_exactly_zero(toy):
    z0, m0 = _start(toy)
    model = Stage2Model(toy.data, toy.codec, _cfg(switches={"use_deformation": False}), z0, m0)
    assert model.deform is None and model.ramp(100) == 0.0
    canon = model.canonical()[:, model.layout.render_index]
    frames = torch.arange(3)
    moved, offs, _ = model.deformed(canon, frames, 1.0)
    assert torch.count_nonzero(offs) == 0 and torch.equal(moved, canon[None].expand(3, -1, -1, -1))
    assert "motion" not in model.get_loss_dict(50)
    # with the MLP on, the canonical steps are exactly rigid too
    on = Stage2Model(toy.data, toy.codec, _cfg(), z0, m0)
    assert on.ramp(0) == 0.0 and on.ramp(FAST["canonical_steps"]) > 0.0
    assert torch.count_nonzero(on.deformed(canon, frames, on.ramp(0))[1]) == 0


def test_deformation_weight_zero_at_root():
    cfg = DeformConfig()
    u = torch.linspace(0, 1, 32)
    w = deformation_weight(u, cfg.pinned_fraction)
    assert float(w[0]) == 0.0 and float(w[-1]) == pytest.approx(1.0)
    assert torch.all(w[u <= cfg.pinned_fraction] == 0) and torch.all(torch.diff(w) >= 0)
    field = DeformationField(2, 5, cfg, seed=1)
    with torch.no_grad():                       # a trained-looking field: non-zero outputs everywhere
        field.mlp[-1].weight.normal_(0, 1.0, generator=torch.Generator().manual_seed(2))
        field.mlp[-1].bias.fill_(0.5)
    t = torch.linspace(0, 1, 32)[:, None]
    pts = torch.cat([0.02 * t, -0.2 * t, 0.01 * torch.sin(9 * t)], -1)[None].repeat(5, 1, 1) + torch.tensor([0, 0.1, 0])
    moved, off = field(pts, 1)
    pinned = u <= cfg.pinned_fraction
    assert torch.count_nonzero(off[:, pinned]) == 0 and float(off[:, -1].detach().norm(dim=-1).min()) > 1e-4
    assert float(off.detach().norm(dim=-1).max()) <= cfg.max_offset * 2 ** 0.5 + 1e-7
    assert torch.equal(moved[:, 0], pts[:, 0])                              # the root never moves
    seg = lambda p: (p[:, 1:] - p[:, :-1]).norm(dim=-1)                     # noqa: E731
    assert torch.allclose(seg(moved), seg(pts), atol=1e-6)                  # lengths restored


def test_blockwise_field_matches_the_concatenated_mlp():
    """offsets_batch (the first layer evaluated block by block, several keyframes per call) is the
    MLP applied to the concatenated input, as written: values and every gradient agree."""
    gen = torch.Generator().manual_seed(4)
    field = DeformationField(4, 30, DeformConfig(), seed=2)
    with torch.no_grad():                       # a trained-looking field: every input block matters
        field.mlp[-1].weight.copy_(0.3 * torch.randn(field.mlp[-1].weight.shape, generator=gen))
        field.texel_embed.weight.copy_(0.5 * torch.randn(field.texel_embed.weight.shape, generator=gen))
    t = torch.linspace(0, 1, 16)[:, None]
    base = torch.cat([0.02 * t, -0.2 * t, 0.01 * torch.sin(9 * t)], -1)[None]
    pts = (base + 0.01 * torch.randn(30, 1, 3, generator=gen)).double().requires_grad_(True)
    field = field.double()
    frames = torch.tensor([2, 0, 3])
    index = torch.randperm(30, generator=gen)
    weights = torch.randn(3, 30, 16, 3, generator=gen, dtype=torch.float64)

    def grads(off):
        field.zero_grad()
        pts.grad = None
        (off * weights).sum().backward()
        return [pts.grad.clone()] + [p.grad.clone() for p in field.parameters()]

    per_frame = torch.stack([pts + 0.001 * i for i in range(3)])          # frames may see different strands
    fast = field.offsets_batch(per_frame, frames, index)
    g_fast = grads(fast)
    slow = torch.stack([field.offsets_reference(per_frame[i], int(f), index) for i, f in enumerate(frames)])
    g_slow = grads(slow)
    assert float(slow.detach().abs().max()) > 1e-3
    torch.testing.assert_close(fast, slow, rtol=1e-12, atol=1e-15)
    for a, b in zip(g_fast, g_slow):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-14)
    moved, off = field.forward_batch(per_frame, frames, index, scale=0.5)
    for i, f in enumerate(frames):                                          # one keyframe at a time: the same
        m1, o1 = field(per_frame[i], int(f), index, scale=0.5)
        torch.testing.assert_close(moved[i], m1, rtol=1e-12, atol=1e-15)
        torch.testing.assert_close(off[i], o1, rtol=1e-12, atol=1e-15)


def test_one_default_step_moves_the_field_by_a_fraction_of_its_range():
    """At the default learning rates, one Adam step from rest moves the field's output (before the
    clamp) by well under its range [-1, 1]: the field can settle between rest and the bound."""
    cfg = Stage2Config()
    field = DeformationField(3, 40, DeformConfig(code_init_std=cfg.code_init_std), seed=0)
    t = torch.linspace(0, 1, 32)[:, None]
    pts = torch.cat([0.02 * t, -0.2 * t, 0.01 * torch.sin(9 * t)], -1)[None].repeat(40, 1, 1)
    opt = torch.optim.Adam(field.param_groups(cfg.lr_mlp, cfg.lr_codes))
    target = torch.randn(40, 32, 3, generator=torch.Generator().manual_seed(0))
    loss = -(field.offsets(pts, 1) * target).sum()        # every point pulled its own way
    opt.zero_grad()
    loss.backward()
    opt.step()
    with torch.no_grad():
        raw = field.mlp(torch.zeros(1, field.mlp[0].in_features)).abs().max()
        off = field.offsets(pts, 1).norm(dim=-1)[:, -1]
    assert 0.0 < float(off.max()) < 0.25 * field.cfg.max_offset
    assert float(raw) < 0.25


def test_visibility_masking_zeroes_gradient_of_invisible_segments(toy):
    z0, m0 = _start(toy)
    grads = {}
    for use in (True, False):
        cfg = _cfg(switches={"use_visibility": use}, visibility_unit="segment")   # method.md's gate
        model = Stage2Model(toy.data, toy.codec, cfg, z0, m0)
        canon = model.canonical()[:, model.layout.render_index].detach().requires_grad_(True)
        frames = torch.tensor([1])                                          # one side view
        moved, _, _ = model.deformed(canon, frames, 0.0)
        out = render_frames(moved, toy.data, frames, model.cfg.render)
        model.gate.set_visibility(gate_visibility(out.visibility, model.cfg.visibility_unit))
        loss = image_losses(out, toy.data, frames)
        (loss["silhouette"] + loss["direction"]).backward()
        grads[use] = (canon.grad.norm(dim=-1), out.visibility[0])
    g_on, vis = grads[True]
    g_off, _ = grads[False]
    pv = point_visibility(vis)
    assert pv.any() and (~pv).any()
    assert float(g_on[~pv].abs().max()) == 0.0                            # invisible points get nothing
    assert float(g_off[~pv].abs().max()) > 0.0                            # ... which the gate really removed
    assert torch.allclose(g_on[pv], g_off[pv])                            # visible ones keep their gradient


def test_strand_visibility_unit_updates_whole_seen_strands_only(toy):
    z0, m0 = _start(toy)
    model = Stage2Model(toy.data, toy.codec, _cfg(visibility_unit="strand"), z0, m0)
    canon = model.canonical()[:, model.layout.render_index].detach().requires_grad_(True)
    frames = torch.tensor([1])
    moved, _, _ = model.deformed(canon, frames, 0.0)
    out = render_frames(moved, toy.data, frames, model.cfg.render)
    model.gate.set_visibility(gate_visibility(out.visibility, model.cfg.visibility_unit))
    loss = image_losses(out, toy.data, frames)
    (loss["silhouette"] + loss["direction"]).backward()
    seg = out.visibility[0]
    seen = seg.any(-1)                                                     # (N,) strands with a visible segment
    partly = seen & ~seg.all(-1)
    assert partly.any() and (~seen).any()
    g = canon.grad.norm(dim=-1)
    assert float(g[~seen].max()) == 0.0                                   # unseen strands get nothing
    hidden_pts = ~point_visibility(seg)
    assert float(g[partly][hidden_pts[partly]].max()) > 0.0               # hidden parts of seen strands do
    assert torch.equal(gate_visibility(seg, "segment"), seg)
    with pytest.raises(ValueError, match="visibility_unit"):
        Stage2Model(toy.data, toy.codec, _cfg(visibility_unit="pixel"), z0, m0)


def test_anchor_holds_only_the_points_no_keyframe_shows(toy):
    # the term itself: tests/test_anchor.py
    z0, m0 = _start(toy)
    model = Stage2Model(toy.data, toy.codec, _cfg(weights={"anchor": 1.0}), z0, m0)
    terms = model.get_loss_dict(0)
    assert float(terms["anchor"].detach()) == 0.0                                   # starts at the Stage 1 strands
    hidden = ~model.points_seen.any(0)
    assert hidden.any() and (~hidden).any()                                # the toy hides some points
    with torch.no_grad():
        model.zmap.delta.add_(0.5)
    assert float(model.get_loss_dict(1)["anchor"].detach()) > 0.0
    assert "anchor" not in Stage2Model(toy.data, toy.codec, _cfg(weights={"anchor": 0.0}), z0, m0).get_loss_dict(0)
    # anchor_outward: the directions point away from the head, and a lift of every point is free
    out = Stage2Model(toy.data, toy.codec, _cfg(weights={"anchor": 1.0}, anchor_outward=True), z0, m0)
    assert model.outward is None and out.outward.shape == out.start.shape
    sdf = toy.data.head.sdf
    assert bool((sdf(out.start + 1e-3 * out.outward) > sdf(out.start)).all())
    out.get_loss_dict(0)
    lifted = anchor_loss(out.start + 2e-3 * out.outward, out.start, ~out.points_seen.any(0), out.outward)
    assert float(lifted) < 1e-12


def test_harmonic_extension_interpolates_between_known_nodes():
    # a path 0-1-2-3-4 with the ends known: the inner nodes interpolate linearly
    pairs = torch.tensor([[0, 1], [1, 2], [2, 3], [3, 4]])
    known = torch.tensor([True, False, False, False, True])
    ext = harmonic_extension(pairs, 5, known, eps=0.0)
    assert ext.shape == (3, 2)
    u = ext @ torch.tensor([0.0, 1.0], dtype=torch.float64)
    assert torch.allclose(u, torch.tensor([0.25, 0.5, 0.75], dtype=torch.float64))
    # one known end: the whole chain follows it (eps only pulls it slightly towards 0)
    one = harmonic_extension(pairs, 5, torch.tensor([True, False, False, False, False]))
    assert torch.all(one > 0.95) and torch.all(one <= 1.0)
    # a node cut off from every known node gets 0
    iso = harmonic_extension(pairs[:1], 3, torch.tensor([True, False, False]))
    assert float(iso[1].abs().max()) == 0.0 and float(iso[0, 0]) > 0.99


def test_unobserved_guides_follow_the_observed_change(toy):
    z0, m0 = _start(toy)
    model = Stage2Model(toy.data, toy.codec, _cfg(extend_unobserved=True), z0, m0)
    model.get_loss_dict(0)                                               # first render fixes the followers
    follow = model.follow.clone()
    assert follow.any() and (~follow).any()
    k = z0.shape[0]
    tix = model.layout.texel_index
    with torch.no_grad():
        assert torch.equal(model.z, model.zmap())                         # no change yet: nothing added
        model.zmap.delta.view(k, -1)[0, tix[~follow]] = 1.0 / model.zmap.gain.view(k, -1)[0, tix[~follow]]
        z = model.z.reshape(k, -1)
    # the observed guides changed their first coefficient by 1: the followers move by about as much
    assert torch.allclose(z[0, tix[~follow]], torch.ones(int((~follow).sum())), atol=1e-5)
    assert float(z[0, tix[follow]].min()) > 0.9 and float(z[0, tix[follow]].max()) <= 1.0 + 1e-6
    assert float(z[1:].abs().max()) < 1e-6
    # the addition is detached: the followers' losses do not reach the observed coefficients
    model.zmap.delta.grad = None
    model.z.reshape(k, -1)[0, tix[follow]].sum().backward()
    assert float(model.zmap.delta.grad.view(k, -1)[:, tix[~follow]].abs().max()) == 0.0
    # the anchor holds the followers' own coefficients, not the change they follow: with only the
    # observed coefficients changed, the followers' hidden points pay nothing and get no pull back
    held = Stage2Model(toy.data, toy.codec, _cfg(extend_unobserved=True, weights={"anchor": 1.0}), z0, m0)
    held.get_loss_dict(0)
    fol = held.follow.clone()
    hidden = ~held.points_seen.any(0)
    assert bool((hidden & fol[:, None]).any())                           # followers with hidden points
    with torch.no_grad():
        held.zmap.delta.view(k, -1)[0, tix[~fol]] = 1.0 / held.zmap.gain.view(k, -1)[0, tix[~fol]]
        assert float((held.z.reshape(k, -1)[0, tix[fol]]).abs().min()) > 0.5     # they did move
    held.zmap.delta.grad = None
    held.get_loss_dict(1)["anchor"].backward()
    assert float(held.zmap.delta.grad.view(k, -1)[:, tix[fol]].abs().max()) == 0.0
    # switched off (default): the map is the plain one
    off = Stage2Model(toy.data, toy.codec, _cfg(), z0, m0)
    off.get_loss_dict(0)
    assert not off.follow.any()
    # a resumed fit restores the followers and ends where the uninterrupted one does
    states = {}

    def keep(step, model, trainer):
        if step == 3:
            states["ck"] = copy.deepcopy(checkpoint_state(step, model, trainer))

    a = fit_stage2(toy.data, toy.codec, _cfg(extend_unobserved=True), z0, m0, progress=False, on_step=keep)
    c = fit_stage2(toy.data, toy.codec, _cfg(extend_unobserved=True), z0, m0, progress=False, resume=states["ck"])
    assert states["ck"]["model"]["follow"].any()
    assert torch.allclose(a.z, c.z, atol=1e-6) and not torch.allclose(a.z, fit_stage2(
        toy.data, toy.codec, _cfg(), z0, m0, progress=False).z, atol=1e-4)


def test_same_seed_same_output_and_resume(toy):
    z0, m0 = _start(toy)
    states = {}

    def keep(step, model, trainer):
        if step == 3:
            states["ck"] = copy.deepcopy(checkpoint_state(step, model, trainer))

    a = fit_stage2(toy.data, toy.codec, _cfg(), z0, m0, progress=False, on_step=keep)
    b = fit_stage2(toy.data, toy.codec, _cfg(), z0, m0, progress=False)
    assert torch.equal(a.z, b.z) and torch.equal(a.guides, b.guides)
    for pa, pb in zip(a.extra["deform"].parameters(), b.extra["deform"].parameters()):
        assert torch.equal(pa, pb)
    c = fit_stage2(toy.data, toy.codec, _cfg(), z0, m0, progress=False, resume=states["ck"])
    assert len(c.history.total) == FAST["iterations"]
    assert torch.allclose(a.z, c.z, atol=1e-6)
    other = fit_stage2(toy.data, toy.codec, _cfg(seed=5), z0, m0, progress=False)
    assert not torch.equal(other.extra["deform"].frame_codes.weight, a.extra["deform"].frame_codes.weight)


def test_lr_decay_follows_the_step_and_survives_resume(toy):
    z0, m0 = _start(toy)
    cfg = _cfg(lr_decay_steps=6, lr_final=0.2)
    states, lrs = {}, []

    def keep(step, model, trainer):
        lrs.append([g["lr"] for opt in trainer.optimizers for g in opt.param_groups])
        if step == 4:
            states["ck"] = copy.deepcopy(checkpoint_state(step, model, trainer))

    a = fit_stage2(toy.data, toy.codec, cfg, z0, m0, progress=False, on_step=keep)
    assert lrs[0][0] == pytest.approx(cfg.lr_z) and lrs[-1][0] == pytest.approx(0.2 * cfg.lr_z)
    assert lrs[-1][1] == pytest.approx(0.2 * cfg.lr_mlp)                  # every group decays
    c = fit_stage2(toy.data, toy.codec, cfg, z0, m0, progress=False, resume=states["ck"])
    assert torch.allclose(a.z, c.z, atol=1e-6)
    plain = fit_stage2(toy.data, toy.codec, _cfg(), z0, m0, progress=False)
    assert not torch.allclose(a.z, plain.z, atol=1e-5)


def _stage2_parser() -> argparse.ArgumentParser:
    from vid2haircut.cli import stage2

    parser = argparse.ArgumentParser()
    stage2.register(parser.add_subparsers())
    return parser


def test_files_cli_outputs_and_resume(toy, tmp_path):
    from vid2haircut.fit.pipeline import run_stage1
    from vid2haircut.io.strand_formats import load_strands

    files = write_toy_files(toy, tmp_path / "data")
    s1 = tmp_path / "s1"
    run_stage1(files["dataset_root"], "toy", files["keyframes"], files["head"], files["targets"], s1,
               codec_path=files["codec"], progress=False,
               settings={"iterations": 2, "map_res": 12, "render": {"n_points": 16, "size": 40}, "n_dense": 200})
    out = tmp_path / "s2"
    argv = ["stage2", "--root", str(files["dataset_root"]), "--subject", "toy", "--seq", "HAIR",
            "--keyframes", str(files["keyframes"]), "--head", str(files["head"]), "--targets", str(files["targets"]),
            "--stage1-dir", str(s1), "--out", str(out), "--no-progress",
            "--settings", json.dumps({**FAST, "render": {"n_points": 16, "size": 40}})]
    args = _stage2_parser().parse_args(argv)
    assert args.func(args) == 0
    for rel in ("strands.npz", "guides.npz", "hairmap.npz", "deform.pt", "checkpoint.pt", "loss_curve.png",
                "stage2.json", *(f"renders/frame_{t:05d}.png" for t in range(3))):
        assert (out / rel).is_file(), rel
    dense = load_strands(out / "strands.npz")
    assert dense.n_strands == 300 and dense.head_model == "proxy-v1"
    first = json.loads((out / "stage2.json").read_text())
    assert first["resumed_from_step"] is None and first["keyframes"] == [0, 1, 2]
    assert 0.0 <= first["carved_fraction"] < 1.0 and first["config"]["carve_tolerance"] == 1.0
    assert args.func(args) == 0                                             # again: resumes at the end
    again = json.loads((out / "stage2.json").read_text())
    assert again["resumed_from_step"] == FAST["iterations"] - 1
    assert np.array_equal(load_strands(out / "strands.npz").points, dense.points)
    # a decoding-only setting resumes the finished fit and decodes it again
    args = _stage2_parser().parse_args(argv[:-1] + [json.dumps({**FAST, "render": {"n_points": 16, "size": 40},
                                                                "carve_tolerance": 0.0})])
    assert args.func(args) == 0
    plain = json.loads((out / "stage2.json").read_text())
    assert plain["resumed_from_step"] == FAST["iterations"] - 1 and plain["carved_fraction"] == 0.0
    assert plain["config"]["carve_tolerance"] == 0.0 and plain["signature"] == first["signature"]
    # fewer keyframes is one setting
    args = _stage2_parser().parse_args(argv[:-1] + [json.dumps({**FAST, "iterations": 2, "n_keyframes": 1,
                                                                "render": {"n_points": 16, "size": 40}})])
    assert args.func(args) == 0
    assert json.loads((out / "stage2.json").read_text())["keyframes"] == [0]


def test_silhouette_opacity_thins_only_the_silhouette(toy):
    """The silhouette term sees translucent guides (a second render); direction, depth and visibility
    stay those of the opaque render, and the silhouette still passes a gradient to the points."""
    model = Stage2Model(toy.data, toy.codec, _cfg(), *_start(toy))
    pts = model.canonical()[:, model.layout.render_index].detach()[None].requires_grad_(True)
    frames = torch.tensor([0])
    opaque = render_frames(pts, toy.data, frames, apply_overrides(model.cfg.render, {"silhouette_opacity": 1.0}))
    thin = render_frames(pts, toy.data, frames, apply_overrides(model.cfg.render, {"silhouette_opacity": 0.3}))
    s_thin, s_opaque = thin.silhouette.detach(), opaque.silhouette.detach()
    assert float(s_opaque.max()) > 0.9
    assert bool((s_thin <= s_opaque + 1e-6).all())
    # translucent guides cover less: only overlaps of several reach full coverage
    assert float(s_thin.mean()) < 0.8 * float(s_opaque.mean())
    for name in ("direction", "depth", "mask", "visibility"):
        assert torch.equal(getattr(thin, name), getattr(opaque, name)), name
    (g,) = torch.autograd.grad(thin.silhouette.sum(), pts)
    assert float(g.abs().sum()) > 0.0
    with pytest.raises(ValueError, match="silhouette_opacity"):
        render_frames(pts, toy.data, frames, apply_overrides(model.cfg.render, {"silhouette_opacity": 0.0}))


def test_gravity_term_is_in_the_loss_only_when_weighted(toy):
    z0, m0 = _start(toy)
    assert "gravity" not in Stage2Model(toy.data, toy.codec, _cfg(), z0, m0).get_loss_dict(0)
    model = Stage2Model(toy.data, toy.codec, _cfg(weights={"gravity": 0.1}), z0, m0)
    losses = model.get_loss_dict(0)
    from vid2haircut.fit.losses import gravity_loss
    expect = gravity_loss(model.canonical()[:, model.layout.render_index])
    assert float(losses["gravity"]) == pytest.approx(float(expect), rel=1e-12)


def test_depth_alignment_reaches_the_depth_term_and_is_checked(toy):
    z0, m0 = _start(toy)
    terms = {a: float(Stage2Model(toy.data, toy.codec, _cfg(depth_align=a), z0, m0).get_loss_dict(0)["depth"])
             for a in ("quantile", "affine")}
    assert terms["quantile"] != terms["affine"]
    with pytest.raises(ValueError, match="depth_align"):
        Stage2Model(toy.data, toy.codec, _cfg(depth_align="median"), z0, m0)


def test_outside_term_pulls_stray_strands_and_respects_the_gate(toy):
    z0, m0 = _start(toy)
    assert "outside" not in Stage2Model(toy.data, toy.codec, _cfg(), z0, m0).get_loss_dict(0)
    model = Stage2Model(toy.data, toy.codec, _cfg(weights={"outside": 1.0}, visibility_unit="strand"), z0, m0)
    assert toy.data.outside is not None and float(toy.data.outside.max()) > 1.0
    canon = model.canonical()[:, model.layout.render_index].detach().requires_grad_(True)
    frames = torch.arange(3)
    moved, _, _ = model.deformed(canon, frames, 0.0)
    out = render_frames(moved, toy.data, frames, model.cfg.render)
    model.gate.set_visibility(gate_visibility(out.visibility, model.cfg.visibility_unit))
    from vid2haircut.fit.scene import outside_term
    term = outside_term(moved, toy.data, frames, model.cfg.outside_tolerance)
    assert float(term.detach()) > 0.0                         # the mean strand sticks out of the toy's hair
    term.backward()
    seen = out.visibility.any(-1).any(0)                      # (N,) strands some frame shows
    g = canon.grad.norm(dim=-1).amax(-1)
    assert float(g[~seen].max()) == 0.0 and float(g[seen].max()) > 0.0
    left = {}
    for w in (0.0, 100.0):                                    # after the same steps, with and without the term
        cfg = _cfg(iterations=12, weights={"outside": w}, switches={"use_deformation": False})
        res = fit_stage2(toy.data, toy.codec, cfg, z0, m0, progress=False)
        pts = res.guides[:, model.layout.render_index][None].expand(3, -1, -1, -1)
        left[w] = float(outside_term(pts, toy.data, frames, model.cfg.outside_tolerance))
    assert left[100.0] < 0.7 * left[0.0]
