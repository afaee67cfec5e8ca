"""Tests of the strand renderer (vid2haircut.render): physics, reference agreement, gradients."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch


sys.path.insert(0, str(Path(__file__).parent))
from render_scenes import (BACKENDS, DT, backend, line, orbit_camera, quad_depth, random_scene,  # noqa: E402,F401
                           simple_camera)
from render_scenes import render_bins as render_strands  # noqa: E402  (the binned model on both backends)
from render_reference import reference_render  # noqa: E402


# ---------------------------------------------------------------- physics


def test_empty_scene_renders_empty(backend):
    K, E = simple_camera()
    for pts in (torch.zeros(1, 0, 4, 3, dtype=DT),  # no strands
                line([-0.01, 0, -0.5], [0.01, 0, -0.5])[None, None],  # behind the camera
                line([5.0, 5.0, 0.5], [5.1, 5.0, 0.5])[None, None]):  # off-screen
        out = render_strands(pts, K, E, 32, 32, backend=backend)
        assert out.silhouette.shape == (1, 32, 32)
        assert float(out.silhouette.abs().max()) == 0.0
        assert float(out.depth.abs().max()) == 0.0
        assert float(out.direction.abs().max()) == 0.0
        assert not out.mask.any() and not out.visibility.any()
        assert out.visibility.shape == (1, pts.shape[1], 3 if pts.shape[2] == 4 else 5)


def test_empty_batches_render_and_differentiate(backend):
    """No frames, or frames without strands: empty / blank images and a gradient of the right shape
    (the torch backend had failed on both: reshapes with -1, and an in-place edit of an empty view)."""
    for B, N in ((0, 3), (2, 0), (0, 0)):
        K, E = simple_camera(batch=B)
        pts = torch.zeros(B, N, 5, 3, dtype=DT, requires_grad=True)
        for opacity in (None, 0.3):
            out = render_strands(pts, K, E, 24, 20, backend=backend, silhouette_opacity=opacity)
            assert out.silhouette.shape == out.depth.shape == out.mask.shape == (B, 20, 24)
            assert out.direction.shape == (B, 20, 24, 2) and out.visibility.shape == (B, N, 4)
            assert float(out.silhouette.abs().sum() + out.depth.abs().sum()) == 0.0
            (out.silhouette.sum() + out.depth.sum() + out.direction.sum()).backward()
            assert pts.grad.shape == pts.shape
            pts.grad = None


def test_horizontal_strand_is_thin_line_of_direction_zero(backend):
    K, E = simple_camera(33)
    pts = line([-0.02, 0.0, 0.5], [0.02, 0.0, 0.5], 9)[None, None]  # along x, through the optical axis
    out = render_strands(pts, K, E, 33, 33, backend=backend)
    sil = out.silhouette[0]
    c = 16  # the optical axis row
    # 40 mm at 0.5 m -> 32 px long; beaded between Gaussian centres (std = half a segment)
    assert float(sil[c, 6:27].min()) > 0.8 and float(sil[c, 6:27].max()) > 0.98
    assert float(sil[: c - 2].max()) < 1e-6 and float(sil[c + 3:].max()) < 1e-6  # thin
    m = out.mask[0]
    assert m.sum() >= 30
    assert float(out.angle[0][m].abs().max()) < 1e-6
    assert torch.allclose(out.direction[0][m], torch.tensor([1.0, 0.0], dtype=DT), atol=1e-6)
    assert torch.allclose(out.depth[0][m], torch.full((), 0.5, dtype=DT), atol=1e-9)
    assert out.visibility.all()
    # a vertical strand: angle pi/2, doubled-angle vector (-1, 0)
    out = render_strands(line([0.0, -0.02, 0.5], [0.0, 0.02, 0.5], 9)[None, None], K, E, 33, 33, backend=backend)
    m = out.mask[0]
    assert torch.allclose(out.angle[0][m], torch.full((), math.pi / 2, dtype=DT), atol=1e-6)
    assert torch.allclose(out.direction[0][m], torch.tensor([-1.0, 0.0], dtype=DT), atol=1e-6)


def test_strand_behind_head_is_hidden_and_invisible(backend):
    K, E = simple_camera(33)
    head = quad_depth(0.45, 33, K, E)
    assert torch.allclose(head[0], torch.full((33, 33), 0.45, dtype=DT))
    strand = line([-0.02, 0.0, 0.5], [0.02, 0.0, 0.5], 9)[None, None]
    visible = render_strands(strand, K, E, 33, 33, backend=backend)
    hidden = render_strands(strand, K, E, 33, 33, head_depth=head, backend=backend)
    assert visible.visibility.all() and float(visible.silhouette.max()) > 0.9
    assert float(hidden.silhouette.max()) == 0.0 and not hidden.visibility.any()
    front = render_strands(strand - torch.tensor([0, 0, 0.1], dtype=DT), K, E, 33, 33, head_depth=head,
                           backend=backend)
    assert front.visibility.all() and float(front.silhouette.max()) > 0.9


def test_strand_in_front_hides_the_other_in_depth(backend):
    K, E = simple_camera(33)
    horiz = line([-0.02, 0.0, 0.40], [0.02, 0.0, 0.40], 8)  # 8 points: a segment midpoint on the axis
    vert = line([0.0, -0.02, 0.42], [0.0, 0.02, 0.42], 8)
    for z_front, z_back, front, back, front_dir in ((0.40, 0.42, horiz, vert, (1.0, 0.0)),
                                                    (0.42, 0.40, horiz + torch.tensor([0, 0, 0.02], dtype=DT),
                                                     vert - torch.tensor([0, 0, 0.02], dtype=DT), (-1.0, 0.0))):
        out = render_strands(torch.stack([front, back])[None], K, E, 33, 33, backend=backend)
        d = out.depth[0, 16, 16]  # the crossing pixel: front alpha 0.99, 1 % of the back shows
        assert abs(float(d) - min(z_front, z_back)) < 3e-4, d
        assert torch.allclose(out.direction[0, 16, 16], torch.tensor(front_dir, dtype=DT), atol=0.05)
        assert out.visibility.all()  # both strands are seen away from the crossing
    # a dense sheet of strands in front hides a strand completely
    sheet = torch.stack([line([-0.03, y, 0.40], [0.03, y, 0.40], 9) for y in np.linspace(-0.01, 0.01, 41)])
    hidden = line([-0.005, -0.004, 0.43], [0.005, 0.004, 0.43], 9)[None]
    out = render_strands(torch.cat([sheet, hidden])[None], K, E, 33, 33, backend=backend)
    assert out.visibility[0, :-1].any() and not out.visibility[0, -1].any()
    assert float((out.depth[0][out.mask[0]] - 0.40).abs().max()) < 5e-4


# ---------------------------------------------------------------- reference agreement


@pytest.mark.parametrize("seed,with_head", [(0, False), (1, False), (2, True)])
def test_matches_reference(seed, with_head, backend):
    size = 20
    pts = random_scene(seed, spread=0.03)  # some strands leave the image
    K, E = orbit_camera(size)
    head = None
    if with_head:
        head_t = quad_depth(0.25, size, torch.tensor(K), torch.tensor(np.eye(4)[None]))  # camera z = 0.25
        head = head_t.numpy()
    ref = reference_render(pts, K, E, size, size, head_depth=head)
    out = render_strands(torch.tensor(pts), torch.tensor(K), torch.tensor(E), size, size,
                         head_depth=None if head is None else torch.tensor(head), backend=backend)
    sil = out.silhouette[0].numpy()
    # silhouette: exact (order independent)
    assert np.abs(sil - ref.silhouette[0]).max() < 1e-9
    assert ref.silhouette.max() > 0.9 and (ref.silhouette[0] > 0.5).sum() > 20
    m = ref.silhouette[0] > 0.5
    # depth: binned compositing; stated tolerance mean < 0.2 mm, p95 < 1 mm inside the mask
    err = np.abs(out.depth[0].numpy() - ref.depth[0])[m]
    assert err.mean() < 2e-4 and np.percentile(err, 95) < 1e-3, (err.mean(), err.max())
    # direction (doubled-angle unit vectors): mean L1 < 0.1
    derr = np.abs(out.direction[0].numpy() - ref.direction[0]).sum(-1)[m]
    assert derr.mean() < 0.1, derr.mean()
    # visibility agrees with the reference where the reference is clear-cut
    vis = out.visibility[0].reshape(-1).numpy()
    assert vis[ref.max_weight[0] > 0.6].all()
    assert not vis[ref.max_weight[0] < 0.05].any()


# ---------------------------------------------------------------- gradients


@pytest.mark.parametrize("channel", ["silhouette", "depth", "direction", "depth_normalized"])
def test_gradients_match_finite_differences(channel, backend):
    size = 16
    K, E = orbit_camera(size)
    pts = torch.tensor(random_scene(3, n=3, p=4, spread=0.015), requires_grad=True)
    gen = torch.Generator().manual_seed(0)
    R = torch.randn(1, size, size, 2, generator=gen, dtype=DT)
    K, E = torch.tensor(K), torch.tensor(E)

    def f(p):
        out = getattr(render_strands(p, K, E, size, size, backend=backend), channel)
        return (out * (R if out.ndim == 4 else R[..., 0])).sum()

    g = torch.autograd.grad(f(pts), pts)[0]
    assert float(g.abs().max()) > 0  # the gradient reaches the points
    assert torch.autograd.gradcheck(f, (pts,), eps=1e-7, atol=1e-5 * float(g.abs().max()), rtol=1e-3)


def test_silhouette_only_mode_matches(backend):
    size = 20
    K, E = (torch.tensor(a) for a in orbit_camera(size))
    pts = torch.tensor(random_scene(4), requires_grad=True)
    full = render_strands(pts, K, E, size, size, backend=backend)
    g_full = torch.autograd.grad(full.silhouette.square().sum(), pts)[0]
    sil = render_strands(pts, K, E, size, size, shading=False, backend=backend)
    g_sil = torch.autograd.grad(sil.silhouette.square().sum(), pts)[0]
    assert torch.allclose(full.silhouette, sil.silhouette, atol=1e-12)
    assert torch.allclose(g_full, g_sil, atol=1e-9)
    assert float(sil.depth.detach().abs().max()) == 0.0
