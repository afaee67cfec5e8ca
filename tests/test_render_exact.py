"""The renderer's exact front-to-back compositing (``compositing="exact"``, numba backend):
against the per-pixel reference, finite differences, the physical tests, early termination."""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from vid2haircut.render import render_strands
from vid2haircut.render.numba_backend import numba_available

sys.path.insert(0, str(Path(__file__).resolve().parent))
import render_scenes as tr  # noqa: E402  (the renderer tests' scenes and cameras)
import test_render  # noqa: E402  (physical tests)
import test_render_frames  # noqa: E402  (frames and shapes)
from render_reference import reference_render  # noqa: E402

pytestmark = pytest.mark.skipif(not numba_available(), reason="needs numba")
DT = torch.float64
exact = functools.partial(render_strands, backend="numba", compositing="exact")


@pytest.mark.parametrize("seed,with_head", [(0, False), (1, False), (2, True), (5, False)])
def test_exact_matches_reference(seed, with_head):
    """Every channel equals the reference's to round-off (the bins' depth error was 0.015-0.07 mm)."""
    size = 20
    pts = tr.random_scene(seed, spread=0.03)
    K, E = tr.orbit_camera(size)
    head = tr.quad_depth(0.25, size, torch.tensor(K), torch.tensor(np.eye(4)[None])).numpy() if with_head else None
    ref = reference_render(pts, K, E, size, size, head_depth=head)
    out = exact(torch.tensor(pts), torch.tensor(K), torch.tensor(E), size, size,
                head_depth=None if head is None else torch.tensor(head))
    m = ref.silhouette[0] > 0.5
    assert m.sum() > 20
    assert np.abs(out.silhouette[0].numpy() - ref.silhouette[0]).max() < 1e-12
    assert np.abs(out.depth[0].numpy() - ref.depth[0])[m].max() < 1e-12
    assert np.abs(out.direction[0].numpy() - ref.direction[0]).sum(-1)[m].max() < 1e-8
    clear = np.abs(ref.max_weight[0] - 0.3) > 1e-9  # the visibility test at weight 0.3, as the reference's
    vis = out.visibility[0].reshape(-1).numpy()
    assert np.array_equal(vis[clear], (ref.max_weight[0] >= 0.3)[clear])


@pytest.mark.parametrize("channel", ["silhouette", "depth", "direction", "depth_normalized"])
def test_exact_gradients_match_finite_differences(channel):
    size = 16
    K, E = (torch.tensor(a) for a in tr.orbit_camera(size))
    pts = torch.tensor(tr.random_scene(3, n=3, p=4, spread=0.015), requires_grad=True)
    R = torch.randn(1, size, size, 2, generator=torch.Generator().manual_seed(0), dtype=DT)

    def f(p):
        out = getattr(exact(p, K, E, size, size), channel)
        return (out * (R if out.ndim == 4 else R[..., 0])).sum()

    g = torch.autograd.grad(f(pts), pts)[0]
    assert float(g.abs().max()) > 0
    assert torch.autograd.gradcheck(f, (pts,), eps=1e-7, atol=1e-5 * float(g.abs().max()), rtol=1e-3)


@pytest.mark.parametrize("test", ["test_empty_scene_renders_empty", "test_empty_batches_render_and_differentiate",
                                  "test_horizontal_strand_is_thin_line_of_direction_zero",
                                  "test_strand_behind_head_is_hidden_and_invisible",
                                  "test_strand_in_front_hides_the_other_in_depth",
                                  "test_batch_of_frames_equals_single_frames_and_shapes_vary",
                                  "test_depth_normalized_in_unit_range_inside_mask", "test_near_plane_zero_renders"])
def test_physical_tests_hold_for_exact(test, monkeypatch):
    """The renderer's physical and shape tests (tests/test_render.py, test_render_frames.py), every
    render there made exact."""
    module = test_render if hasattr(test_render, test) else test_render_frames
    monkeypatch.setattr(module, "render_strands", functools.partial(render_strands, compositing="exact"))
    getattr(module, test)("numba")


