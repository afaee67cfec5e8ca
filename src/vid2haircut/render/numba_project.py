"""Fused CPU projection of strand segments to screen-space Gaussians (numba), with its backward pass.

The same EWA projection as :func:`vid2haircut.render.gaussians.segment_gaussians` followed by
:func:`vid2haircut.render.gaussians.conics`, in two loops instead of ~40 torch operations and
their autograd graph (measured, 4k strands x 32 points, 2 threads: 14.7 ms forward+backward in
torch against about 1 ms here). The forward pass computes in the dtype of the points; the
backward pass, written out by hand below (reverse order of the forward formulas), in float64,
and the gradients of the two segments that share a strand point are summed per strand in a
fixed order, so the result does not depend on the number of threads. Gradients reach the
points only (not the cameras); :func:`vid2haircut.render.api.render_strands` uses the torch path
when K or world_2_cam require gradients. tests/test_render_backends.py checks values and
gradients against the torch functions.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from vid2haircut.render.numba_math import lane_cast

_PAR = dict(cache=True, parallel=True, error_model="numpy")
# columns of the Gaussian table [G, 8] (as :mod:`.numba_walk`) and of the covariance table [G, 3]
G_MX, G_MY, G_QXX, G_QXY, G_QYY, G_Z, G_C, G_S = range(8)


@njit(cache=True, inline="always")
def _segment(points, b, n, j, R, t, k00, k01, k10, k11, near, w2, dilation, eps_l):
    """The EWA projection of segment j of strand n in frame b (R, t: the camera's rotation and
    translation; every argument and result in one float dtype). Returns the camera-frame midpoint
    (mx, my, mz) and segment (dx, dy, dz), zc = max(mz, near), iz = 1 / zc, X = mx iz, Y = my iz,
    the projected segment (ja, jb), the world segment (sx, sy, sz) with len2e = |s|^2 + eps_l,
    coef = 1/4 - w^2 / len2e and the covariance (sxx, sxy, syy)."""
    one = lane_cast(1.0, near)
    p0x, p0y, p0z = points[b, n, j, 0], points[b, n, j, 1], points[b, n, j, 2]
    p1x, p1y, p1z = points[b, n, j + 1, 0], points[b, n, j + 1, 1], points[b, n, j + 1, 2]
    half = one / (one + one)
    mwx, mwy, mwz = half * (p1x + p0x), half * (p1y + p0y), half * (p1z + p0z)
    sx, sy, sz = p1x - p0x, p1y - p0y, p1z - p0z
    mx = R[0, 0] * mwx + R[0, 1] * mwy + R[0, 2] * mwz + t[0]
    my = R[1, 0] * mwx + R[1, 1] * mwy + R[1, 2] * mwz + t[1]
    mz = R[2, 0] * mwx + R[2, 1] * mwy + R[2, 2] * mwz + t[2]
    dx = R[0, 0] * sx + R[0, 1] * sy + R[0, 2] * sz
    dy = R[1, 0] * sx + R[1, 1] * sy + R[1, 2] * sz
    dz = R[2, 0] * sx + R[2, 1] * sy + R[2, 2] * sz
    zc = max(mz, near)
    iz = one / zc
    X, Y = mx * iz, my * iz
    a0 = iz * (dx - X * dz)
    a1 = iz * (dy - Y * dz)
    ja = k00 * a0 + k01 * a1
    jb = k10 * a0 + k11 * a1
    iz2 = iz * iz
    m00, m01, m11 = iz2 * (one + X * X), iz2 * X * Y, iz2 * (one + Y * Y)
    r00, r01 = k00 * m00 + k01 * m01, k00 * m01 + k01 * m11
    r10, r11 = k10 * m00 + k11 * m01, k10 * m01 + k11 * m11
    jj00, jj01, jj11 = r00 * k00 + r01 * k01, r00 * k10 + r01 * k11, r10 * k10 + r11 * k11
    len2e = sx * sx + sy * sy + sz * sz + eps_l
    coef = half * half - w2 / len2e
    sxx = w2 * jj00 + coef * ja * ja + dilation
    sxy = w2 * jj01 + coef * ja * jb
    syy = w2 * jj11 + coef * jb * jb + dilation
    return (mx, my, mz, dx, dy, dz, zc, iz, X, Y, ja, jb, sx, sy, sz, len2e, coef, sxx, sxy, syy)


@njit(**_PAR)
def project_forward(points, K, w2c, strand_width, dilation, near, gpar, covs, valid):
    """Screen-space Gaussians of every segment.

    Args:
        points: [B, N, P, 3] world points (float32 or float64). K: [B, 3, 3], w2c: [B, 4, 4]
            (same dtype). strand_width (metres), dilation (px^2), near (metres): as in
            :func:`vid2haircut.render.gaussians.segment_gaussians`.
        gpar: [B * N * (P - 1), 8] filled with (mean x, mean y, q_xx, q_xy, q_yy, z, cos 2a, sin 2a),
            segments strand-major per frame. covs: [B * N * (P - 1), 3] filled with the
            covariance (xx, xy, yy). valid: [B * N * (P - 1)] bool, filled.
    """
    B, N, P = points.shape[0], points.shape[1], points.shape[2]
    S = N * (P - 1)
    z0 = points[0, 0, 0, 0] * 0  # zero of the dtype
    w2 = lane_cast(strand_width, z0) * lane_cast(strand_width, z0)
    dil, nr = lane_cast(dilation, z0), lane_cast(near, z0)
    tiny, eps_d, eps_l = lane_cast(1e-12, z0), lane_cast(1e-12, z0), lane_cast(1e-20, z0)
    for bn in prange(B * N):
        b, n = bn // N, bn - (bn // N) * N
        k00, k01, k02, k10, k11, k12 = K[b, 0, 0], K[b, 0, 1], K[b, 0, 2], K[b, 1, 0], K[b, 1, 1], K[b, 1, 2]
        R, t = w2c[b, :3, :3], w2c[b, :3, 3]
        for j in range(P - 1):
            g = b * S + n * (P - 1) + j
            (mx, my, mz, dx, dy, dz, zc, iz, X, Y, ja, jb, sx, sy, sz, len2e, coef, sxx, sxy,
             syy) = _segment(points, b, n, j, R, t, k00, k01, k10, k11, nr, w2, dil, eps_l)
            xn, yn = mx / zc, my / zc
            u = k00 * xn + k01 * yn + k02
            v = k10 * xn + k11 * yn + k12
            n2 = ja * ja + jb * jb + eps_d
            det = max(sxx * syy - sxy * sxy, tiny)
            gpar[g, G_MX], gpar[g, G_MY] = u, v
            gpar[g, G_QXX], gpar[g, G_QXY], gpar[g, G_QYY] = syy / det, -sxy / det, sxx / det
            gpar[g, G_Z] = mz
            gpar[g, G_C], gpar[g, G_S] = (ja * ja - jb * jb) / n2, (ja + ja) * jb / n2
            covs[g, 0], covs[g, 1], covs[g, 2] = sxx, sxy, syy
            valid[g] = (mz > nr) & math.isfinite(u) & math.isfinite(v) & math.isfinite(sxx) & \
                math.isfinite(sxy) & math.isfinite(syy)


@njit(**_PAR)
def project_backward(points, K, w2c, strand_width, dilation, near, grad, out):
    """d loss / d points from d loss / d gpar.

    Args:
        points, K, w2c, strand_width, dilation, near: as given to :func:`project_forward`.
        grad: [B * N * (P - 1), 8] gradient of the Gaussian table (columns as ``gpar``; float32
            or float64, read as float64).
        out: [B, N, P, 3] filled with the gradient of the points: summed in float64 (each point's
            two segment terms in segment order), stored in the dtype of ``out``.
    """
    B, N, P = points.shape[0], points.shape[1], points.shape[2]
    S = N * (P - 1)
    w2 = float(strand_width) * float(strand_width)
    Rs = w2c[:, :3, :3].astype(np.float64)
    ts = w2c[:, :3, 3].astype(np.float64)
    points64 = points.astype(np.float64)
    for bn in prange(B * N):
        b, n = bn // N, bn - (bn // N) * N
        k00, k01, k10, k11 = float(K[b, 0, 0]), float(K[b, 0, 1]), float(K[b, 1, 0]), float(K[b, 1, 1])
        R, t = Rs[b], ts[b]
        a0 = a1 = a2 = 0.0  # point j's sum so far (float64): the term of segment j - 1
        f64 = np.float64  # reads the gradient in float64 (numba's float() keeps float32)
        for j in range(P - 1):
            g = b * S + n * (P - 1) + j
            gu, gv, gqxx = f64(grad[g, G_MX]), f64(grad[g, G_MY]), f64(grad[g, G_QXX])
            gqxy, gqyy = f64(grad[g, G_QXY]), f64(grad[g, G_QYY])
            gz, gc, gs = f64(grad[g, G_Z]), f64(grad[g, G_C]), f64(grad[g, G_S])
            if gu == 0.0 and gv == 0.0 and gqxx == 0.0 and gqxy == 0.0 and gqyy == 0.0 and gz == 0.0 \
                    and gc == 0.0 and gs == 0.0:  # undrawn (possibly non-finite) segment
                out[b, n, j, 0], out[b, n, j, 1], out[b, n, j, 2] = a0, a1, a2
                a0 = a1 = a2 = 0.0
                continue
            # forward again, in float64
            (mx, my, mz, dx, dy, dz, zc, iz, X, Y, ja, jb, sx, sy, sz, len2e, coef, sxx, sxy,
             syy) = _segment(points64, b, n, j, R, t, k00, k01, k10, k11, near, w2, dilation, 1e-20)
            xn, yn = mx / zc, my / zc
            iz2 = iz * iz
            n2 = ja * ja + jb * jb + 1e-12
            # conic <- covariance: q = (syy, -sxy, sxx) / det, det = max(sxx syy - sxy^2, 1e-12)
            det_raw = sxx * syy - sxy * sxy
            det = max(det_raw, 1e-12)
            g_det = -(gqxx * syy - gqxy * sxy + gqyy * sxx) / (det * det) if det_raw >= 1e-12 else 0.0
            g_sxx = gqyy / det + g_det * syy
            g_syy = gqxx / det + g_det * sxx
            g_sxy = -gqxy / det - 2.0 * g_det * sxy
            # direction <- (ja, jb)
            cc = (ja * ja - jb * jb) / n2
            ss = 2.0 * ja * jb / n2
            g_ja = gc * (2.0 * ja - 2.0 * ja * cc) / n2 + gs * (2.0 * jb - 2.0 * ja * ss) / n2
            g_jb = gc * (-2.0 * jb - 2.0 * jb * cc) / n2 + gs * (2.0 * ja - 2.0 * jb * ss) / n2
            # covariance <- (jj, coef, ja, jb)
            g_ja += g_sxx * 2.0 * coef * ja + g_sxy * coef * jb
            g_jb += g_syy * 2.0 * coef * jb + g_sxy * coef * ja
            g_coef = g_sxx * ja * ja + g_sxy * ja * jb + g_syy * jb * jb
            g_jj00, g_jj01, g_jj11 = w2 * g_sxx, w2 * g_sxy, w2 * g_syy
            g_len2 = g_coef * w2 / (len2e * len2e)
            # jj <- r <- m
            g_r00 = g_jj00 * k00 + g_jj01 * k10
            g_r01 = g_jj00 * k01 + g_jj01 * k11
            g_r10 = g_jj11 * k10
            g_r11 = g_jj11 * k11
            g_m00 = g_r00 * k00 + g_r10 * k10
            g_m01 = g_r00 * k01 + g_r01 * k00 + g_r10 * k11 + g_r11 * k10
            g_m11 = g_r01 * k01 + g_r11 * k11
            g_iz2 = g_m00 * (1.0 + X * X) + g_m01 * X * Y + g_m11 * (1.0 + Y * Y)
            g_X = g_m00 * iz2 * 2.0 * X + g_m01 * iz2 * Y
            g_Y = g_m01 * iz2 * X + g_m11 * iz2 * 2.0 * Y
            # (ja, jb) <- (a0, a1) <- (iz, d, X, Y)
            g_a0 = g_ja * k00 + g_jb * k10
            g_a1 = g_ja * k01 + g_jb * k11
            g_iz = g_a0 * (dx - X * dz) + g_a1 * (dy - Y * dz) + g_iz2 * 2.0 * iz
            g_dx, g_dy = g_a0 * iz, g_a1 * iz
            g_dz = -(g_a0 * iz * X + g_a1 * iz * Y)
            g_X -= g_a0 * iz * dz
            g_Y -= g_a1 * iz * dz
            # (X, Y) <- (m, iz); the mean <- (m, zc)
            g_mx, g_my = g_X * iz, g_Y * iz
            g_iz += g_X * mx + g_Y * my
            g_xn = gu * k00 + gv * k10
            g_yn = gu * k01 + gv * k11
            g_mx += g_xn / zc
            g_my += g_yn / zc
            g_zc = -(g_xn * xn + g_yn * yn) / zc - g_iz * iz * iz
            g_mz = gz + (g_zc if mz >= near else 0.0)
            # camera -> world (R^T), segment length
            gmw0 = R[0, 0] * g_mx + R[1, 0] * g_my + R[2, 0] * g_mz
            gmw1 = R[0, 1] * g_mx + R[1, 1] * g_my + R[2, 1] * g_mz
            gmw2 = R[0, 2] * g_mx + R[1, 2] * g_my + R[2, 2] * g_mz
            gs0 = R[0, 0] * g_dx + R[1, 0] * g_dy + R[2, 0] * g_dz + 2.0 * sx * g_len2
            gs1 = R[0, 1] * g_dx + R[1, 1] * g_dy + R[2, 1] * g_dz + 2.0 * sy * g_len2
            gs2 = R[0, 2] * g_dx + R[1, 2] * g_dy + R[2, 2] * g_dz + 2.0 * sz * g_len2
            out[b, n, j, 0] = a0 + (0.5 * gmw0 - gs0)
            out[b, n, j, 1] = a1 + (0.5 * gmw1 - gs1)
            out[b, n, j, 2] = a2 + (0.5 * gmw2 - gs2)
            a0, a1, a2 = 0.0 + (0.5 * gmw0 + gs0), 0.0 + (0.5 * gmw1 + gs1), 0.0 + (0.5 * gmw2 + gs2)
        out[b, n, P - 1, 0], out[b, n, P - 1, 1], out[b, n, P - 1, 2] = a0, a1, a2
