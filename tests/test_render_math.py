"""The numba kernels' vectorisable math (render/numba_math.py): exp, log(1 - a), compress stores."""

from __future__ import annotations

import numpy as np
import pytest

numba = pytest.importorskip("numba")

from vid2haircut.render.numba_math import compress16, lane_exp, lane_log1m  # noqa: E402


@numba.njit(cache=True)
def _exp_all(x, out):
    for i in range(x.shape[0]):
        out[i] = lane_exp(x[i])


@numba.njit(cache=True)
def _log1m_all(a, out):
    for i in range(a.shape[0]):
        out[i] = lane_log1m(a[i])


@numba.njit(cache=True)
def _compress_all(src, mask, dst):
    n = 0
    for k in range(src.shape[0] // 16):
        n += compress16(dst, np.uint64(n), src[16 * k:16 * k + 16], mask[16 * k:16 * k + 16])
    return n


@pytest.mark.parametrize("dtype,tol", [(np.float32, 1.2e-7), (np.float64, 3e-16)])
def test_exp_relative_error(dtype, tol):
    x = np.concatenate([np.linspace(-87, 0, 400_001), -np.geomspace(1e-12, 1, 10_001)]).astype(dtype)
    out = np.empty_like(x)
    _exp_all(x, out)
    ref = np.exp(x.astype(np.float64))
    assert out.dtype == dtype and np.max(np.abs(out - ref) / ref) < tol


@pytest.mark.parametrize("dtype,tol", [(np.float32, 2.5e-7), (np.float64, 1e-15)])
def test_log1m_relative_error(dtype, tol):
    """log(1 - a) over the renderer's alpha range, small alphas included (the rounding of 1 - a is
    corrected: log(fl(1 - a)) alone is off by up to 5e-6 relative at a = 0.011 in float32)."""
    a = np.concatenate([np.linspace(0, 0.99, 400_001), np.geomspace(1e-9, 0.05, 20_001)]).astype(dtype)
    out = np.empty_like(a)
    _log1m_all(a, out)
    ref = np.log1p(-a.astype(np.float64))
    nz = ref != 0
    assert out.dtype == dtype and np.all(out[~nz] == 0)
    assert np.max(np.abs(out[nz] - ref[nz]) / np.abs(ref[nz])) < tol


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32])
def test_compress16_appends_the_kept_lanes_in_order(dtype):
    rng = np.random.default_rng(0)
    src = rng.uniform(-5, 5, 16 * 200).astype(dtype)
    mask = (rng.random(src.shape[0]) < 0.3).astype(np.int32)
    mask[:16] = 1  # a full line and an empty one
    mask[16:32] = 0
    dst = np.full(src.shape[0] + 16, -99, dtype)
    n = _compress_all(src, mask, dst)
    assert n == mask.sum() and np.array_equal(dst[:n], src[mask != 0])
    assert np.all(dst[n:n + 1] == 0)  # the last call's lanes past the kept ones are zeros
    assert np.all(dst[n + 16:] == -99)  # and nothing lies further than 16 slots from the start