def test_early_termination():
    """A pixel stops once its transmittance is below t_min: what lies behind adds nothing there,
    the silhouette is off by less than t_min, and no gradient reaches what was not composited."""
    K, E = tr.simple_camera(33)
    front = tr.line([-0.02, 0.0, 0.40], [0.02, 0.0, 0.40], 8)  # alpha 0.99 at the crossing: T = 0.01 behind
    back = tr.line([0.0, -0.02, 0.42], [0.0, 0.02, 0.42], 8)
    pts = torch.stack([front, back])[None].requires_grad_(True)
    deep = exact(pts, K, E, 33, 33, t_min=1e-12)
    cut = exact(pts, K, E, 33, 33, t_min=0.05)
    alone = exact(front[None, None], K, E, 33, 33, t_min=0.05)
    c = 16
    assert float(cut.silhouette[0, c, c]) == float(alone.silhouette[0, c, c])  # the front strand alone
    assert 1.0 - float(alone.silhouette[0, c, c]) < 0.05
    assert float(deep.silhouette[0, c, c]) > float(cut.silhouette[0, c, c]) + 1e-3  # the back strand shows through
    assert float((cut.silhouette - deep.silhouette).abs().max()) <= 0.05
    assert abs(float(cut.depth[0, c, c]) - 0.40) < 1e-12 and float(deep.depth[0, c, c]) > 0.40 + 1e-5
    # the back strand's Gaussian at the crossing has no gradient through the crossing pixel when cut
    g_cut = torch.autograd.grad(cut.depth[0, c, c], pts)[0]
    g_deep = torch.autograd.grad(deep.depth[0, c, c], pts)[0]
    assert float(g_cut[0, 1].abs().max()) == 0.0 and float(g_deep[0, 1].abs().max()) > 0.0
    # float32 agrees with float64
    f32 = exact(pts.detach().float(), K.float(), E.float(), 33, 33)
    f64 = exact(pts.detach(), K, E, 33, 33)
    assert float((f32.silhouette.double() - f64.silhouette).abs().max()) < 1e-5
    assert float((f32.depth.double() - f64.depth)[f64.mask].abs().max()) < 1e-5


@pytest.mark.parametrize("seed", [0, 1])
def test_early_termination_matches_reference(seed):
    """Dense hair over several tiles (one of them partial), t_min 0.05 so that many pixels stop:
    every channel equals the per-pixel reference that stops a pixel below t_min, to round-off.
    Checks the early stop, and that the instances and window lines skipped over stopped pixels
    (numba_lines.walk_lines' live masks) held nothing to composite."""
    size = 40
    pts = tr.random_scene(seed, n=40, p=8, spread=0.012)
    K, E = tr.orbit_camera(size)
    ref = reference_render(pts, K, E, size, size, t_min=0.05)
    out = exact(torch.tensor(pts), torch.tensor(K), torch.tensor(E), size, size, t_min=0.05)
    assert (1.0 - ref.silhouette[0] < 0.05).sum() > 150  # pixels that stopped
    m = ref.silhouette[0] > 0.5
    assert np.abs(out.silhouette[0].numpy() - ref.silhouette[0]).max() < 1e-12
    assert np.abs(out.depth[0].numpy() - ref.depth[0])[m].max() < 1e-12
    assert np.abs(out.direction[0].numpy() - ref.direction[0]).sum(-1)[m].max() < 1e-8
    clear = np.abs(ref.max_weight[0] - 0.3) > 1e-9
    vis = out.visibility[0].reshape(-1).numpy()
    assert np.array_equal(vis[clear], (ref.max_weight[0] >= 0.3)[clear])


def test_translucent_silhouette_and_silhouette_only():
    """``silhouette_opacity`` with exact compositing is the silhouette of a second, silhouette-only
    exact render at that opacity; the silhouette-only render equals the shaded one's silhouette."""
    size = 20
    K, E = (torch.tensor(a) for a in tr.orbit_camera(size))
    pts = torch.tensor(tr.random_scene(4), requires_grad=True)
    both = exact(pts, K, E, size, size, silhouette_opacity=0.3)
    alone = exact(pts, K, E, size, size, opacity=0.3, shading=False)
    full = exact(pts, K, E, size, size)
    assert torch.equal(both.silhouette, alone.silhouette) and torch.equal(both.depth, full.depth)
    sil = exact(pts, K, E, size, size, shading=False)
    assert torch.allclose(sil.silhouette, full.silhouette, atol=1e-15)
    g = torch.autograd.grad(sil.silhouette.square().sum(), pts)[0]
    g_full = torch.autograd.grad(full.silhouette.square().sum(), pts)[0]
    assert torch.allclose(g, g_full, atol=1e-9)


