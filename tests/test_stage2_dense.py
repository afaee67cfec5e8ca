"""Stage 2 drawing the dense hair instead of the guides in its image terms (``render_dense``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vid2haircut.fit.config import Stage2Config
from vid2haircut.fit.outputs import dense_strands
from vid2haircut.fit.settings import apply_overrides
from vid2haircut.fit.stage2 import Stage2Model, fit_stage2
from vid2haircut.fit.toy import toy_problem

FAST = {"iterations": 10, "canonical_steps": 3, "ramp_steps": 2, "lr_z": 0.1, "render": {"n_points": 16},
        "n_dense": 300, "switches": {"use_deformation": False}, "render_dense": 150, "dense_from_step": 0}


@pytest.fixture(scope="module")
def toy():
    return toy_problem(size=40, n_frames=3, map_res=12, k=12)


def _cfg(**extra) -> Stage2Config:
    return apply_overrides(Stage2Config(), {**FAST, **extra})


def test_the_drawn_dense_strands_are_the_outputs_before_the_push_and_uneven_ends(toy):
    z0 = toy.z_gt + 0.3 * torch.randn(toy.z_gt.shape, generator=torch.Generator().manual_seed(0))
    model = Stage2Model(toy.data, toy.codec, _cfg(), z0, toy.mask.clone())
    drawn = model.dense()
    out = dense_strands(z0, toy.mask, toy.data.head, toy.codec, 150, model.cfg.seed, toy.data.head_model,
                        collision_margin=None)
    assert drawn.shape == (150, toy.codec.n_points, 3)
    assert np.allclose(drawn.detach().numpy(), out.points, atol=1e-6)
    drawn.sum().backward()                                    # differentiable in the hair map
    assert float(model.zmap.delta.grad.abs().sum()) > 0.0


def test_dense_drawing_fits_and_keeps_the_guides_for_the_anchor(toy):
    z0 = torch.zeros_like(toy.z_gt)
    res = fit_stage2(toy.data, toy.codec, _cfg(), z0, toy.mask.clone(), progress=False)
    t = res.history.terms
    image = [sum(t[k][i] for k in ("silhouette", "direction")) for i in (0, -1)]
    assert image[1] < 0.9 * image[0]
    moving = fit_stage2(toy.data, toy.codec, _cfg(switches={"use_deformation": True}), z0, toy.mask.clone(),
                        progress=False).history.terms
    assert not np.isnan(moving["motion"][-1]) and np.isnan(moving["motion"][0])   # the field joins after 3 steps
    model = Stage2Model(toy.data, toy.codec, _cfg(), z0, toy.mask.clone())
    guides = Stage2Model(toy.data, toy.codec, _cfg(render_dense=0), z0, toy.mask.clone())
    a, b = model.get_loss_dict(0), guides.get_loss_dict(0)
    assert torch.equal(model.points_seen, guides.points_seen)          # what the guides show, either way
    assert float(a["silhouette"].detach()) != float(b["silhouette"].detach())   # but a different picture
    assert model.gate.mask.shape[1] == 150                              # the gate acts on the drawn strands


def test_dense_strands_take_the_offsets_of_their_nearest_guide(toy):
    cfg = _cfg(switches={"use_deformation": True})
    model = Stage2Model(toy.data, toy.codec, cfg, torch.zeros_like(toy.z_gt), toy.mask.clone())
    own = model._dense_owner
    n = int(model.layout.texel_index.numel())
    assert own.shape == (150,) and int(own.min()) >= 0 and int(own.max()) < n
    assert len(torch.unique(own)) > n // 3                              # spread over the guides
    with torch.no_grad():                                                # a field that is not at rest
        model.deform.mlp[-1].weight.copy_(0.1 * torch.randn(model.deform.mlp[-1].weight.shape,
                                                            generator=torch.Generator().manual_seed(1)))
        model.deform.texel_embed.weight[int(own[0])] += 1.0              # move one guide's embedding
    guides = model.canonical()[:, model.layout.render_index].detach()
    drawn = model.dense()[:, model.layout.render_index].detach()
    moved, offs, g_moved = model.deformed(drawn, torch.tensor([1]), 0.5, guides)
    expect = 0.5 * model.deform.offsets(guides, 1)
    assert float(expect.abs().max()) > 1e-4
    torch.testing.assert_close(offs[0], expect[own])                     # point by point, nearest guide
    seg = (moved[0, :, 1:] - moved[0, :, :-1]).norm(dim=-1)
    torch.testing.assert_close(seg, (drawn[:, 1:] - drawn[:, :-1]).norm(dim=-1))   # lengths kept
    assert float((moved[0] - drawn).abs().max()) > 1e-5
    torch.testing.assert_close(g_moved[0, :, 0], guides[:, 0])             # the guides move too, roots fixed
    assert float((g_moved[0] - guides).abs().max()) > 1e-5
    with torch.no_grad():
        model.deform.texel_embed.weight[int(own[0])] -= 1.0
    _, rest, _ = model.deformed(drawn, torch.tensor([1]), 0.5, guides)
    changed = (offs - rest).abs().amax((0, 2, 3)) > 0
    assert torch.equal(changed, own == own[0])                           # exactly the strands it owns


def test_the_moved_hairs_penetration_is_the_moved_guides(toy):
    """The dense strands, decoded without the push out of the head, may reach into it where no
    guide does; the deformed phase's penetration term takes the moved guides, not them."""
    from vid2haircut.fit.losses import penetration_loss

    cfg = _cfg(switches={"use_deformation": True}, penetration_margin=-0.01)   # 1 cm of standoff: non-zero
    z0 = toy.z_gt + 0.3 * torch.randn(toy.z_gt.shape, generator=torch.Generator().manual_seed(2))
    model = Stage2Model(toy.data, toy.codec, cfg, z0, toy.mask.clone())
    with torch.no_grad():
        model.deform.mlp[-1].bias.fill_(0.5)                             # a field that moves the hair
    step = cfg.canonical_steps + cfg.ramp_steps                          # full scale
    losses = model.get_loss_dict(step)
    canon = model.canonical()
    guides = canon[:, model.layout.render_index]
    _, _, moved_guides = model.deformed(model.dense()[:, model.layout.render_index], model.frames_for_step(step),
                                        1.0, guides)
    sdf, m = toy.data.head.sdf, cfg.penetration_margin
    expect = penetration_loss(canon, sdf, m) + penetration_loss(moved_guides, sdf, m)
    torch.testing.assert_close(losses["penetration"], expect)
    drawn_moved = model.last_deformed
    assert float(penetration_loss(drawn_moved, sdf, m)) != float(penetration_loss(moved_guides, sdf, m))


