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
    """numba_ops.channels_fused (the numba backend's depth, direction and mask) = api._finish's
    torch operations: the channels and the gradients of a loss over any of them, byte for byte
    (the loss through silhouette, depth, normalised depth and direction in turn)."""
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
        for x, y in zip(run(False, seed), run(True, seed)):
            assert x.dtype == y.dtype and x.shape == y.shape
            assert x.detach().numpy().tobytes() == y.detach().numpy().tobytes()
    log_t, wz, dirs = _channel_sums(0, dtype)
    out = _finish(PixelSums(log_t, -torch.expm1(log_t), wz, dirs), torch.zeros(1), None, fused=True)
    assert out.mask.any() and not out.mask.all() and bool((out.direction == 0).all(-1).any())
