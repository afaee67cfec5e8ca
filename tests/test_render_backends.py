"""Renderer backends: fused numba CPU kernels vs the torch path (values, gradients, determinism)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vid2haircut.camera import look_at
from vid2haircut.render.numba_backend import numba_available, resolve_backend

from render_scenes import DT, orbit_camera, quad_depth, random_scene  # noqa: F401
from render_scenes import render_bins as render_strands  # (the binned model on both backends)


def _backend_scene(dtype):
    """Two frames of 40 wavy strands x 8 points crossing at mm depth spacing, 48 x 40 px, a head plane."""
    size_w, size_h = 48, 40
    K0, E0 = orbit_camera(size_w)
    K0[:, 1, 2] -= 4.0  # principal point of a 48 x 40 image
    E1 = look_at(np.array([0.08, 0.03, 0.23]), np.zeros(3))[None]
    pts = np.concatenate([random_scene(20, n=40, p=8, spread=0.025), random_scene(21, n=40, p=8, spread=0.025)])
    K = torch.tensor(np.concatenate([K0, K0]), dtype=dtype)
    E = torch.tensor(np.concatenate([E0, E1]), dtype=dtype)
    head = quad_depth(0.252, size_w, torch.tensor(K0), torch.eye(4, dtype=DT)[None])[:, :size_h].expand(2, -1, -1)
    return torch.tensor(pts, dtype=dtype, requires_grad=True), K, E, size_w, size_h, head.to(dtype).contiguous()


def _render_and_grad(backend, dtype, shading=True, torch_projection=False):
    pts, K, E, w, h, head = _backend_scene(dtype)
    if torch_projection:  # cameras that require gradients keep the numba backend on the torch projection
        K.requires_grad_(True)
    gen = torch.Generator().manual_seed(1)
    R = torch.randn(2, h, w, 2, generator=gen, dtype=dtype)
    out = render_strands(pts, K, E, w, h, head_depth=head, backend=backend, shading=shading)
    loss = (out.silhouette * R[..., 0]).sum() + (out.depth_normalized * R[..., 1]).sum() + (out.direction * R).sum()
    return out, torch.autograd.grad(loss, pts)[0]


def _assert_same_render(a, b):
    """Every image channel and the visibility of two StrandRenders bit for bit equal."""
    for name in ("silhouette", "direction", "angle", "depth", "depth_normalized", "mask", "visibility"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name


@pytest.mark.skipif(not numba_available(), reason="needs numba")
@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-9), (torch.float32, 1e-5)])
def test_backends_agree_on_random_scene(dtype, tol):
    """The numba and torch kernels implement the same model: values and gradients agree to round-off.

    In float32 both composite the same Gaussians (the torch projection): the numba projection's
    last-bit differences (checked in :func:`test_fused_projection_matches_torch`) can move a
    contribution across the alpha_min cut, a discrete change far above round-off."""
    a, ga = _render_and_grad("torch", dtype)
    b, gb = _render_and_grad("numba", dtype, torch_projection=dtype == torch.float32)
    assert a.mask.sum() > 300 and a.visibility.any() and not a.visibility.all()  # a busy, partly hidden scene
    for name in ("silhouette", "depth", "depth_normalized", "direction"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == dtype and x.shape == y.shape
        assert float((x - y).detach().abs().max()) < tol, name
    assert torch.equal(a.visibility, b.visibility) and torch.equal(a.mask, b.mask)
    assert float((ga - gb).abs().max()) < tol * float(ga.abs().max())
    # silhouette only
    (a, ga), (b, gb) = (_render_and_grad("torch", dtype, False),
                        _render_and_grad("numba", dtype, False, torch_projection=dtype == torch.float32))
    assert float((a.silhouette - b.silhouette).detach().abs().max()) < tol
    assert float((ga - gb).abs().max()) < tol * float(ga.abs().max())


@pytest.mark.skipif(not numba_available(), reason="needs numba")
def test_default_float32_path_is_close_to_torch():
    """The float32 numba path as the pipeline runs it (its own projection and windows) against
    the torch backend: last-bit differences of the Gaussians may move a contribution across the
    alpha_min cut (a step of ~0.01 in alpha) at a few pixels, nothing more."""
    a, ga = _render_and_grad("torch", torch.float32)
    b, gb = _render_and_grad("numba", torch.float32)
    for name in ("silhouette", "depth_normalized"):
        d = (getattr(a, name) - getattr(b, name)).detach().abs()
        assert float(d.mean()) < 1e-6 and float((d > 1e-4).float().mean()) < 0.005, name
    d = (a.direction - b.direction).detach().abs().amax(-1)
    assert float((d > 1e-3).float().mean()) < 0.005
    assert float((a.mask != b.mask).float().mean()) < 0.005
    assert float((a.visibility != b.visibility).float().mean()) < 0.005
    cos = float((ga * gb).sum() / (ga.norm() * gb.norm()))
    assert cos > 0.9999  # measured: 5e-8 mean silhouette difference, no pixel off by 1e-4, cos 1 - 1e-7


@pytest.mark.skipif(not numba_available(), reason="needs numba")
@pytest.mark.parametrize("dtype,p", [(torch.float64, 8), (torch.float32, 8), (torch.float64, 2), (torch.float64, 5),
                                     (torch.float64, 19), (torch.float32, 19)])
def test_fused_projection_matches_torch(dtype, p):
    """The numba projection (numba_project.py) gives the torch projection's Gaussian table, and in
    float64 its gradient w.r.t. the points, for strands of p points (the kernels pad each strand's
    segments to whole vectors) with a strand of NaN and some drawn segments whose neighbours are not."""
    from vid2haircut.render.gaussians import segment_gaussians
    from vid2haircut.render.numba_ops import gaussian_table, project_fused

    pts, K, E, w, h, _ = _backend_scene(dtype)
    B, N = pts.shape[:2]
    pts = torch.nn.functional.interpolate(pts.detach().reshape(B * N, 8, 3).transpose(1, 2), size=p, mode="linear",
                                          align_corners=True).transpose(1, 2).reshape(B, N, p, 3)
    pts = torch.cat([pts, torch.full_like(pts[:, :1], float("nan"))], 1).requires_grad_(True)
    g = segment_gaussians(pts, K, E, 0.004, 0.3, 1e-2)
    G = g.depths.numel()
    ref = gaussian_table(g.means.reshape(G, 2), g.covs.reshape(G, 3), g.depths.reshape(G), g.dirs.reshape(G, 2))
    table, covs, valid = project_fused(pts, K, E, 0.004, 0.3, 1e-2)
    assert torch.equal(valid, g.valid.reshape(G)) and not valid.all()  # the NaN strand is invalid
    rtol = 1e-13 if dtype == torch.float64 else 2e-6
    with torch.no_grad():
        scale = ref[valid].abs().amax(0)
        assert float(((table - ref)[valid].abs() / scale).max()) < rtol
        cref = g.covs.reshape(G, 3)[valid]
        assert float(((covs[valid] - cref).abs() / cref.abs().amax(0)).max()) < rtol
    weights = torch.randn(G, 8, generator=torch.Generator().manual_seed(3), dtype=dtype) * valid[:, None]
    weights[::3] = 0.0  # segments the loss does not see, between seen ones
    (gr,) = torch.autograd.grad((torch.nan_to_num(ref) * weights).sum(), pts)
    (gf,) = torch.autograd.grad((table * weights).sum(), pts)
    ok = torch.isfinite(pts).all(-1)
    assert torch.isfinite(gf).all() and float((gf - gr)[ok].abs().max()) < 50 * rtol * float(gr[ok].abs().max())


@pytest.mark.skipif(not numba_available(), reason="needs numba")
def test_numba_backend_is_deterministic_for_any_thread_count():
    threads = torch.get_num_threads()
    try:
        runs = []
        for n in (1, 2, 2):
            torch.set_num_threads(n)  # the numba kernels use as many threads as torch
            runs.append(_render_and_grad("numba", torch.float32))
    finally:
        torch.set_num_threads(threads)
    (a, ga), *rest = runs
    for b, gb in rest:
        _assert_same_render(a, b)
        assert torch.equal(ga, gb)


@pytest.mark.skipif(not numba_available(), reason="needs numba")
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_walk_compaction_by_loop_equals_compress(dtype, monkeypatch):
    """The window walk's two ways of appending the kept lanes (numba_simd.line16 with this CPU's
    compaction, or the numba loop) give identical renders and gradients."""
    from vid2haircut.render import numba_simd

    runs = []
    for compress in (False, True):
        monkeypatch.setattr(numba_simd, "USE_LINE16", compress)
        runs.append(_render_and_grad("numba", dtype))
    (a, ga), (b, gb) = runs
    _assert_same_render(a, b)
    assert torch.equal(ga, gb)


@pytest.mark.skipif(not numba_available(), reason="needs numba")
@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-10), (torch.float32, 2e-5)])
@pytest.mark.parametrize("sop", [0.3, 0.995])
def test_translucent_silhouette_from_one_walk(dtype, tol, sop):
    """``silhouette_opacity`` below the opacity: the numba backend's one-walk silhouette equals a
    second, silhouette-only render at that opacity (values and gradients), the rest is the opaque
    render's; the torch backend (two renders) agrees. 0.995 reaches the ``alpha_max`` clamp."""
    pts, K, E, w, h, head = _backend_scene(dtype)
    R = torch.randn(2, h, w, 3, generator=torch.Generator().manual_seed(2), dtype=dtype)

    def loss(out):
        return (out.silhouette * R[..., 0]).sum() + (out.depth_normalized * R[..., 1]).sum() + \
            (out.direction[..., 0] * R[..., 2]).sum()

    one = render_strands(pts, K, E, w, h, head_depth=head, backend="numba", silhouette_opacity=sop)
    opaque = render_strands(pts, K, E, w, h, head_depth=head, backend="numba")
    sil = render_strands(pts, K, E, w, h, head_depth=head, backend="numba", opacity=sop, shading=False)
    two = opaque._replace(silhouette=sil.silhouette)
    assert float((one.silhouette - two.silhouette).detach().abs().max()) < tol
    if sop < 0.5:
        assert float((one.silhouette - opaque.silhouette).detach().abs().max()) > 0.1  # it is translucent
    for name in ("depth", "direction", "mask", "visibility"):
        assert torch.equal(getattr(one, name), getattr(two, name)), name
    (g1,) = torch.autograd.grad(loss(one), pts)
    (g2,) = torch.autograd.grad(loss(two), pts)
    assert float((g1 - g2).abs().max()) < tol * float(g2.abs().max())
    if dtype == torch.float64:
        t = render_strands(pts, K, E, w, h, head_depth=head, backend="torch", silhouette_opacity=sop)
        assert float((t.silhouette - one.silhouette).detach().abs().max()) < tol
        (gt,) = torch.autograd.grad(loss(t), pts)
        assert float((gt - g1).abs().max()) < 1e-9 * float(gt.abs().max())
        # without shading: the silhouette alone, the same on both backends
        kw = dict(head_depth=head, silhouette_opacity=sop, shading=False)
        n, t = (render_strands(pts, K, E, w, h, backend=b, **kw) for b in ("numba", "torch"))
        assert float((n.silhouette - t.silhouette).detach().abs().max()) < tol
        (gn,) = torch.autograd.grad((n.silhouette * R[..., 0]).sum(), pts)
        (gt,) = torch.autograd.grad((t.silhouette * R[..., 0]).sum(), pts)
        assert float((gn - gt).abs().max()) < 1e-9 * float(gt.abs().max())
    for bad in (0.0, 0.005):  # at or below alpha_min (exp(-4.5) = 0.011): both backends refuse it
        for backend in ("numba", "torch"):
            with pytest.raises(ValueError, match="silhouette_opacity"):
                render_strands(pts, K, E, w, h, backend=backend, silhouette_opacity=bad)


