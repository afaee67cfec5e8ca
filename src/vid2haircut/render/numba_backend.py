"""Fused CPU compositing backend (numba) behind :func:`vid2haircut.render.render_strands`.

Choice: ``backend="auto"`` (the default) picks these kernels for CPU tensors of dtype float32 or
float64 when numba imports, and the torch kernels (:mod:`.raster`, :mod:`.kernels`) otherwise
(CUDA, other dtypes, numba missing); ``"torch"`` and ``"numba"`` force one. Both implement the
same compositing model over the same kind of pixel windows (:func:`.footprint.gaussian_windows`).
The numba backend projects the segments itself (:func:`.numba_ops.project_fused`, :mod:`.numba_project`:
one loop forward and one backward instead of ~40 torch operations and their autograd graph)
and computes its windows itself (:func:`.numba_windows.gaussian_windows`), unless K or
world_2_cam require gradients: then it takes torch's Gaussians and torch's windows, bit for
bit those of the torch backend (torch's float32 square root is not always correctly rounded,
so numba's windows can differ from torch's by a pixel at an edge in rare cases). The two agree
to float round-off (tests/test_render_backends.py checks values and gradients). Why a second
backend: the torch kernels need ~13 gather/scatter and ~55 elementwise passes over the
(Gaussian, pixel) contributions; the fused kernels (:mod:`.numba_kernels`) composite one screen
tile at a time in cache, walking the windows line by line with vector lanes
(:mod:`.numba_lines`), ~3x less time for forward+backward (numbers in :mod:`.api`). With
``t_min`` (``compositing="exact"``), :func:`composite_fused` hands the Gaussians to the kernels of
:mod:`.numba_exact` in depth order instead (sorted here, gradients and visibility mapped back).

Compilation: on first use, once per machine, ~21 s for the first dtype and ~13 s for the other
(measured, 2 cores), then cached on disk (``cache=True``: ``__pycache__`` next to the modules,
or numba's user cache directory); loading the cache costs ~0.5 s per process. numba's cache
follows the source file of each compiled function, not the modules it inlines: after editing
:mod:`.numba_math`, :mod:`.numba_simd` or :mod:`.numba_lines` alone, delete the ``*.nbi`` /
``*.nbc`` files of ``__pycache__`` (a package install or update replaces every file, so users are
not affected).
Threads: ``min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS)``, on numba's TBB
threading layer where the ``tbb`` package's library loads, else its workqueue layer
(:func:`numba_available`); the results are bitwise identical for any thread count and either
layer. The kernels share the cores with torch's OpenMP workers, which spin for a while after each
parallel torch op; importing vid2haircut before torch shortens
that spin (``GOMP_SPINCOUNT``, see the package docstring). Memory: the forward pass keeps 16
bytes per window element for the backward pass in float32 (24 in float64; ~120 MB allocated for
4k strands at 256 x 256, about 40% of it touched).
"""

from __future__ import annotations

import functools
import os
import threading

import numpy as np
import torch
from torch import Tensor

from vid2haircut.render import numba_simd
from vid2haircut.render.allocator import aligned_empty
from vid2haircut.render.footprint import gaussian_windows
from vid2haircut.render.kernels import KernelConsts
from vid2haircut.render.types import PixelSums

BACKENDS = ("auto", "numba", "torch")
_LOCK = threading.Lock()  # numba's workqueue layer must not be entered from two threads at once
TILE = 16
"""Screen tile size (pixels) of the fused kernels."""


@functools.lru_cache(maxsize=1)
def numba_available() -> bool:
    """True when numba imports (the fused kernels are then usable on CPU).

    Unless the environment sets ``NUMBA_THREADING_LAYER``, numba's threading layer is chosen here
    (before any parallel kernel runs): "tbb" when Intel's TBB library (the ``tbb`` package of
    environment.lock) loads (:func:`tbb_layer_usable`), else "workqueue"; never numba's default
    OpenMP layer, whose workers and torch's spin-wait against each other after every parallel
    region (measured: 70 ms instead of 4 ms per small render, and torch ops slowed 3x). Both idle
    their workers without that contention; TBB starts a parallel region in ~2 us, the workqueue
    layer in 30-120 us (it wakes a sleeping worker each time), and a render runs ~20 of them:
    4000 strands at 256 x 256, exact compositing, forward+backward 41.4-47.4 -> 36.4-37.2 ms; 300
    strands at 64 x 64, 7.0 -> 4.2 ms (best of 100; median 10.9 -> 5.4 ms), on the project's
    2-core CPU (AMD EPYC, Zen 3); torch's own ops the same. The results do not depend on the
    layer: no kernel reduces across the iterations of a parallel loop. The workqueue layer does
    not support launching kernels from several Python threads at once, so this module runs its
    kernels under a lock (concurrent renders wait for each other) whatever the layer.
    """
    try:
        import numba
    except ImportError:
        return False
    tbb = tbb_layer_usable()  # (loads the library: also for a layer the environment names, "tbb" or "safe")
    if "NUMBA_THREADING_LAYER" not in os.environ:
        numba.config.THREADING_LAYER = "tbb" if tbb else "workqueue"
    return True