def test_depth_order():
    from vid2haircut.render.numba_records import depth_order

    rng = np.random.default_rng(0)
    for dt in (np.float32, np.float64):
        z = (rng.random(5000) * 0.3 + 0.5).astype(dt)
        z[5], z[7], z[9], z[11] = np.nan, -1.0, z[10], -0.0
        key = np.where(np.isnan(z), np.inf, np.maximum(z.astype(np.float32), 0.0))
        assert np.array_equal(depth_order(z), np.argsort(key, kind="stable"))
    z = np.full(40, 0.5, np.float32)  # one high digit: the low pass alone
    z[::3] = 0.25
    assert np.array_equal(depth_order(z), np.argsort(z, kind="stable"))
    z = np.full(7, 0.5, np.float32)  # one depth; and no depth at all
    assert np.array_equal(depth_order(z), np.arange(7)) and depth_order(z[:0]).shape == (0,)
    z = rng.choice(np.float32([0.3, 0.31, 0.7, np.inf, 1e-30, 3e38]), 100000)  # many ties, extreme depths
    assert np.array_equal(depth_order(z), np.argsort(z, kind="stable"))
    # spans of 1 to 31 bits (one, two or three passes of up to 12-bit digits), with negative and
    # NaN depths; only negative and NaN ones; only NaN ones
    for span in (1e-7, 1e-6, 1e-4, 1e-2, 0.5, 1e3, 1e30):
        z = (0.5 + rng.random(3000) * span).astype(np.float32)
        z[rng.integers(0, 3000, 40)] = np.float32(np.nan)
        z[rng.integers(0, 3000, 40)] = np.float32(-0.3)
        z[rng.integers(0, 3000, 40)] = np.float32(0.0)
        key = np.where(np.isnan(z), np.inf, np.maximum(z, 0.0))
        assert np.array_equal(depth_order(z), np.argsort(key, kind="stable")), span
    z = np.float32([np.nan, -1.0, np.nan, -2.0, 0.0])
    assert list(depth_order(z)) == [1, 3, 4, 0, 2] and list(depth_order(z[:4])) == [1, 3, 0, 2]
    assert list(depth_order(z[[0, 2]])) == [0, 1]
    # one chunk per thread (each of at least DEPTH_CHUNK_MIN): the same stable order, every chunk
    # count, with ties across chunks, NaN and negative depths, a strided column and float64
    from vid2haircut.render.numba_records import DEPTH_CHUNK_MIN

    for n, span in ((2 * DEPTH_CHUNK_MIN + 17, 0.3), (5 * DEPTH_CHUNK_MIN, 1e-5), (3 * DEPTH_CHUNK_MIN, 1e3)):
        z = (0.5 + rng.random(n) * span).astype(np.float32)
        z[rng.integers(0, n, 500)] = np.float32(np.nan)
        z[rng.integers(0, n, 500)] = np.float32(-0.3)
        z[rng.integers(0, n, 2000)] = z[0]
        want = np.argsort(np.where(np.isnan(z), np.inf, np.maximum(z, 0.0)), kind="stable")
        for threads in (1, 2, 3, 8):
            assert np.array_equal(depth_order(z, threads), want), (n, threads)
        table = np.zeros((n, 8), np.float64)
        table[:, 5] = z
        assert np.array_equal(depth_order(table[:, 5], 2), want)


