"""Tests of the strand renderer (vid2haircut.render): physics, reference agreement, gradients."""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from vid2haircut.camera import intrinsics_from_fov, look_at
from vid2haircut.render import mesh_depth, render_strands, segment_gaussians
from vid2haircut.render.numba_backend import numba_available

sys.path.insert(0, str(Path(__file__).parent))
from render_reference import reference_render  # noqa: E402

DT = torch.float64
BACKENDS = ["torch", pytest.param("numba", marks=pytest.mark.skipif(not numba_available(), reason="needs numba"))]


@pytest.fixture(params=BACKENDS)
def backend(request):
    """Every rendering test runs once per compositing backend."""
    return request.param


def simple_camera(size: int = 33, f: float = 400.0, batch: int = 1):
    """Camera at the origin looking down +z (identity extrinsics), principal point at the centre
    (odd sizes put the optical axis on a pixel centre)."""
    c = (size - 1) / 2.0
    K = torch.tensor([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]], dtype=DT).expand(batch, 3, 3)
    return K.contiguous(), torch.eye(4, dtype=DT).expand(batch, 4, 4).contiguous()


def line(p0, p1, n: int = 6) -> torch.Tensor:
    """[n, 3] points evenly spaced from p0 to p1."""
    t = torch.linspace(0, 1, n, dtype=DT)[:, None]
    return torch.tensor(p0, dtype=DT) * (1 - t) + torch.tensor(p1, dtype=DT) * t


def random_scene(seed: int, n: int = 6, p: int = 6, spread: float = 0.02):
    rng = np.random.default_rng(seed)
    roots = rng.uniform(-spread, spread, (n, 3))
    steps = rng.normal(0, 0.004, (n, p - 1, 3)) + np.array([0.0, -0.006, 0.0])
    return np.concatenate([roots[:, None], roots[:, None] + np.cumsum(steps, 1)], 1)[None]


def orbit_camera(size: int):
    K = intrinsics_from_fov(size, size, 30.0)[None]
    E = look_at(np.array([0.0, 0.0, 0.25]), np.zeros(3))[None]
    return K, E


def quad_depth(z: float, size: int, K, E):
    """Head depth of a camera-facing quad at camera depth z covering the view (via mesh_depth)."""
    v = torch.tensor([[[-1.0, -1.0, z], [1.0, -1.0, z], [1.0, 1.0, z], [-1.0, 1.0, z]]], dtype=DT)
    return mesh_depth(v, torch.tensor([[0, 1, 2], [0, 2, 3]]), K, E, size, size)


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


def test_bad_input_raises_clear_errors():
    K, E = simple_camera()
    with pytest.raises(ValueError, match="points"):
        render_strands(torch.zeros(1, 2, 3, dtype=DT), K, E, 32, 32)
    with pytest.raises(ValueError, match="at least 2 points"):
        render_strands(torch.zeros(1, 2, 1, 3, dtype=DT), K, E, 32, 32)
    with pytest.raises(ValueError, match="K must have shape"):
        render_strands(torch.zeros(2, 2, 3, 3, dtype=DT), K, E, 32, 32)
    with pytest.raises(ValueError, match="head_depth"):
        render_strands(torch.zeros(1, 2, 3, 3, dtype=DT), K, E, 32, 32, head_depth=torch.zeros(1, 16, 16))
    with pytest.raises(ValueError, match="image size"):
        render_strands(torch.zeros(1, 2, 3, 3, dtype=DT), K, E, 0, 32)
    with pytest.raises(ValueError, match="vis_weight"):
        render_strands(torch.zeros(1, 2, 3, 3, dtype=DT), K, E, 32, 32, vis_weight=0.0)


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


@pytest.mark.parametrize("backend", BACKENDS)
def test_bad_arguments_are_refused_before_any_kernel(backend):
    """Arguments a kernel would misread are refused up front: one depth bin (the numba kernels had
    written out of bounds: a crash), sizes that are not whole numbers or too large (tile counts
    overflow), half-precision points (covariances overflow to a blank image), non-finite or
    impossible cameras, widths and depth maps (blank or mirrored images)."""
    pts = torch.tensor([[[[-0.02, 0.0, 0.5], [0.0, 0.0, 0.5], [0.02, 0.0, 0.5]]]], dtype=DT)
    K = torch.tensor([[[400.0, 0, 31.5], [0, 400.0, 31.5], [0, 0, 1]]], dtype=DT)
    E = torch.eye(4, dtype=DT)[None]
    cases = [
        (dict(bins=1), ValueError, "2 <= bins <= 1024"),
        (dict(bins=10**9), ValueError, "2 <= bins <= 1024"),
        (dict(bins=2.5), TypeError, "bins must be a whole number"),
        (dict(depth_bin=float("nan")), ValueError, "finite depth_bin > 0"),
        (dict(width=64.5), TypeError, "width must be a whole number"),
        (dict(width=2**36, height=2**36), ValueError, "at most 16384 a side"),
        (dict(points=pts.half()), ValueError, "float32 or float64 tensor, got torch.float16"),
        (dict(K=K * float("nan")), ValueError, "K and world_2_cam must be finite"),
        (dict(K=K * 0.0), ValueError, "positive focal lengths"),
        (dict(world_2_cam=E * float("inf")), ValueError, "must be finite"),
        (dict(strand_width=-1e-3), ValueError, "strand_width, dilation and near >= 0"),
        (dict(strand_width=float("nan")), ValueError, "strand_width, dilation and near >= 0"),
        (dict(near=-1.0), ValueError, "strand_width, dilation and near >= 0"),
        (dict(dilation=-0.2), ValueError, "strand_width, dilation and near >= 0"),
        (dict(head_depth=torch.full((1, 64, 64), float("nan"), dtype=DT)), ValueError, "head_depth has NaN"),
        (dict(head_depth=torch.ones((1, 64, 64), dtype=torch.bool)), ValueError, "head_depth must be a float"),
    ]
    for kw, error, message in cases:
        args = dict(points=pts, K=K, world_2_cam=E, width=64, height=64, backend=backend)
        args.update(kw)
        with pytest.raises(error, match=re.escape(message)):
            render_strands(**args)
    # whole numbers of other types and a numpy head depth map are fine
    out = render_strands(pts, K, E, np.int64(64), torch.tensor(64), backend=backend,
                         head_depth=np.full((1, 64, 64), np.inf))
    assert float(out.silhouette.sum()) > 1
    # integer cameras are cast to the points' dtype (as before these checks), 64.0 is a whole number
    same = render_strands(pts, torch.tensor([[[400, 0, 31], [0, 400, 31], [0, 0, 1]]]), torch.eye(4, dtype=torch.int64)[None],
                          64.0, 64, backend=backend)
    assert float(same.silhouette.sum()) > 1
