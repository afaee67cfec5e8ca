"""Fused CPU projection of strand segments to screen-space Gaussians (numba), with its backward pass.

The same EWA projection as :func:`vid2haircut.render.gaussians.segment_gaussians` followed by
:func:`vid2haircut.render.gaussians.conics`, in two loops instead of ~40 torch operations and
their autograd graph (measured, 4k strands x 32 points, 2 threads: 14.7 ms forward+backward in
torch against ~3 ms here). The forward pass computes in float64 but for float32 points takes
the segment (point differences, midpoint sums) and its rotation into the camera frame in
float32, and stores its results in the dtype of the points; the backward pass, written out by
hand below (reverse order of the forward formulas), computes in float64, and the gradients of
the two segments that share a strand point are summed per strand in a fixed order, so the
result does not depend on the number of threads. Both run over one strand at a time with its
points in rows (vectorised over segments, see the note above :func:`_forward_strand`). Gradients reach the
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
_CHUNK = 32  # strands per parallel work item (its scratch rows allocated once)
# columns of the Gaussian table [G, 8] (as :mod:`.numba_walk`) and of the covariance table [G, 3]
G_MX, G_MY, G_QXX, G_QXY, G_QYY, G_Z, G_C, G_S = range(8)


@njit(cache=True, inline="always")
def _segment(pT, j, cam, k00, k01, k10, k11, near, w2, dilation, eps_l):
    """The EWA projection of segment j of one strand (pT: [3, >= j + 2] its points, one row per
    coordinate; cam: the camera's rotation and translation (c00, c01, ..., c22, t0, t1, t2); every
    argument and result in one float dtype). Returns the camera-frame midpoint
    (mx, my, mz) and segment (dx, dy, dz), zc = max(mz, near), iz = 1 / zc, X = mx iz, Y = my iz,
    the projected segment (ja, jb), the world segment (sx, sy, sz) with len2e = |s|^2 + eps_l,
    coef = 1/4 - w^2 / len2e and the covariance (sxx, sxy, syy)."""
    one = lane_cast(1.0, near)
    c00, c01, c02, c10, c11, c12, c20, c21, c22, t0, t1, t2 = cam
    p0x, p0y, p0z = pT[0, j], pT[1, j], pT[2, j]
    p1x, p1y, p1z = pT[0, j + 1], pT[1, j + 1], pT[2, j + 1]
    half = one / (one + one)
    mwx, mwy, mwz = half * (p1x + p0x), half * (p1y + p0y), half * (p1z + p0z)
    sx, sy, sz = p1x - p0x, p1y - p0y, p1z - p0z
    mx = c00 * mwx + c01 * mwy + c02 * mwz + t0
    my = c10 * mwx + c11 * mwy + c12 * mwz + t1
    mz = c20 * mwx + c21 * mwy + c22 * mwz + t2
    dx = c00 * sx + c01 * sy + c02 * sz
    dy = c10 * sx + c11 * sy + c12 * sz
    dz = c20 * sx + c21 * sy + c22 * sz
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


@njit(cache=True, inline="always")
def _padded(P):
    """Segments of a P-point strand padded to a whole number of 8-lane vectors."""
    return (P - 1 + 7) // 8 * 8


@njit(cache=True, inline="always")
def _camera(w2c, b, like):
    """Frame b's rotation and translation as the tuple (c00, c01, ..., c22, t0, t1, t2) in the type of ``like``."""
    return (lane_cast(w2c[b, 0, 0], like), lane_cast(w2c[b, 0, 1], like), lane_cast(w2c[b, 0, 2], like),
            lane_cast(w2c[b, 1, 0], like), lane_cast(w2c[b, 1, 1], like), lane_cast(w2c[b, 1, 2], like),
            lane_cast(w2c[b, 2, 0], like), lane_cast(w2c[b, 2, 1], like), lane_cast(w2c[b, 2, 2], like),
            lane_cast(w2c[b, 0, 3], like), lane_cast(w2c[b, 1, 3], like), lane_cast(w2c[b, 2, 3], like))