def test_backend_choice():
    pts = torch.zeros(1, 1, 2, 3)
    assert resolve_backend("torch", pts) == "torch"
    assert resolve_backend("auto", pts) == ("numba" if numba_available() else "torch")
    assert resolve_backend("auto", pts.half()) == "torch"
    with pytest.raises(ValueError, match="backend must be one of"):
        resolve_backend("fast", pts)
    with pytest.raises(ValueError, match="numba"):
        resolve_backend("numba", pts.half())


@pytest.mark.skipif(not numba_available(), reason="needs numba")
def test_numba_backend_from_two_python_threads():
    """Concurrent renders (e.g. from a thread pool) wait for each other instead of crashing."""
    from concurrent.futures import ThreadPoolExecutor

    ref = _render_and_grad("numba", torch.float64)
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(lambda _: _render_and_grad("numba", torch.float64), range(4)))
    for out, grad in results:
        assert torch.equal(out.silhouette, ref[0].silhouette) and torch.equal(grad, ref[1])


@pytest.mark.skipif(not numba_available(), reason="needs numba")
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_hidden_tile_instances_are_culled_without_changing_the_render(dtype, monkeypatch):
    """(Gaussian, tile) pairs that the head hides at every pixel of the tile are not listed; the
    renders and gradients are bit for bit those listing them, and NaN depths are never culled."""
    from vid2haircut.render import numba_tiles

    counts, runs = [], []
    real, real_hmax = numba_tiles.bin_windows, numba_tiles.tile_head_max

    def counting(*args):
        res = real(*args)
        counts.append(res[1].shape[0])
        return res

    monkeypatch.setattr(numba_tiles, "bin_windows", counting)
    runs.append(_render_and_grad("numba", dtype))
    monkeypatch.setattr(numba_tiles, "tile_head_max", lambda *a: np.full_like(real_hmax(*a), np.inf))  # no culling
    runs.append(_render_and_grad("numba", dtype))
    (a, ga), (b, gb) = runs
    assert counts[0] < counts[1]  # the head plane hides some whole tiles of some windows
    _assert_same_render(a, b)
    assert torch.equal(ga, gb)
    # the rule itself: an instance is dropped where z >= the tile's largest head depth, NaN kept
    wint = np.array([[1, 0, 8, 4]] * 3, np.int64)  # horizontal windows over x 0..7, rows 0..3
    wflt = np.zeros((3, 2), np.float32)
    hmax = np.array([1.0, np.inf], dtype=np.float64)  # two tiles of 8 x 8 in a 16 x 8 image
    wint[2, 1] = 8  # the third window lies in the second tile
    z = np.array([1.0, np.nan, 5.0])
    gstart, inst_pos, tile_start, sorted_g, _, _ = real(wint, wflt, np.zeros(3, np.int64), 1, 16, 8, 8, z, hmax, False)
    assert list(tile_start) == [0, 1, 2] and list(sorted_g) == [1, 2] and list(gstart) == [0, 0, 1, 2]