def test_the_guides_are_drawn_before_dense_from_step(toy):
    model = Stage2Model(toy.data, toy.codec, _cfg(dense_from_step=5), torch.zeros_like(toy.z_gt), toy.mask.clone())
    n = int(model.layout.texel_index.numel())
    assert not model.draws_dense(4) and model.draws_dense(5)
    model.get_loss_dict(4)
    assert model.gate.mask.shape[1] == n                                # the guides
    model.get_loss_dict(5)
    assert model.gate.mask.shape[1] == 150                              # the dense strands
    assert not Stage2Model(toy.data, toy.codec, _cfg(render_dense=0, dense_from_step=5), torch.zeros_like(toy.z_gt),
                           toy.mask.clone()).draws_dense(9)


def test_by_default_the_dense_strands_are_drawn_from_the_end_of_the_canonical_steps(toy):
    cfg = Stage2Config()
    assert cfg.render_dense > 0 and cfg.dense_from_step < 0
    model = Stage2Model(toy.data, toy.codec, _cfg(dense_from_step=-1), torch.zeros_like(toy.z_gt), toy.mask.clone())
    c = model.cfg.canonical_steps
    assert not model.draws_dense(c - 1) and model.draws_dense(c)


def test_the_gate_zeroes_the_gradient_of_the_dense_points_a_frame_does_not_show(toy):
    from vid2haircut.fit.scene import image_losses, render_frames
    from vid2haircut.fit.visibility import gate_visibility, point_visibility

    grads = {}
    for use in (True, False):
        cfg = _cfg(switches={"use_deformation": False, "use_visibility": use}, visibility_unit="segment")
        model = Stage2Model(toy.data, toy.codec, cfg, torch.zeros_like(toy.z_gt), toy.mask.clone())
        drawn = model.dense()[:, model.layout.render_index].detach().requires_grad_(True)
        frames = torch.tensor([1])                                           # one side view
        moved, _, _ = model.deformed(drawn, frames, 0.0)
        out = render_frames(moved, toy.data, frames, model.cfg.render)
        model.gate.set_visibility(gate_visibility(out.visibility, cfg.visibility_unit))
        loss = image_losses(out, toy.data, frames)
        (loss["silhouette"] + loss["direction"]).backward()
        grads[use] = (drawn.grad.norm(dim=-1), out.visibility[0])
    (g_on, vis), (g_off, _) = grads[True], grads[False]
    pv = point_visibility(vis)
    assert pv.shape == g_on.shape and pv.any() and (~pv).any()
    assert float(g_on[~pv].abs().max()) == 0.0                               # hidden dense points get nothing
    assert float(g_off[~pv].abs().max()) > 0.0
    torch.testing.assert_close(g_on[pv], g_off[pv])
