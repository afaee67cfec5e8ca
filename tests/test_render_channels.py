"""The numba backend's image channels (depth, direction, mask) against the torch operations, bit for bit."""

from __future__ import annotations

import pytest
import torch

from vid2haircut.render.numba_backend import numba_available


def _channel_sums(seed, dtype, shape=(2, 37, 41)):
    """Pixel sums (log transmittance, sum w z, direction sums) with the channels' edge cases: no
    coverage, weights around the 1e-12 threshold, saturated pixels, zero and tiny direction sums."""
    g = torch.Generator().manual_seed(seed)
    log_t = -torch.rand(shape, generator=g, dtype=dtype) * 3
    log_t[..., :5], log_t[..., 5:8], log_t[..., 8:10] = 0.0, -1e-13, -30.0
    wz = torch.rand(shape, generator=g, dtype=dtype)
    dirs = torch.randn(shape + (2,), generator=g, dtype=dtype) * torch.exp(
        torch.randn(shape + (1,), generator=g, dtype=dtype) * 8)
    dirs[..., 3:6, :] = 0.0
    dirs[..., 6, 0], dirs[..., 6, 1] = 1e-11, 0.0
    return log_t, wz, dirs


@pytest.mark.skipif(not numba_available(), reason="needs numba")
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("terms", [("sil", "dn", "dir"), ("sil", "d", "dn", "dir"), ("dir",), ("dn",), ("sil", "dir")])
def test_fused_channels_equal_torch_bit_for_bit(dtype, terms):
    """numba_ops.channels_fused and normalize_depth_fused (the numba backend's depth, direction,
    mask and normalised depth) = api._finish's torch operations: the channels byte for byte, and the
    gradients of a loss over any of them (the loss through silhouette, depth, normalised depth and
    direction in turn) byte for byte too, but through the normalised depth (to round-off there)."""
    from vid2haircut.render.api import _finish
    from vid2haircut.render.types import PixelSums

    def run(fused, seed):
        log_t, wz, dirs = (t.requires_grad_() for t in _channel_sums(seed, dtype))
        weight = -torch.expm1(log_t) + 0.0
        out = _finish(PixelSums(log_t, weight, wz, dirs), torch.zeros(1), None, fused=fused)
        g = torch.Generator().manual_seed(seed + 1)
        shape = weight.shape
        loss = {"sil": (out.silhouette * torch.rand(shape, generator=g, dtype=dtype)).sum(),
                "dn": (out.depth_normalized * torch.rand(shape, generator=g, dtype=dtype)).sum(),
                "d": (out.depth * torch.rand(shape, generator=g, dtype=dtype)).sum(),
                "dir": (out.direction * torch.randn(shape + (2,), generator=g, dtype=dtype)).sum()}
        sum(loss[k] for k in terms).backward()
        grads = [t.grad if t.grad is not None else torch.zeros(0, dtype=dtype) for t in (log_t, wz, dirs)]
        return [out.depth, out.direction, out.mask, out.depth_normalized] + grads

    for seed in range(3):
        for i, (x, y) in enumerate(zip(run(False, seed), run(True, seed))):
            assert x.dtype == y.dtype and x.shape == y.shape
            if i >= 4 and "dn" in terms and x.numel():  # the normalised depth's sums run in another order
                x, y = x.double(), y.double()
                tol = 1e-5 if dtype == torch.float32 else 1e-12
                assert float((x - y).abs().max()) <= tol * float(x.abs().max())
                continue
            assert x.detach().numpy().tobytes() == y.detach().numpy().tobytes()
    log_t, wz, dirs = _channel_sums(0, dtype)
    out = _finish(PixelSums(log_t, -torch.expm1(log_t), wz, dirs), torch.zeros(1), None, fused=True)
    assert out.mask.any() and not out.mask.all() and bool((out.direction == 0).all(-1).any())


@pytest.mark.skipif(not numba_available(), reason="needs numba")
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fused_normalized_depth_against_autograd(dtype):
    """normalize_depth_fused = api.normalize_depth: the same values, and autograd's gradient to
    round-off, in frames whose minimum and maximum are held by several pixels (autograd shares
    their gradient evenly), a frame with one depth (span clamped to 1e-8: no gradient through it),
    a frame with an empty mask (zeros), and one with a single masked pixel."""
    from vid2haircut.render.api import normalize_depth
    from vid2haircut.render.numba_ops import normalize_depth_fused

    g = torch.Generator().manual_seed(3)
    B, H, W = 5, 23, 19
    depth = (0.5 + torch.rand(B, H, W, generator=g, dtype=torch.float64)).to(dtype)
    mask = torch.rand(B, H, W, generator=g) > 0.3
    depth[0, :3, 0], depth[0, 5, :4] = depth[0][mask[0]].min(), depth[0][mask[0]].max()  # ties
    mask[0, :3, 0], mask[0, 5, :4] = True, True
    depth[1] = 0.7  # one depth
    depth[4] = (0.01 + 1e-9 * torch.randint(0, 5, (H, W), generator=g)).to(dtype)  # a span below 1e-8: clamped
    mask[2] = False
    mask[3] = False
    mask[3, 4, 4] = True
    w = torch.randn(B, H, W, generator=g, dtype=dtype)
    grads = []
    for fn in (normalize_depth, normalize_depth_fused):
        d = depth.clone().requires_grad_()
        out = fn(d, mask)
        (out * w).sum().backward()
        grads.append((out.detach(), d.grad))
    (ref, g_ref), (got, g_got) = grads
    assert ref.numpy().tobytes() == got.numpy().tobytes()
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    assert float((g_ref - g_got).abs().max()) <= tol * float(g_ref.abs().max())
    assert float(g_ref[0][depth[0] == depth[0][mask[0]].min()].abs().min()) > 0  # the shared minimum's share
    assert not g_got[2].any() and not g_got[1][~mask[1]].any() and float(got[4].max()) > 0.1
