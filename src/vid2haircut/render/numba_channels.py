"""Image channels of the fused CPU backend (numba): depth and direction from the pixel sums, in one pass.

:func:`vid2haircut.render.api.render_strands` turns the compositor's per-pixel sums (the weight
w = 1 - exp(sum l), sum w z and the two direction sums) into the depth map (sum w z / w where
w > 1e-12, else 0), the unit direction map ((0, 0) where the sums' norm^2 <= 1e-20) and the mask
(w > 0.5 where w > 1e-12). In torch that is ~10 elementwise operations forward and ~20 backward,
each a pass over [B, H, W] arrays (4.1 ms for one 256 x 256 frame, 9.2 ms for six 224 x 224 ones
on the project's 2-core CPU). These two kernels do the same per pixel with the same operations in
the same order (IEEE division and square root: torch's rsqrt is 1 / sqrt correctly rounded, and
its ``pow(r, 3)`` is r r r), so the channels and the gradients equal torch's bit for bit
(tests/test_render_channels.py); :class:`vid2haircut.render.numba_backend` wraps them as one
autograd function.

Backward, per pixel (autograd's formulas for the torch graph of ``api._finish``, in its order):
depth = where(f, wz / s, 0), s = where(f, w, 1): d wz = g' / s and d w = where(f, -g' ((wz / s) / s), 0)
with g' = where(f, g_depth, 0); direction = d inv: d d = g_dir inv + 2 (n2' d) added as autograd
adds them ((g_dir inv + n2' d) + n2' d), n2' = where(h, -0.5 r' r^3, 0), r' = where(h, g_dir . d, 0),
r = rsqrt(where(h, |d|^2, 1)).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from vid2haircut.render.numba_math import lane_cast

_PAR = dict(cache=True, parallel=True, error_model="numpy")


@njit(cache=True, error_model="numpy", inline="always")
def _rsqrt(a, b, n2min, one):
    """(r, h) of direction sums (a, b): h = |(a, b)|^2 > n2min, r = rsqrt(|(a, b)|^2 if h else 1)."""
    n2 = a * a + b * b
    h = n2 > n2min
    return one / np.sqrt(n2 if h else one), h


@njit(**_PAR)
def channels_forward(weight, wz, dirs, wmin, n2min, half, depth, direction, mask):
    """Per pixel of the flattened [M] sums (``dirs`` [M, 2]; one float dtype, with the thresholds
    ``wmin`` (1e-12), ``n2min`` (1e-20) and ``half`` (0.5) as 0-d arrays of it): depth [M],
    direction [M, 2] and mask [M] bool, filled."""
    one, zero = np.ones(1, weight.dtype)[0], np.zeros(1, weight.dtype)[0]
    wm, nm, hf = wmin[()], n2min[()], half[()]
    for i in prange(weight.shape[0]):
        w = weight[i]
        f = w > wm
        s = w if f else one
        q = wz[i] / s
        depth[i] = q if f else zero
        a, b = dirs[i, 0], dirs[i, 1]
        r, h = _rsqrt(a, b, nm, one)
        inv = r if h else zero
        direction[i, 0] = a * inv
        direction[i, 1] = b * inv
        mask[i] = (w > hf) & f


@njit(**_PAR)
def channels_backward(weight, wz, dirs, g_depth, g_dir, wmin, n2min, with_depth, with_dir, g_w, g_wz, g_dirs):
    """Gradients of :func:`channels_forward`'s depth and direction (``g_depth`` [M], ``g_dir`` [M, 2];
    read only when ``with_depth`` / ``with_dir``) w.r.t. the weight, sum w z and the direction
    sums: g_w, g_wz [M] (written when ``with_depth``), g_dirs [M, 2] (when ``with_dir``)."""
    one, zero = np.ones(1, weight.dtype)[0], np.zeros(1, weight.dtype)[0]
    mhalf = -(one / (one + one))  # -0.5 in the arrays' dtype (a float literal would make the products float64)
    wm, nm = wmin[()], n2min[()]
    for i in prange(weight.shape[0]):
        if with_depth:
            w = weight[i]
            f = w > wm
            s = w if f else one
            gq = g_depth[i] if f else zero
            g_wz[i] = gq / s
            gs = -gq * ((wz[i] / s) / s)
            g_w[i] = gs if f else zero
        if with_dir:
            a, b = dirs[i, 0], dirs[i, 1]
            r, h = _rsqrt(a, b, nm, one)
            inv = r if h else zero
            g0, g1 = g_dir[i, 0], g_dir[i, 1]
            gr = g0 * a + g1 * b
            gr = gr if h else zero
            gn = (gr * mhalf) * ((r * r) * r)
            gn = gn if h else zero
            b0, b1 = gn * a, gn * b
            g_dirs[i, 0] = (g0 * inv + b0) + b0
            g_dirs[i, 1] = (g1 * inv + b1) + b1



@njit(**_PAR, fastmath={"nnan", "nsz", "reassoc"})
def normalize_forward(depth, mask, out, stats):
    """Min-max normalised depth per frame inside the mask, as
    :func:`vid2haircut.render.api.normalize_depth` computes it (the same operations in the same
    dtype, so the same values: (depth - min) / max(max - min, 1e-8), 0 outside the mask and in
    frames with an empty mask). The depths must not be NaN (fastmath: the min and max are
    vectorised; the channels' depth never is).

    Args:
        depth, out: [B, M] one float dtype; mask: [B, M] bool.
        stats: [B, 4] float64, filled with (min, max, the span before the clamp, pixels in the
            mask) per frame for :func:`normalize_backward`.
    """
    for b in prange(depth.shape[0]):
        zero, eps, inf = lane_cast(0.0, depth), lane_cast(1e-8, depth), lane_cast(np.inf, depth)
        # min and max of the masked depths through ``out`` (LLVM vectorises these loops, not one
        # reducing selects of the mask: 0.07 against 0.21 ms for 256 x 256, measured)
        for i in range(depth.shape[1]):
            out[b, i] = depth[b, i] if mask[b, i] else inf
        lo = inf
        for i in range(depth.shape[1]):
            lo = min(lo, out[b, i])
        for i in range(depth.shape[1]):
            out[b, i] = depth[b, i] if mask[b, i] else -inf
        hi = -inf
        for i in range(depth.shape[1]):
            hi = max(hi, out[b, i])
        n = 0
        for i in range(depth.shape[1]):
            n += mask[b, i]
        dmin = lo if n > 0 else zero
        raw = hi - dmin if n > 0 else lane_cast(1.0, depth)
        span = max(raw, eps)
        for i in range(depth.shape[1]):
            q = (depth[b, i] - dmin) / span
            out[b, i] = q if mask[b, i] else zero
        stats[b, 0], stats[b, 1], stats[b, 2], stats[b, 3] = lo, hi, raw, n


@njit(**_PAR, fastmath={"nnan", "nsz", "reassoc"})
def normalize_backward(depth, mask, out, stats, grad, g_depth):
    """d loss / d depth [B, M] (``g_depth``, filled) of :func:`normalize_forward` from the
    gradient ``grad`` [B, M] of its output ``out``: autograd's result for the torch operations of
    :func:`vid2haircut.render.api.normalize_depth`, to round-off (its sums run in another order).
    Inside the mask: grad / span, plus, at the pixels holding the minimum, d loss / d min shared
    evenly among them, and the same for the maximum (as autograd's amin / amax share it):
    d loss / d min = -sum(grad) / span - c d loss / d span, d loss / d max = c d loss / d span,
    d loss / d span = -sum(grad out) / span, c = 1 where the span was not clamped (raw >= 1e-8)."""
    for b in prange(depth.shape[0]):
        zero, eps = lane_cast(0.0, depth), lane_cast(1e-8, depth)
        lo, hi, raw = lane_cast(stats[b, 0], depth), lane_cast(stats[b, 1], depth), lane_cast(stats[b, 2], depth)
        if stats[b, 3] == 0:
            for i in range(depth.shape[1]):
                g_depth[b, i] = zero
            continue
        span = max(raw, eps)
        gsum = gout = 0.0
        nlo = nhi = 0
        for i in range(depth.shape[1]):
            m = mask[b, i]
            g = grad[b, i] if m else zero
            gsum += g
            gout += g * out[b, i]
            v = depth[b, i]
            nlo += m & (v == lo)
            nhi += m & (v == hi)
        g_span = -gout / span if raw >= eps else 0.0
        g_lo = (-gsum / span - g_span) / nlo
        g_hi = g_span / nhi
        for i in range(depth.shape[1]):
            v = depth[b, i]
            g = grad[b, i] / span + ((g_lo if v == lo else 0.0) + (g_hi if v == hi else 0.0))
            g_depth[b, i] = g if mask[b, i] else zero
