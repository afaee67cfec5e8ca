"""Stage 2's deformation field: zero with the MLP off, zero weight at the root, the blockwise
evaluation against the concatenated MLP, the size of one step."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

from vid2haircut.fit.config import Stage2Config
from vid2haircut.fit.deform import deformation_weight, DeformationField, DeformConfig
from vid2haircut.fit.stage2 import Stage2Model

sys.path.insert(0, str(Path(__file__).parent))
from stage2_common import FAST, cfg as _cfg, make_toy, start as _start  # noqa: E402


@pytest.fixture(scope="module")
def toy():
    return make_toy()


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
