"""Tests of the strand renderer (vid2haircut.render): frames and shapes, the Gaussians, the head's depth
map, the projection, chunking, CUDA, the near plane and the angle channel."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from vid2haircut.camera import look_at
from vid2haircut.render import mesh_depth, segment_gaussians

sys.path.insert(0, str(Path(__file__).parent))
from render_scenes import (BACKENDS, DT, backend, line, orbit_camera, quad_depth, random_scene,  # noqa: E402,F401
                           simple_camera)
from render_scenes import render_bins as render_strands  # noqa: E402  (the binned model on both backends)


# ---------------------------------------------------------------- batching and shapes


def test_batch_of_frames_equals_single_frames_and_shapes_vary(backend):
    size = 24
    K0, E0 = orbit_camera(size)
    E1 = look_at(np.array([0.1, 0.02, 0.22]), np.zeros(3))[None]
    pts = np.concatenate([random_scene(5), random_scene(6)])  # hair moves per frame
    K = torch.tensor(np.concatenate([K0, K0 * [[1.1], [1.1], [1]]]))
    E = torch.tensor(np.concatenate([E0, E1]))
    both = render_strands(torch.tensor(pts), K, E, size, size, backend=backend)
    for b in range(2):
        one = render_strands(torch.tensor(pts[b:b + 1]), K[b:b + 1], E[b:b + 1], size, size, backend=backend)
        for a, c in ((both.silhouette[b], one.silhouette[0]), (both.depth[b], one.depth[0]),
                     (both.direction[b], one.direction[0]), (both.depth_normalized[b], one.depth_normalized[0])):
            assert torch.allclose(a, c, atol=1e-9)
        assert torch.equal(both.visibility[b], one.visibility[0])
    # P = 2 (one segment per strand) and a different N on the next call
    two = render_strands(torch.tensor(pts[:1, :3, :2]), K[:1], E[:1], size, size, backend=backend)
    assert two.visibility.shape == (1, 3, 1) and float(two.silhouette.max()) > 0.5
    float_out = render_strands(torch.tensor(pts[:1, :2], dtype=torch.float32), K[:1].float(), E[:1].float(), 32, 20,
                               backend=backend)
    assert float_out.silhouette.shape == (1, 20, 32) and float_out.silhouette.dtype == torch.float32


def test_depth_normalized_in_unit_range_inside_mask(backend):
    size = 24
    K, E = (torch.tensor(a) for a in orbit_camera(size))
    out = render_strands(torch.tensor(random_scene(7)), K, E, size, size, backend=backend)
    dn, m = out.depth_normalized[0], out.mask[0]
    assert float(dn[m].min()) == 0.0 and abs(float(dn[m].max()) - 1.0) < 1e-9
    assert float(dn[~m].abs().max()) == 0.0


def test_gaussian_shape_follows_the_segment():
    K, E = simple_camera(64, f=500.0)
    seg = line([-0.01, 0.0, 0.5], [0.01, 0.0, 0.5], 2)[None, None]  # 20 mm long -> 20 px
    g = segment_gaussians(seg, K, E, strand_width=1e-3, dilation=0.0)
    sxx, sxy, syy = g.covs[0, 0].tolist()
    assert abs(sxx - 10.0**2) < 1e-6  # std along = half the segment length (10 px)
    assert abs(syy - 1.0**2) < 1e-6 and abs(sxy) < 1e-9  # std across = strand width (1 mm -> 1 px)
    assert torch.allclose(g.means[0, 0], torch.tensor([31.5, 31.5], dtype=DT))


def test_mesh_depth_of_tilted_plane_is_perspective_correct():
    size = 16
    c = (size - 1) / 2.0
    K = torch.tensor([[[20.0, 0, c], [0, 20.0, c], [0, 0, 1]]], dtype=DT)
    E = torch.eye(4, dtype=DT)[None]
    # plane z = 1 + 0.2 x, a large quad
    v = torch.tensor([[[x, y, 1.0 + 0.2 * x] for x in (-2.0, 2.0) for y in (-2.0, 2.0)]], dtype=DT)
    d = mesh_depth(v, torch.tensor([[0, 1, 3], [0, 3, 2]]), K, E, size, size)
    rx = (torch.arange(size, dtype=DT) - 7.5) / 20.0  # ray x per unit z; z = 1 + 0.2 * rx * z
    expect = 1.0 / (1.0 - 0.2 * rx)
    assert torch.allclose(d[0], expect.expand(size, size), atol=1e-9)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    size = 24
    K, E = (torch.tensor(a) for a in orbit_camera(size))
    pts = torch.tensor(random_scene(8))
    cpu = render_strands(pts, K, E, size, size)
    gpu = render_strands(pts.cuda(), K.cuda(), E.cuda(), size, size)
    assert torch.allclose(cpu.silhouette, gpu.silhouette.cpu(), atol=1e-9)
    assert torch.allclose(cpu.depth, gpu.depth.cpu(), atol=1e-9)


def test_chunked_kernels_match_single_chunk():
    """The CPU path processes elements in cache-sized chunks; results must not depend on the chunking."""
    from vid2haircut.render.api import DEFAULT_ALPHA_MIN
    from vid2haircut.render.footprint import build_footprint
    from vid2haircut.render.kernels import KernelConsts
    from vid2haircut.render.raster import composite

    size = 24
    K, E = (torch.tensor(a) for a in orbit_camera(size))
    pts = torch.tensor(np.concatenate([random_scene(9), random_scene(10)]), requires_grad=True)
    K, E = K.expand(2, 3, 3), E.expand(2, 4, 4)
    head = quad_depth(0.26, size, K[:1], torch.eye(4, dtype=DT)[None]).expand(2, size, size)
    results = []
    for chunk in (1 << 40, 64):
        g = segment_gaussians(pts, K, E)
        G = g.depths.numel()
        frame = torch.arange(2).repeat_interleave(g.depths.shape[1])
        fp = build_footprint(g.means.reshape(G, 2), g.covs.reshape(G, 3), g.valid.reshape(G), frame, size, size,
                             math.log(DEFAULT_ALPHA_MIN))
        consts = KernelConsts(0.0, DEFAULT_ALPHA_MIN, 0.99, 1e-3, 32, 0.3, True, chunk)
        sums, vis = composite(g.means.reshape(G, 2), g.covs.reshape(G, 3), g.depths.reshape(G), g.dirs.reshape(G, 2),
                              fp, 2, size, size, consts, head)
        loss = sums.log_transmittance.sum() + (sums.depth * 3).sum() + sums.dirs.sum()
        results.append((sums, vis, torch.autograd.grad(loss, pts)[0]))
        assert fp.u.shape[0] * fp.rows > 10 * 64  # really several chunks
    (a, va, ga), (b, vb, gb) = results
    for x, y in zip(a, b):
        assert torch.allclose(x, y, atol=1e-12)
    assert torch.equal(va, vb) and torch.allclose(ga, gb, atol=1e-10)


def test_projection_jacobian_matches_finite_differences():
    from vid2haircut.render.project import project_camera_points, projection_jacobian

    K = torch.tensor([[[300.0, 2.0, 40.0], [0.0, 310.0, 30.0], [0.0, 0.0, 1.0]]], dtype=DT)
    cam = torch.tensor([[[0.05, -0.03, 0.6], [-0.1, 0.02, 0.4]]], dtype=DT)
    J = projection_jacobian(cam, K)
    for i in range(3):
        d = torch.zeros(3, dtype=DT)
        d[i] = 1e-6
        num = (project_camera_points(cam + d, K)[0] - project_camera_points(cam - d, K)[0]) / 2e-6
        assert torch.allclose(J[..., i], num, atol=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_near_plane_zero_renders(backend):
    """near=0 is a valid setting (nothing is clipped but points behind the camera)."""
    pts = torch.tensor([[[[-0.02, 0.0, 0.5], [0.0, 0.0, 0.5], [0.02, 0.0, 0.5]]]], dtype=DT)
    K = torch.tensor([[[400.0, 0, 31.5], [0, 400.0, 31.5], [0, 0, 1]]], dtype=DT)
    a = render_strands(pts, K, torch.eye(4, dtype=DT)[None], 64, 64, backend=backend)
    b = render_strands(pts, K, torch.eye(4, dtype=DT)[None], 64, 64, backend=backend, near=0.0)
    assert float(a.silhouette.sum()) > 1 and torch.allclose(a.silhouette, b.silhouette)


def test_angle_is_read_from_direction_and_zero_where_empty():
    """StrandRender.angle: a in [0, pi) of the doubled-angle direction, 0 where direction is (0, 0)
    (signed zeros included: atan2(-0, -0) = -pi would give pi/2), detached."""
    from vid2haircut.render.types import StrandRender

    a = torch.tensor([0.0, 0.3, math.pi / 2, 2.9, math.pi - 1e-4])
    d = torch.stack([torch.cos(2 * a), torch.sin(2 * a)], -1)
    d = torch.cat([d, torch.tensor([[0.0, 0.0], [-0.0, -0.0], [-0.0, 0.0]])])[None, None].requires_grad_(True)
    z = torch.zeros(1, 1, 8)
    r = StrandRender(z, d, z, z, z.bool(), z.bool(), None)
    got = r.angle[0, 0]
    assert not got.requires_grad
    assert torch.allclose(got[:5], a, atol=1e-5)
    assert bool((got >= 0).all() and (got < math.pi).all())
    assert got[5:].tolist() == [0.0, 0.0, 0.0]
