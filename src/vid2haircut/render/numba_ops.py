"""The numba backend's projection and image channels as differentiable torch ops.

:func:`project_fused` (strand points -> the [G, 8] Gaussian table, :mod:`.numba_project`) and
:func:`channels_fused` (pixel sums -> depth, direction and mask, :mod:`.numba_channels`) wrap one
numba kernel forward and one backward each; :func:`gaussian_table` builds the same table from torch's
Gaussians. The compositing between them, and the choice of backend, are in :mod:`.numba_backend`.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from vid2haircut.render.gaussians import conics
from vid2haircut.render.numba_backend import _LOCK, _numba_threads


def gaussian_table(means: Tensor, covs: Tensor, depths: Tensor, dirs: Tensor) -> Tensor:
    """[G, 8] table (mean x, mean y, q_xx, q_xy, q_yy, z, cos2a, sin2a) of flattened Gaussians
    (differentiable; the layout :func:`composite_fused` takes and :func:`project_fused` makes)."""
    qxx, qxy, qyy = conics(covs)
    return torch.stack([means[:, 0], means[:, 1], qxx, qxy, qyy, depths, dirs[:, 0], dirs[:, 1]], 1)


class _FusedProject(torch.autograd.Function):
    @staticmethod
    def forward(ctx, points, K, world_2_cam, strand_width, dilation, near):
        from vid2haircut.render import numba_project as npj

        B, N, P = points.shape[:3]
        G = B * N * (P - 1)
        points = points.detach().contiguous()
        K, world_2_cam = K.detach().to(points.dtype).contiguous(), world_2_cam.detach().to(points.dtype).contiguous()
        gpar, covs = np.empty((G, 8), points.numpy().dtype), np.empty((G, 3), points.numpy().dtype)
        valid = np.empty(G, np.bool_)
        with _LOCK:
            _numba_threads()
            npj.project_forward(points.numpy(), K.numpy(), world_2_cam.numpy(), strand_width, dilation, near, gpar,
                                covs, valid)
        ctx.save_for_backward(points, K, world_2_cam)  # autograd's version check guards in-place edits
        ctx.consts = (strand_width, dilation, near)
        covs_t, valid_t = torch.from_numpy(covs), torch.from_numpy(valid)
        ctx.mark_non_differentiable(covs_t, valid_t)
        ctx.set_materialize_grads(False)  # no zero-filled gradients of covs and valid
        return torch.from_numpy(gpar), covs_t, valid_t

    @staticmethod
    def backward(ctx, grad, _g_covs, _g_valid):
        from vid2haircut.render import numba_project as npj

        if grad is None:
            return None, None, None, None, None, None
        pts, Kn, En = (t.numpy() for t in ctx.saved_tensors)
        out = np.empty(pts.shape, pts.dtype)  # float64 sums, stored in the points' dtype
        g = grad.detach().contiguous().numpy()
        with _LOCK:
            npj.project_backward(pts, Kn, En, *ctx.consts, g, out)
        return torch.from_numpy(out).to(grad.dtype), None, None, None, None, None


def project_fused(points: Tensor, K: Tensor, world_2_cam: Tensor, strand_width: float, dilation: float,
                  near: float) -> tuple[Tensor, Tensor, Tensor]:
    """The numba twin of :func:`vid2haircut.render.gaussians.segment_gaussians` + :func:`gaussian_table`.

    Args:
        points: [B, N, P, 3] CPU float32 / float64 world points; K [B, 3, 3], world_2_cam [B, 4, 4]
            (no gradients reach them).

    Returns:
        (table [B * S, 8] differentiable w.r.t. ``points`` (see :func:`gaussian_table`), covs
        [B * S, 3], valid [B * S] bool), S = N * (P - 1), segments strand-major per frame.
    """
    return _FusedProject.apply(points, K, world_2_cam, float(strand_width), float(dilation), float(near))


class _FusedChannels(torch.autograd.Function):
    @staticmethod
    def forward(ctx, weight, wz, dirs):
        from vid2haircut.render import numba_channels as nc

        w, z, d = (t.detach().contiguous() for t in (weight, wz, dirs))
        shape = w.shape
        wn, zn, dn = w.numpy().reshape(-1), z.numpy().reshape(-1), d.numpy().reshape(-1, 2)
        dt = wn.dtype
        depth, direction, mask = np.empty_like(wn), np.empty_like(dn), np.empty(wn.shape, np.bool_)
        consts = tuple(np.array(v, dt) for v in (1e-12, 1e-20, 0.5))
        with _LOCK:
            _numba_threads()
            nc.channels_forward(wn, zn, dn, *consts, depth, direction, mask)
        ctx.save_for_backward(w, z, d)
        ctx.consts = consts[:2]
        mask_t = torch.from_numpy(mask).reshape(shape)
        ctx.mark_non_differentiable(mask_t)
        ctx.set_materialize_grads(False)
        return torch.from_numpy(depth).reshape(shape), torch.from_numpy(direction).reshape(*shape, 2), mask_t

    @staticmethod
    def backward(ctx, g_depth, g_dir, _g_mask):
        from vid2haircut.render import numba_channels as nc

        w, z, d = ctx.saved_tensors
        wn, zn, dn = w.numpy().reshape(-1), z.numpy().reshape(-1), d.numpy().reshape(-1, 2)
        with_depth, with_dir = g_depth is not None, g_dir is not None
        gd = g_depth.detach().to(w.dtype).contiguous().numpy().reshape(-1) if with_depth else np.zeros(0, wn.dtype)
        gv = g_dir.detach().to(w.dtype).contiguous().numpy().reshape(-1, 2) if with_dir else np.zeros((0, 2), wn.dtype)
        g_w, g_wz = (np.empty_like(wn), np.empty_like(wn)) if with_depth else (np.zeros(0, wn.dtype),) * 2
        g_dirs = np.empty_like(dn) if with_dir else np.zeros((0, 2), wn.dtype)
        with _LOCK:
            _numba_threads()
            nc.channels_backward(wn, zn, dn, gd, gv, *ctx.consts, with_depth, with_dir, g_w, g_wz, g_dirs)
        if not with_depth:
            return None, None, (torch.from_numpy(g_dirs).reshape(d.shape) if with_dir else None)
        return (torch.from_numpy(g_w).reshape(w.shape), torch.from_numpy(g_wz).reshape(w.shape),
                torch.from_numpy(g_dirs).reshape(d.shape) if with_dir else None)


def channels_fused(weight: Tensor, wz: Tensor, dirs: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The image channels of :func:`vid2haircut.render.api.render_strands` from the pixel sums, in one
    numba pass forward and one backward (:mod:`.numba_channels`), bit for bit torch's.

    Args:
        weight, wz: [B, H, W] CPU float32 / float64 (1 - transmittance, sum w z); dirs: [B, H, W, 2].

    Returns:
        (depth [B, H, W], direction [B, H, W, 2], mask [B, H, W] bool), differentiable w.r.t. the
        three inputs but the mask.
    """
    if wz.shape != weight.shape or dirs.shape != (*weight.shape, 2):  # the kernels index all three alike
        raise ValueError(f"channels_fused: weight {tuple(weight.shape)}, wz {tuple(wz.shape)} and dirs "
                         f"{tuple(dirs.shape)} must be [B, H, W], [B, H, W] and [B, H, W, 2]")
    return _FusedChannels.apply(weight, wz, dirs)