def test_bad_options():
    K, E = tr.simple_camera(9)
    pts = tr.line([-0.01, 0.0, 0.4], [0.01, 0.0, 0.4], 4)[None, None]
    with pytest.raises(ValueError, match="compositing must be one of"):
        render_strands(pts, K, E, 9, 9, compositing="sorted")
    with pytest.raises(ValueError, match="t_min must be in"):
        exact(pts, K, E, 9, 9, t_min=0.0)
    with pytest.raises(ValueError, match="t_min must be in"):  # the default, "auto", is the exact model here
        render_strands(pts, K, E, 9, 9, backend="numba", t_min=1.0)
    render_strands(pts, K, E, 9, 9, backend="torch", t_min=1.0)  # (the binned model has no t_min)
    with pytest.raises(ValueError, match="needs the numba backend"):
        render_strands(pts, K, E, 9, 9, backend="torch", compositing="exact")
    from vid2haircut.fit.components import COMPOSITINGS as fit_choices
    from vid2haircut.fit.config import Stage2Config
    from vid2haircut.fit.settings import apply_overrides
    from vid2haircut.render.api import COMPOSITINGS

    assert fit_choices == COMPOSITINGS
    cfg = apply_overrides(Stage2Config(), {"render": {"compositing": "exact", "t_min": 1e-3}})
    assert (cfg.render.compositing, cfg.render.t_min) == ("exact", 1e-3)
    for bad, msg in (({"compositing": "sorted"}, "must be one of"), ({"t_min": 1.0}, "must be in")):
        with pytest.raises(ValueError, match=msg):
            apply_overrides(Stage2Config(), {"render": bad})


def test_default_is_exact_on_numba_and_bins_on_torch():
    """``compositing="auto"`` (the default) is the exact model where the numba kernels render and the
    binned one on the torch kernels (CUDA's), the same render to the bit as naming it."""
    from vid2haircut.render.api import resolve_compositing

    size = 20
    pts = torch.tensor(tr.random_scene(1, spread=0.03))
    K, E = (torch.tensor(a) for a in tr.orbit_camera(size))
    for backend, model in (("numba", "exact"), ("torch", "bins")):
        assert resolve_compositing("auto", backend) == model and resolve_compositing("bins", backend) == "bins"
        default = render_strands(pts, K, E, size, size, backend=backend)
        named = render_strands(pts, K, E, size, size, backend=backend, compositing=model)
        for name in ("silhouette", "depth", "direction", "visibility"):
            assert torch.equal(getattr(default, name), getattr(named, name)), (backend, name)
    auto = render_strands(pts, K, E, size, size)  # the CPU's default backend with numba installed
    bins = render_strands(pts, K, E, size, size, compositing="bins")
    assert torch.equal(auto.silhouette, exact(pts, K, E, size, size).silhouette)
    assert not torch.equal(auto.silhouette, bins.silhouette)  # (the two models differ on this scene)
    with pytest.raises(ValueError, match="compositing must be one of"):
        resolve_compositing("sorted", "numba")


def test_same_result_for_any_thread_count_and_projection_path():
    """Bit for bit the same at 1 and 2 threads; with cameras requiring gradients (torch's projection
    and windows) the same render to round-off, and a gradient reaches the intrinsics."""
    size = 24
    K, E = (torch.tensor(a) for a in tr.orbit_camera(size))
    K, E = K.expand(2, 3, 3).contiguous(), E.expand(2, 4, 4).contiguous()
    pts = torch.tensor(np.concatenate([tr.random_scene(6, n=12), tr.random_scene(7, n=12)]))
    runs = []
    threads = torch.get_num_threads()
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            p = pts.clone().requires_grad_(True)
            out = exact(p, K, E, size, size)
            g = torch.autograd.grad(out.silhouette.sum() + out.depth.sum() + out.direction.sum(), p)[0]
            runs.append((out.silhouette, out.depth, out.direction, out.visibility, g))
    finally:
        torch.set_num_threads(threads)
    assert all(torch.equal(a, b) for a, b in zip(*runs))
    Kg = K.clone().requires_grad_(True)
    viaw = exact(pts, Kg, E, size, size)
    assert float((viaw.depth - runs[0][1]).abs().max()) < 1e-12 and torch.equal(viaw.visibility, runs[0][3])
    assert float(torch.autograd.grad(viaw.depth.sum(), Kg)[0].abs().max()) > 0
