"""Depth that also covers the visible head: synthetic depth maps, depth targets, and the fit's depth term."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from vid2haircut.fit.image_terms import depth_loss
from vid2haircut.fit.scene import image_losses
from vid2haircut.front.targets.depth import normalise_depth
from vid2haircut.synth.sequence import relative_depth

H = W = 20


def _scene():
    """Head on the left half (camera z 1.05), hair on the right half (0.95 + a ramp), as (H,W) arrays."""
    cols = np.arange(W)[None, :].repeat(H, 0)
    rows = np.arange(H)[:, None].repeat(W, 1)
    hair = (cols >= W // 2).astype(np.float32)
    hair_z = np.where(hair > 0, 0.95 + 0.002 * rows + 0.001 * cols, np.nan).astype(np.float32)
    head = (cols < W // 2).astype(np.float32)
    head_z = np.where(head > 0, 1.05 + 0.001 * rows, np.nan).astype(np.float32)
    return hair, hair_z, head, head_z


def test_relative_depth_covers_the_visible_head_only_when_asked():
    hair, hair_z, head, head_z = _scene()
    d0, v0 = relative_depth(hair, hair_z)
    assert v0.sum() == (hair >= 0.5).sum() and d0[v0].min() == 0.0 and d0[v0].max() == 1.0
    d1, v1 = relative_depth(hair, hair_z, head, head_z)
    assert v1.all()                                                  # hair and head: every pixel here
    z = np.where(hair > 0, hair_z, head_z)
    expect = (z - z.min()) / (z.max() - z.min())
    assert np.allclose(d1, expect, atol=2 ** -16)
    assert d1[head > 0].min() > d1[hair > 0].max()                   # the head lies behind the hair
    hidden = head.copy()
    hidden[:, :3] = 0.4                                              # mostly hidden by hair: not a target
    _, v2 = relative_depth(hair, hair_z, hidden, head_z)
    assert not v2[:, :3].any() and v2[:, 3:].all()


def test_normalise_depth_keeps_the_head_in_the_hair_normalisation():
    hair, hair_z, head, head_z = _scene()
    raw = np.where(hair > 0, hair_z, head_z)
    d0, v0 = normalise_depth(raw, np.ones_like(hair, bool), hair)
    d1, v1 = normalise_depth(raw, np.ones_like(hair, bool), hair, context=True)
    assert (v0 == (hair >= 0.5)).all() and v1.all()
    assert np.array_equal(d0[v0], d1[v0])                            # the hair's values do not change
    lo, hi = np.quantile(raw[hair > 0], (0.05, 0.95))
    assert np.allclose(d1[head > 0], (raw[head > 0] - lo) / (hi - lo), atol=1e-6)
    assert float(d1[head > 0].min()) > 1.0                           # behind the hair's far quantile


def _fit_inputs(shift: float):
    """Rendered hair (right half) at the true depth plus ``shift`` metres, and the targets with context."""
    hair, hair_z, head, head_z = _scene()
    raw = np.where(hair > 0, hair_z, head_z)
    target, valid = normalise_depth(raw, np.ones_like(hair, bool), hair, context=True)
    t = lambda a: torch.as_tensor(a)[None]                            # noqa: E731
    depth = t(np.nan_to_num(hair_z) + shift * hair).requires_grad_(True)
    out = SimpleNamespace(silhouette=t(hair), direction=torch.zeros(1, H, W, 2), mask=t(hair > 0), depth=depth)
    data = SimpleNamespace(mask=t(hair), confidence=t(hair), direction=torch.zeros(1, H, W, 2), depth=t(target),
                           depth_valid=t(valid), head_depth=t(np.where(head > 0, head_z, np.inf).astype(np.float32)))
    return out, data


def test_depth_term_with_the_head_sees_how_far_the_hair_stands_off_it():
    frames = torch.zeros(1, dtype=torch.long)
    for align in ("affine", "quantile"):
        out, data = _fit_inputs(0.0)
        assert float(image_losses(out, data, frames, align, depth_head=True)["depth"].detach()) < 1e-4
        out, data = _fit_inputs(0.02)                                  # the hair 2 cm nearer the head
        off = image_losses(out, data, frames, align)["depth"]
        on = image_losses(out, data, frames, align, depth_head=True)["depth"]
        assert float(off.detach()) < 1e-4 < 0.05 < float(on.detach())   # the hair alone cannot tell
        on.backward()
        g = out.depth.grad[0]
        assert float(g[:, W // 2:].abs().sum()) > 0 and float(g[:, : W // 2].abs().sum()) == 0.0
        # off is the hair-only term as before
        ref = depth_loss(out.depth, out.mask, data.depth, data.depth_valid, align=align)
        assert float(off.detach()) == pytest.approx(float(ref.detach()))


def test_depth_head_needs_the_head_occluder_and_leaves_hair_only_targets_alone():
    frames = torch.zeros(1, dtype=torch.long)
    out, data = _fit_inputs(0.02)
    data.head_depth = None
    assert float(image_losses(out, data, frames, "affine", depth_head=True)["depth"].detach()) < 1e-4
    out, data = _fit_inputs(0.02)
    data.depth_valid = data.depth_valid & (data.mask > 0.5)             # targets of the hair only
    a = image_losses(out, data, frames, "affine", depth_head=True)["depth"]
    b = image_losses(out, data, frames, "affine")["depth"]
    assert float(a.detach()) == float(b.detach())


def test_synthesised_depth_maps_cover_the_visible_head_with_depth_context(tmp_path):
    from dataclasses import replace

    from vid2haircut.io.sequence import open_sequence
    from vid2haircut.synth.sequence import SynthConfig, synthesize_sequence

    cfg = SynthConfig(family="bob", seed=3, n_frames=2, width=96, height=96, n_strands=400, n_points=16,
                      landmark_noise_px=0.0, image_format="png")
    maps = {}
    for context in (False, True):
        root = tmp_path / str(context)
        synthesize_sequence(root, "synth_0001", "HAIR", replace(cfg, depth_context=context))
        seq = open_sequence(root, "synth_0001", "HAIR")
        maps[context] = (seq.read_depth(0), seq.read_hair_mask(0), seq.read_alpha(0))
        seq.close()
    (d0, v0), hair, alpha = maps[False]
    (d1, v1), _, _ = maps[True]
    assert v0.sum() > 100 and (v1 & ~v0).sum() > 100                 # the head adds pixels, where no hair is
    assert (v0 & ~v1).sum() == 0 and (hair[v1 & ~v0] < 0.5).all() and (alpha[v1 & ~v0] > 0.4).all()
    slope, shift = np.polyfit(d0[v0], d1[v0], 1)                      # the hair: the same depths, rescaled
    assert slope > 0 and np.abs(d1[v0] - (slope * d0[v0] + shift)).max() < 1e-3