class _FusedNormalize(torch.autograd.Function):
    @staticmethod
    def forward(ctx, depth, mask):
        from vid2haircut.render import numba_channels as nc

        d = depth.detach().contiguous()
        B = d.shape[0]
        M = int(np.prod(d.shape[1:]))
        dn, mn = d.numpy().reshape(B, M), mask.contiguous().numpy().reshape(B, M)
        out, stats = np.empty_like(dn), np.empty((B, 4))
        with _LOCK:
            _numba_threads()
            nc.normalize_forward(dn, mn, out, stats)
        ctx.arrays, ctx.dtype = (dn, mn, out, stats), depth.dtype
        return torch.from_numpy(out).reshape(d.shape)

    @staticmethod
    def backward(ctx, grad):
        from vid2haircut.render import numba_channels as nc

        dn, mn, out, stats = ctx.arrays
        g = grad.detach().to(ctx.dtype).contiguous()
        g_depth = np.empty_like(dn)
        with _LOCK:
            _numba_threads()
            nc.normalize_backward(dn, mn, out, stats, g.numpy().reshape(dn.shape), g_depth)
        return torch.from_numpy(g_depth).reshape(grad.shape), None


def normalize_depth_fused(depth: Tensor, mask: Tensor) -> Tensor:
    """:func:`vid2haircut.render.api.normalize_depth` in one numba pass forward and one backward
    (:func:`.numba_channels.normalize_forward`): the same values; the gradient equal to autograd's
    to round-off (torch's ~25 operations took 1.27 ms forward and backward for one 256 x 256 frame
    on the project's 2-core CPU; 0.40 ms here with autograd's overhead, the two kernels 0.08 ms each).

    Args:
        depth: [B, H, W] CPU float32 / float64; mask: [B, H, W] bool.
    """
    if mask.shape != depth.shape or mask.dtype != torch.bool:
        raise ValueError(f"normalize_depth_fused: depth {tuple(depth.shape)} needs a bool mask of the same shape, "
                         f"got {mask.dtype} {tuple(mask.shape)}")
    return _FusedNormalize.apply(depth, mask)