@functools.lru_cache(maxsize=1)
def tbb_layer_usable() -> bool:
    """Load Intel's TBB library for numba's "tbb" threading layer; True when that layer can run.

    numba's tbb extension finds ``libtbb.so.12`` through the dynamic loader only, and pip puts the
    ``tbb`` wheel's library in ``<environment>/lib``, which the loader does not search: it is
    loaded here by path first (global symbols), then by name (a system install). numba then checks
    the TBB version itself (2021.6 or later)."""
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return False
    for path in (os.path.join(sys.prefix, "lib", "libtbb.so.12"), "libtbb.so.12"):
        try:
            ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
        except OSError:
            continue
        try:
            from numba.np.ufunc import tbbpool  # noqa: F401  (the layer's extension; needs the library)
        except ImportError:
            return False
        try:
            from numba.np.ufunc.parallel import _check_tbb_version_compatible
        except ImportError:  # another numba: it checks when it starts the layer
            return True
        try:
            _check_tbb_version_compatible()
        except ImportError:
            return False
        return True
    return False


def resolve_backend(backend: str, points: Tensor) -> str:
    """``"numba"`` or ``"torch"`` for ``backend`` in ("auto", "numba", "torch") and these points.

    Raises ValueError for an unknown name, or for "numba" with CUDA tensors, an unsupported dtype
    or numba not installed.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    ok = points.device.type == "cpu" and points.dtype in (torch.float32, torch.float64)
    if backend == "auto":
        return "numba" if ok and numba_available() else "torch"
    if backend == "numba" and not (ok and numba_available()):
        raise ValueError("backend='numba' needs numba installed and float32/float64 CPU points, got "
                         f"{points.dtype} on {points.device} (numba installed: {numba_available()})")
    return backend


class _Plan:
    """Everything the kernels need besides the differentiable Gaussian values (numpy arrays)."""

    def __init__(self, wint, wflt, frame, z, head, consts: KernelConsts, batch: int, height: int, width: int, dtype,
                 ratio: float = 0.0, t_min: float | None = None):
        import numba

        from vid2haircut.render import numba_tiles, numba_walk

        self.wint, self.wflt = wint, wflt
        self.exact = t_min is not None  # front to back (numba_exact), the Gaussians numbered by depth
        self.has_head = head is not None
        self.head = head if head is not None else np.zeros((1, 1, 1), dtype)
        with _LOCK:
            _numba_threads()
            hmax = numba_tiles.tile_head_max(self.head, self.has_head, batch, width, height, TILE)
            self.gstart, self.inst_pos, self.tile_start, self.sorted_g, boxes, inst_csr = numba_tiles.bin_windows(
                wint, wflt, frame, batch, width, height, TILE, z, hmax, self.exact)
            self.boxes = boxes if self.exact else None  # (box codes for the exact model's walk)
            self.inst_csr = inst_csr if self.exact else None
            bounds = numba_walk.tile_bounds(self.tile_start, self.sorted_g, wint, self.boxes, width, height, TILE)
        bounds = bounds + TILE  # room for the zeros of the walk's last 16-lane store (numba_simd)
        self.offsets = np.concatenate([[0], np.cumsum(bounds)[:-1]]).astype(np.int64)
        self.capacity = int(bounds.sum())
        self.consts = np.array([consts.log_opacity, consts.alpha_min, consts.alpha_max, ratio], np.float64)
        self.second = ratio > 0.0
        self.nbins = int(consts.bins) if consts.shading else 1
        self.vis_weight = float(consts.vis_weight)
        self.shape = (batch, height, width)
        self.t_min = float(t_min) if self.exact else 0.0
        self.shade = bool(consts.shading)
        self.order = None  # exact: [G] the Gaussians' depth order (numba_records.depth_order)
        self.work_start, self.work_tiles = numba_tiles.assign_tiles(self.tile_start, numba.get_num_threads())
        # shapes of the kernels' four per-pixel outputs (sum l, sum w z, direction sums, sum l2) and
        # of their gradients; empty where the kernels neither write nor read them
        shade, img, none = self.nbins > 1, (batch, height, width), (0, 0, 0)
        self.out_shapes = (img, img if shade else none, img + (2,) if shade else none + (0,),
                           img if self.second else none)


def _numba_threads() -> int:
    """numba's thread count := ``min(torch.get_num_threads(), NUMBA_NUM_THREADS)`` (the kernels run
    as many threads as torch would); returns it."""
    import numba

    n = max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(n)
    return n


class _FusedComposite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, table, zs, plan):
        from vid2haircut.render import numba_kernels as nk

        if plan.exact:
            return _exact_forward(ctx, table, plan)

        gpar = table.detach().contiguous().numpy()
        zs_np = zs.detach().contiguous().numpy()
        B, H, W = plan.shape
        out = tuple(np.zeros(shape, zs_np.dtype) for shape in plan.out_shapes)
        cap = plan.capacity
        cap2 = cap if plan.second else 0
        elems = (np.empty(cap, np.int32), np.empty(cap, np.int32), np.empty(cap, gpar.dtype), np.empty(cap, gpar.dtype),
                 np.empty(cap2, gpar.dtype), np.empty(cap2, gpar.dtype))
        e_range = np.empty((plan.sorted_g.shape[0], 2), np.int64)
        visible = np.zeros(gpar.shape[0], np.bool_)
        with _LOCK:
            nk.composite_forward(gpar, zs_np, plan.wint, plan.wflt, plan.head, plan.has_head, plan.consts,
                                 plan.nbins, plan.tile_start, plan.sorted_g, plan.boxes, plan.work_start,
                                 plan.work_tiles, W, H, TILE, plan.offsets, elems, e_range, out, plan.vis_weight, visible,
                                 numba_simd.USE_LINE16 and TILE == 16)  # numba_simd.line16: 16 lanes
        ctx.plan, ctx.gpar, ctx.elems, ctx.e_range, ctx.dtype = plan, gpar, elems, e_range, table.dtype
        visible_t = torch.from_numpy(visible)
        ctx.mark_non_differentiable(visible_t)
        ctx.set_materialize_grads(False)  # outputs the loss does not reach: None (zeros in backward)
        return (*(torch.from_numpy(o) for o in out), visible_t)

    @staticmethod
    def backward(ctx, g_l, g_z, g_d, g_2, _g_vis):
        from vid2haircut.render import numba_kernels as nk

        plan = ctx.plan
        if plan.exact:
            return _exact_backward(ctx, g_l, g_2, g_z, g_d)
        B, H, W = plan.shape
        g = _grad_images((g_l, g_z, g_d, g_2), plan.out_shapes, ctx.gpar.dtype)
        acc = aligned_empty((plan.sorted_g.shape[0], nk.N_ACC), np.float64)  # composite_backward writes every entry
        grads = aligned_empty((ctx.gpar.shape[0], 8), ctx.gpar.dtype)  # float64 sums, stored in the table's dtype
        with _LOCK:
            nk.composite_backward(ctx.gpar, plan.consts, plan.nbins, plan.tile_start, plan.sorted_g,
                                  plan.work_start, plan.work_tiles, W, H, TILE, ctx.elems, ctx.e_range, g, acc)
            nk.reduce_gradients(plan.gstart, plan.inst_pos, ctx.gpar, acc, grads)
        return torch.from_numpy(grads).to(ctx.dtype), None, None


def _grad_images(grads, shapes, dtype) -> tuple:
    """The upstream gradients of the compositing outputs as numpy arrays of ``dtype`` (the table's:
    one compiled kernel per dtype; the kernels sum in float64), zeros where autograd passed None,
    empty where the kernels do not read them (``shapes``: the outputs' shapes, empty ones first 0)."""
    tdt = torch.from_numpy(np.empty(0, dtype)).dtype
    return tuple(np.zeros(shape, dtype) if t is None or shape[0] == 0 else t.detach().to(tdt).contiguous().numpy()
                 for t, shape in zip(grads, shapes))


def _exact_forward(ctx, table, plan):
    """:class:`_FusedComposite`'s forward with :mod:`.numba_exact`."""
    from vid2haircut.render import numba_exact as ne

    gpar = plan.gpar_sorted  # the table's rows in depth order (views of numba_records.gaussian_records)
    z_np = gpar[:, 5]
    B, H, W = plan.shape
    dt = gpar.dtype
    none = (0, 0, 0)
    out = (np.zeros((B, H, W), dt), np.zeros((B, H, W), dt), np.zeros((B, H, W) if plan.shade else none, dt),
           np.zeros((B, H, W, 2) if plan.shade else none + (0,), dt))  # log T, silhouette, sum w z, directions
    sums = np.empty((B, H, W, 3) if plan.shade else none + (0,))  # (read where the forward wrote it, as t_end)
    t_end = np.empty((B, H, W))  # (read by the backward pass only where the forward pass wrote it)
    cap = plan.capacity
    elems = (np.empty(cap, np.int32), np.empty(cap, dt), np.empty(cap, dt))
    e_range = np.empty((plan.sorted_g.shape[0], 2), np.int64)
    visible = np.zeros(gpar.shape[0], np.bool_)
    tile_kept = np.zeros(plan.tile_start.shape[0] - 1, np.int64)
    with _LOCK:
        ne.composite_exact_forward(gpar, z_np, plan.wint, plan.wflt, plan.head, plan.has_head, plan.consts,
                                   plan.shade, plan.tile_start, plan.sorted_g, plan.boxes, plan.work_start,
                                   plan.work_tiles, W, H, TILE, plan.offsets, elems, e_range, out, sums, t_end,
                                   plan.vis_weight, visible,
                                   numba_simd.USE_LINE16 and TILE == 16, plan.t_min, plan.order, tile_kept)
    ctx.plan, ctx.gpar, ctx.elems, ctx.e_range, ctx.dtype, ctx.sums = plan, gpar, elems, e_range, table.dtype, sums
    ctx.t_end, ctx.tile_kept = t_end, tile_kept
    visible_t = torch.from_numpy(visible)  # in the table's order (the kernel maps it back)
    ctx.mark_non_differentiable(visible_t)
    ctx.set_materialize_grads(False)
    log_t, weight, wz, wdirs = (torch.from_numpy(o) for o in out)
    return log_t, wz, wdirs, weight, visible_t  # (the silhouette in the slot of the bins' second one)


def _exact_backward(ctx, g_l, g_w, g_z, g_d):
    """:class:`_FusedComposite`'s backward with :mod:`.numba_exact` (``g_w``: the silhouette's)."""
    from vid2haircut.render import numba_exact as ne, numba_kernels as nk

    plan = ctx.plan
    B, H, W = plan.shape
    shapes = ((B, H, W), (B, H, W), (B, H, W) if plan.shade else (0, 0, 0), (B, H, W, 2) if plan.shade else (0, 0, 0, 0))
    g = _grad_images((g_l, g_w, g_z, g_d), shapes, ctx.gpar.dtype)
    kept = ctx.tile_kept  # rows of sums for the instances with elements only, tile by tile
    acc_start = np.concatenate([[0], np.cumsum(kept)[:-1]]).astype(np.int64)
    acc = aligned_empty((int(kept.sum()), nk.N_ACC), np.float64)  # one cache line a row (read scattered)
    slot = np.full(plan.sorted_g.shape[0], -1, np.int32)  # each instance's row, in Gaussian order (-1: none)
    grads = aligned_empty((ctx.gpar.shape[0], 8), ctx.gpar.dtype)
    with _LOCK:
        ne.composite_exact_backward(ctx.gpar, plan.shade, plan.tile_start, plan.sorted_g, plan.work_start,
                                    plan.work_tiles, W, H, TILE, ctx.elems, ctx.e_range, g, ctx.sums, ctx.t_end, acc,
                                    acc_start, plan.inst_csr, slot)
        nk.reduce_gradients(plan.gstart, plan.inst_pos, ctx.gpar, acc, grads, plan.order, slot)  # in the table's order
    return torch.from_numpy(grads).to(ctx.dtype), None, None


def composite_fused(
    table: Tensor,  # [G, 8]
    covs: Tensor,  # [G, 3]
    valid: Tensor,  # [G] bool
    frame: Tensor,  # [G] int64
    batch: int,
    height: int,
    width: int,
    consts: KernelConsts,
    power_min: float,
    head_depth: Tensor | None = None,  # [B, H, W]
    torch_windows: bool = False,
    silhouette_ratio: float = 0.0,
    t_min: float | None = None,
) -> tuple[PixelSums, Tensor, Tensor | None]:
    """Composite G Gaussians (flattened over frames) into per-pixel sums with the fused CPU kernels.

    Same contract as :func:`vid2haircut.render.raster.composite`, but the Gaussians come as the
    differentiable [G, 8] table of :func:`.numba_ops.gaussian_table` (or :func:`.numba_ops.project_fused`) and their
    covariances, and ``valid``, ``frame`` and ``power_min`` = log(alpha_min / opacity) replace the
    footprint. ``torch_windows``: take the pixel windows from the torch backend's
    :func:`vid2haircut.render.footprint.gaussian_windows` (bit for bit its windows: for Gaussians
    projected by torch) instead of :func:`vid2haircut.render.numba_windows.gaussian_windows`.
    ``silhouette_ratio`` in (0, 1): also composite a second silhouette at that fraction of the
    opacity, from the same window walk (:func:`.numba_walk.alpha_and_l2`). ``t_min``: composite
    exactly front to back, each pixel stopping below this transmittance (:mod:`.numba_exact`;
    without a second silhouette); None: the binned model.

    Returns:
        (:class:`PixelSums` with [B, H, W] fields, visible [G] bool, the second silhouette's
        [B, H, W] sum of log(1 - alpha) or None).
    """
    from vid2haircut.render import numba_windows

    if t_min is not None and silhouette_ratio > 0.0:
        raise ValueError("exact compositing draws no second silhouette in the same walk")
    dt = table.dtype
    means = table[:, 0:2].detach()
    exact_windows = t_min is not None and not torch_windows  # (computed while gathered in depth order, below)
    if torch_windows:
        win = gaussian_windows(means, covs.detach(), valid, height, width, power_min)
        wint = torch.stack([win.horizontal.to(torch.int64), win.u_lo.to(torch.int64), win.ntu * win.cols,
                            win.ntv * win.rows], 1).contiguous().numpy()
        wflt = torch.stack([win.slope, win.v0], 1).contiguous().numpy()
    elif not exact_windows:
        G = means.shape[0]
        wint, wflt = np.empty((G, 4), np.int64), np.empty((G, 2), np.float32)
        with _LOCK:
            _numba_threads()
            numba_windows.gaussian_windows(means.numpy(), covs.detach().contiguous().numpy(),
                                           valid.contiguous().numpy(), height, width, power_min, 4, 8, wint, wflt)
    frame_np = frame.to(torch.int64).contiguous().numpy()
    order = gpar_sorted = None
    if t_min is None:
        z = table[:, 5].detach().contiguous()
        z_np = z.numpy()
    else:  # exact front-to-back compositing: the kernels see the Gaussians in depth order, as records
        from vid2haircut.render import numba_records

        tab = table.detach().contiguous().numpy()
        # one cache-line record per Gaussian: its row, depth and window (numba_records.gaussian_records)
        gpar_sorted, rec_wint, rec_wflt = numba_records.gaussian_records(tab.shape[0], tab.dtype)
        with _LOCK:
            threads = _numba_threads()
            # (the strided column: a copy first cost as much as it saved)
            order = numba_records.depth_order(tab[:, 5], threads)
            if exact_windows:  # the windows computed into the records
                frame_np = numba_records.gather_windows(order, tab, covs.detach().contiguous().numpy(),
                                                        valid.contiguous().numpy(), frame_np, height, width,
                                                        power_min, 4, gpar_sorted, rec_wint, rec_wflt)
            else:
                frame_np = numba_records.gather_gaussians(order, tab, wint, wflt, frame_np, gpar_sorted,
                                                          rec_wint, rec_wflt)
        wint, wflt, z_np = rec_wint, rec_wflt, gpar_sorted[:, 5]  # (strided views of the records)
    head = None
    if head_depth is not None:  # compared in the input dtype, as the torch kernels do
        head = head_depth.detach().to(dt).contiguous().numpy()
    plan = _Plan(wint, wflt, frame_np, z_np, head, consts, batch, height,
                 width, np.float32 if dt == torch.float32 else np.float64, silhouette_ratio, t_min)
    plan.order = order
    plan.gpar_sorted = gpar_sorted
    zs = z * (1.0 / consts.depth_bin) if order is None else None  # bin units, rounded like the torch kernels
    log_t, wz, wdirs, log_t2, visible = _FusedComposite.apply(table, zs, plan)
    if plan.exact:  # the kernels' silhouette (in the second silhouette's slot)
        weight, log_t2 = log_t2, None
    else:
        weight = -torch.expm1(log_t) + 0.0  # + 0.0 turns -0.0 into 0.0
        log_t2 = log_t2 if plan.second else None
    if not consts.shading:
        zeros = torch.zeros_like(log_t)
        return PixelSums(log_t, weight, zeros, torch.stack([zeros, zeros], -1)), visible, log_t2
    return PixelSums(log_t, weight, wz, wdirs), visible, log_t2