@njit(cache=True, inline="always")
def _load_strand(points, b, n, pT):
    """pT[:, :P] := strand n of frame b ([3, Q + 1], one row per coordinate, in pT's dtype); the
    columns after P repeat the last point (the padding segments: zero length, results unused)."""
    P = points.shape[2]
    for j in range(P):
        pT[0, j], pT[1, j], pT[2, j] = points[b, n, j, 0], points[b, n, j, 1], points[b, n, j, 2]
    for j in range(P, pT.shape[1]):
        pT[0, j], pT[1, j], pT[2, j] = pT[0, P - 1], pT[1, P - 1], pT[2, P - 1]


# The per-segment loops below run over one strand's points in rows (pT[c, j]) and write rows of
# results: with the [G, 8] tables indexed directly, LLVM versions the loop on the tables' row length
# being 1 (a run-time stride it cannot see) and runs the scalar copy (measured: no faster than
# without vectorisation); with rows it runs 4 (AVX2) or 8 (AVX-512) segments at a time. Each
# lane computes what the scalar code computed (no fast-math), so the results are the same bits.
@njit(cache=True, error_model="numpy", inline="never")
def _forward_strand(pT, cam, k, nr, w2, dil, tiny, eps_d, eps_l, res):
    """res[:, j] := (u, v, q_xx, q_xy, q_yy, z, cos 2a, sin 2a, s_xx, s_xy, s_yy) of segment j, for
    every column of ``res`` (pT: [3, Q + 1]; k: (k00, k01, k02, k10, k11, k12))."""
    k00, k01, k02, k10, k11, k12 = k
    for j in range(res.shape[1]):
        (mx, my, mz, dx, dy, dz, zc, iz, X, Y, ja, jb, sx, sy, sz, len2e, coef, sxx, sxy,
         syy) = _segment(pT, j, cam, k00, k01, k10, k11, nr, w2, dil, eps_l)
        xn, yn = mx / zc, my / zc
        u = k00 * xn + k01 * yn + k02
        v = k10 * xn + k11 * yn + k12
        n2 = ja * ja + jb * jb + eps_d
        det = max(sxx * syy - sxy * sxy, tiny)
        res[0, j], res[1, j] = u, v
        res[2, j], res[3, j], res[4, j] = syy / det, -sxy / det, sxx / det
        res[5, j] = mz
        res[6, j], res[7, j] = (ja * ja - jb * jb) / n2, (ja + ja) * jb / n2
        res[8, j], res[9, j], res[10, j] = sxx, sxy, syy


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
    z0 = points[0, 0, 0, 0] * 0  # float64 zero (numba: float32 * int -> float64), as the constants
    w2 = lane_cast(strand_width, z0) * lane_cast(strand_width, z0)
    dil, nr = lane_cast(dilation, z0), lane_cast(near, z0)
    tiny, eps_d, eps_l = lane_cast(1e-12, z0), lane_cast(1e-12, z0), lane_cast(1e-20, z0)
    Q = _padded(P)
    for c in prange((B * N + _CHUNK - 1) // _CHUNK):
        pT, res = np.empty((3, Q + 1), points.dtype), np.empty((11, Q))  # res: z0's type, float64
        for bn in range(c * _CHUNK, min(B * N, (c + 1) * _CHUNK)):
            b, n = bn // N, bn - (bn // N) * N
            k = (K[b, 0, 0], K[b, 0, 1], K[b, 0, 2], K[b, 1, 0], K[b, 1, 1], K[b, 1, 2])
            _load_strand(points, b, n, pT)
            _forward_strand(pT, _camera(w2c, b, w2c[0, 0, 0]), k, nr, w2, dil, tiny, eps_d, eps_l, res)
            for j in range(P - 1):
                g = b * S + n * (P - 1) + j
                for q in range(8):
                    gpar[g, q] = res[q, j]
                covs[g, 0], covs[g, 1], covs[g, 2] = res[8, j], res[9, j], res[10, j]
                u, v, mz = res[0, j], res[1, j], res[5, j]
                valid[g] = (mz > nr) & math.isfinite(u) & math.isfinite(v) & math.isfinite(res[8, j]) & \
                    math.isfinite(res[9, j]) & math.isfinite(res[10, j])


@njit(cache=True, error_model="numpy", inline="never")
def _backward_strand(pT, cam, k00, k01, k10, k11, near, w2, dilation, gT, terms):
    """The two terms of each segment j's gradient for its end points (float64): terms[0:3, j] for
    point j (0.5 d/d midpoint - d/d segment), terms[3:6, j] for point j + 1 (0.5 d/d midpoint
    + d/d segment, plus 0.0), from gT[:, j], the gradient of its table row (pT: [3, Q + 1])."""
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = cam[0], cam[1], cam[2], cam[3], cam[4], cam[5], cam[6], \
        cam[7], cam[8]
    for j in range(terms.shape[1]):
        gu, gv, gqxx, gqxy, gqyy = gT[G_MX, j], gT[G_MY, j], gT[G_QXX, j], gT[G_QXY, j], gT[G_QYY, j]
        gz, gc, gs = gT[G_Z, j], gT[G_C, j], gT[G_S, j]
        # forward again, in float64
        (mx, my, mz, dx, dy, dz, zc, iz, X, Y, ja, jb, sx, sy, sz, len2e, coef, sxx, sxy,
         syy) = _segment(pT, j, cam, k00, k01, k10, k11, near, w2, dilation, 1e-20)
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
        gmw0 = c00 * g_mx + c10 * g_my + c20 * g_mz
        gmw1 = c01 * g_mx + c11 * g_my + c21 * g_mz
        gmw2 = c02 * g_mx + c12 * g_my + c22 * g_mz
        gs0 = c00 * g_dx + c10 * g_dy + c20 * g_dz + 2.0 * sx * g_len2
        gs1 = c01 * g_dx + c11 * g_dy + c21 * g_dz + 2.0 * sy * g_len2
        gs2 = c02 * g_dx + c12 * g_dy + c22 * g_dz + 2.0 * sz * g_len2
        terms[0, j], terms[1, j], terms[2, j] = 0.5 * gmw0 - gs0, 0.5 * gmw1 - gs1, 0.5 * gmw2 - gs2
        terms[3, j], terms[4, j] = 0.0 + (0.5 * gmw0 + gs0), 0.0 + (0.5 * gmw1 + gs1)
        terms[5, j] = 0.0 + (0.5 * gmw2 + gs2)


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
    Q = _padded(P)
    for c in prange((B * N + _CHUNK - 1) // _CHUNK):
        pT, gT = np.empty((3, Q + 1)), np.zeros((8, Q))
        terms, drawn = np.empty((6, Q)), np.empty(P - 1, np.bool_)
        for bn in range(c * _CHUNK, min(B * N, (c + 1) * _CHUNK)):
            b, n = bn // N, bn - (bn // N) * N
            any_drawn = False
            for j in range(P - 1):  # the gradient's rows as float64 columns; undrawn segments: all zero
                g = b * S + n * (P - 1) + j
                d = False
                for q in range(8):
                    gT[q, j] = np.float64(grad[g, q])  # numba's float() keeps float32
                    d |= gT[q, j] != 0.0
                drawn[j] = d
                any_drawn |= d
            if not any_drawn:  # (possibly non-finite) segments the loss does not see
                for j in range(P):
                    out[b, n, j, 0] = out[b, n, j, 1] = out[b, n, j, 2] = 0.0
                continue
            _load_strand(points, b, n, pT)
            k00, k01, k10, k11 = float(K[b, 0, 0]), float(K[b, 0, 1]), float(K[b, 1, 0]), float(K[b, 1, 1])
            _backward_strand(pT, _camera(w2c, b, 0.0), k00, k01, k10, k11, near, w2, dilation, gT, terms)
            a0 = a1 = a2 = 0.0  # point j's sum so far (float64): the term of segment j - 1
            for j in range(P - 1):
                if drawn[j]:
                    out[b, n, j, 0], out[b, n, j, 1], out[b, n, j, 2] = a0 + terms[0, j], a1 + terms[1, j], \
                        a2 + terms[2, j]
                    a0, a1, a2 = terms[3, j], terms[4, j], terms[5, j]
                else:  # an undrawn segment adds nothing (its terms may be non-finite)
                    out[b, n, j, 0], out[b, n, j, 1], out[b, n, j, 2] = a0, a1, a2
                    a0 = a1 = a2 = 0.0
            out[b, n, P - 1, 0], out[b, n, P - 1, 1], out[b, n, P - 1, 2] = a0, a1, a2
