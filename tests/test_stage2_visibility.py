"""Stage 2's visibility-aware updates on the toy problem: the gate zeroes the gradient of unseen
segments and strands, the anchor holds unseen points, unobserved guides follow the observed change."""

from __future__ import annotations

import copy
import dataclasses
import sys
from pathlib import Path

import pytest
import torch

from vid2haircut.fit.losses import anchor_loss
from vid2haircut.fit.scene import hidden_direction_term, image_losses, render_frames
from vid2haircut.fit.hidden import harmonic_extension
from vid2haircut.fit.stage2 import checkpoint_state, fit_stage2, Stage2Model
from vid2haircut.fit.visibility import gate_visibility, point_visibility

sys.path.insert(0, str(Path(__file__).parent))
from stage2_common import cfg as _cfg, make_toy, start as _start  # noqa: E402


@pytest.fixture(scope="module")
def toy():
    return make_toy()


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


def test_hidden_direction_loss_matches_the_rendered_direction_convention():
    from vid2haircut.fit.image_terms import hidden_direction_loss
    from vid2haircut.render import render_strands

    K = torch.tensor([[[100.0, 0.0, 32.0], [0.0, 100.0, 32.0], [0.0, 0.0, 1.0]]])
    eye = torch.eye(4)[None]
    x = torch.linspace(-0.1, 0.1, 8)
    strand = torch.stack([x, 0.5 * x, torch.ones(8)], -1)[None, None]       # slope 0.5 in the image
    rendered = render_strands(strand, K, eye, 64, 64, strand_width=0.004).direction[0, 34, 36]
    hidden = torch.ones(1, 1, 7, dtype=torch.bool)
    weight = torch.ones(1, 64, 64)
    along = rendered.expand(1, 64, 64, 2)
    assert abs(float(hidden_direction_loss(strand, hidden, K, eye, along, weight, None))) < 1e-5
    across = -along                                                          # doubled angle + 180 deg: 90 deg off
    assert float(hidden_direction_loss(strand, hidden, K, eye, across, weight, None)) == pytest.approx(2.0, abs=1e-5)
    # shown segments, unweighted pixels and segments behind the head pay nothing
    assert float(hidden_direction_loss(strand, ~hidden, K, eye, across, weight, None)) == 0.0
    assert float(hidden_direction_loss(strand, hidden, K, eye, across, 0.0 * weight, None)) == 0.0
    head = torch.full((1, 64, 64), 0.5)
    assert float(hidden_direction_loss(strand, hidden, K, eye, across, weight, head)) == 0.0
    # the gradient turns the strand towards the target: a step lowers the loss
    p = strand.clone().requires_grad_(True)
    tilted = torch.tensor([1.0, 0.0]).expand(1, 64, 64, 2)                    # horizontal
    loss = hidden_direction_loss(p, hidden, K, eye, tilted, weight, None)
    loss.backward()
    with torch.no_grad():
        after = hidden_direction_loss(p - 1e-3 * p.grad / p.grad.norm(), hidden, K, eye, tilted, weight, None)
    assert float(after) < float(loss)


@pytest.mark.parametrize("source", ["render", "target"])
def test_hidden_direction_term_reaches_only_the_strands_the_gate_shuts(toy, source):
    z0, m0 = _start(toy)
    cfg = _cfg(weights={"hidden_direction": 1.0}, visibility_unit="strand", hidden_direction_from=source)
    model = Stage2Model(toy.data, toy.codec, cfg, z0, m0)
    canon = model.canonical()[:, model.layout.render_index].detach().requires_grad_(True)
    frames = torch.tensor([1])
    moved, _, _ = model.deformed(canon, frames, 0.0)
    out = render_frames(moved, toy.data, frames, model.cfg.render)
    model.gate.set_visibility(gate_visibility(out.visibility, model.cfg.visibility_unit))
    hidden = ~gate_visibility(out.visibility, model.cfg.visibility_unit)
    term = hidden_direction_term(canon, moved, hidden, out, toy.data, frames, source)
    term.backward()
    seen = out.visibility[0].any(-1)
    g = canon.grad.norm(dim=-1)
    assert (~seen).any() and float(term) > 0.0
    assert float(g[seen].max()) == 0.0                                     # the gated strands get nothing from it
    assert float(g[~seen].max()) > 0.0                                     # the shut ones do
    if source == "render":
        # the rendered direction is a fixed target: nothing reaches the render's own strands through it,
        # and no keyframe image enters (a different target direction map gives the same term)
        other = dataclasses.replace(toy.data, direction=-toy.data.direction)
        assert float(hidden_direction_term(canon.detach(), moved.detach(), hidden, out, other, frames,
                                           source)) == pytest.approx(float(term), abs=1e-6)
    assert "hidden_direction" in model.get_loss_dict(0)
    off = Stage2Model(toy.data, toy.codec, _cfg(weights={"hidden_direction": 1.0},
                                                switches={"use_visibility": False}), z0, m0)
    assert "hidden_direction" not in off.get_loss_dict(0)                  # nothing is hidden from the gate


def test_gate_from_binned_renders_with_exact_compositing(toy):
    """``gate_bins_every``: with exact compositing the gate takes the binned model's visibility of
    the same strands, made at the steps divisible by it and kept in between; the images stay exact."""
    pytest.importorskip("numba")
    z0, m0 = _start(toy)
    cfg = _cfg(render={"n_points": 16, "compositing": "exact"}, gate_bins_every=2, render_dense=0)
    model = Stage2Model(toy.data, toy.codec, cfg, z0, m0)
    seen = []
    for step in range(3):
        model.get_loss_dict(step)
        out, moved, frames = model.last_render, model.last_deformed, model.last_frames
        with torch.no_grad():
            bins = render_frames(moved, toy.data, frames, dataclasses.replace(cfg.render, compositing="bins"))
            exact = render_frames(moved, toy.data, frames, cfg.render)
        assert torch.equal(out.visibility, bins.visibility)
        assert torch.equal(out.depth.detach(), exact.depth)  # the images: the exact model's
        assert torch.equal(model.gate.mask, point_visibility(gate_visibility(bins.visibility, cfg.visibility_unit)))
        seen.append(out.visibility)
    assert seen[1] is seen[0] and seen[2] is not seen[0]  # made at steps 0 and 2, kept at step 1
    plain = Stage2Model(toy.data, toy.codec, dataclasses.replace(cfg, gate_bins_every=0), z0, m0)
    plain.get_loss_dict(0)
    with torch.no_grad():
        exact = render_frames(plain.last_deformed, toy.data, plain.last_frames, cfg.render)
    assert torch.equal(plain.last_render.visibility, exact.visibility)  # 0: the exact render's own
    # "auto" compositing is the exact model on the CPU, with the gate from the bins every 5 steps by
    # default; the default model, the bins, has no second render
    auto = Stage2Model(toy.data, toy.codec, _cfg(render={"n_points": 16, "compositing": "auto"}), z0, m0)
    assert auto.cfg.gate_bins_every == 5 and auto._gate_from_bins
    default = Stage2Model(toy.data, toy.codec, _cfg(render={"n_points": 16}), z0, m0)
    assert default.cfg.render.compositing == "bins" and not default._gate_from_bins


def test_resume_with_the_gate_from_binned_renders_is_the_same(toy):
    """A checkpoint between two binned renders holds the visibility the gate uses until the next
    one, so a fit resumed from it ends where the uninterrupted fit does (checkpoints every 3 steps,
    binned renders every 5)."""
    pytest.importorskip("numba")
    z0, m0 = _start(toy)
    cfg = _cfg(render={"n_points": 16, "compositing": "exact"}, gate_bins_every=5, render_dense=0)
    states = {}

    def keep(step, model, trainer):
        if step == 3:
            states["ck"] = copy.deepcopy(checkpoint_state(step, model, trainer))

    a = fit_stage2(toy.data, toy.codec, cfg, z0, m0, progress=False, on_step=keep)
    assert len(states["ck"]["bins_visibility"]) == 1  # made at step 0, for all three frames
    b = fit_stage2(toy.data, toy.codec, cfg, z0, m0, progress=False, resume=states["ck"])
    assert torch.allclose(a.z, b.z, atol=1e-6)
    stale = copy.deepcopy(states["ck"])
    stale["bins_visibility"] = []  # a checkpoint without it re-renders at step 4: another fit
    c = fit_stage2(toy.data, toy.codec, cfg, z0, m0, progress=False, resume=stale)
    assert not torch.allclose(a.z, c.z, atol=1e-6)
