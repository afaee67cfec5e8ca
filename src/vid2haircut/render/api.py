"""Public functional API of the strand renderer: :func:`render_strands`.

Pipeline: strand points -> one 2D Gaussian per segment (:mod:`.gaussians`, EWA projection) ->
pixel windows (:mod:`.footprint`) -> order-independent compositing into pixel sums -> image
channels (here). Two compositing backends implement the same model (``backend`` argument):
the torch kernels (:mod:`.raster`, :mod:`.kernels`; any device) and fused numba kernels
(:mod:`.numba_backend`; CPU, the default there when numba is installed). They agree to float
round-off (tests/test_render.py: 1e-15 in float64, ~1e-6 in float32, values and gradients).

Accuracy against the exact per-pixel front-to-back reference (tests/render_reference.py) is
documented in :mod:`vid2haircut.render.raster` and checked by tests/test_render.py. A second
compositing model, exact front to back with early termination (``compositing="exact"``, numba
backend only: :mod:`.numba_exact`), equals that reference to round-off where no pixel stops early
(elsewhere the silhouette is within ``t_min``) and takes 0.43-0.70 of the
binned model's time (README, Performance). It is the default where the numba backend renders
(``compositing="auto"``); the torch kernels (any device, CUDA) have the binned model only.

Performance (benchmarks/render_bench.py; 4k strands x 32 points = 124k segments at 256 x 256,
7.6 M (Gaussian, pixel) window contributions, 3.1 M of them drawn).
Torch kernels, measured on quiet pinned CPU cores of the device machine, torch 2.11: forward
280 ms, forward+backward 520-580 ms with 2 threads (900 ms with 1), silhouette-only
forward+backward 295 ms; a plain scatter_add_ of the same 7.6 M values takes 15 ms there, so
fwd+bwd is ~40x that ceiling (~13 gather/scatter and ~55 elementwise passes over the
contributions, plus ~65 ms of footprint building). On an H100 (one chunk): fwd+bwd ~17-50 ms
per frame, ~32 ms for 8 frames per call.
Numba backend (``python benchmarks/render_bench.py --backend numba``, 2 threads, torch 2.13):
on a 2-core AMD EPYC (Zen 4, AVX-512), forward 27-32 ms and forward+backward 49-53 ms, 9.9-10.4x a
scatter_add_ of the same 7.6 M values (4.9-5.1 ms there; the code before the explicit vector line kernel
of :mod:`.numba_simd`, the register compaction, the OpenMP spin setting, the culling of tiles
hidden by the head and the merged backward passes: 99 / 133 ms); on a 2-core Intel Xeon (AVX-512)
the code before measured 52 / 84 ms, 7.0x its 12 ms scatter-add.
Breakdown and history: README, Performance; benchmarks/RESULTS.md, "The renderer on an AMD EPYC
(Zen 4)".
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from vid2haircut.checks import as_whole
from vid2haircut.render.allocator import tune_cpu_allocator
from vid2haircut.render.footprint import build_footprint
from vid2haircut.render.gaussians import DEFAULT_DILATION, DEFAULT_STRAND_WIDTH, check_points, segment_gaussians
from vid2haircut.render.kernels import KernelConsts
from vid2haircut.render.project import NUMPY_FLOATS, check_cameras
from vid2haircut.render.numba_backend import composite_fused, resolve_backend
from vid2haircut.render.numba_ops import channels_fused, gaussian_table, normalize_depth_fused, project_fused
from vid2haircut.render.raster import composite
from vid2haircut.render.types import Gaussians2D, PixelSums, StrandRender

MAX_SIDE = 16384
"""Largest image side :func:`render_strands` accepts (beyond it the tile and pixel counts of a
batch outgrow the kernels' index types)."""
COMPOSITINGS = ("auto", "bins", "exact")
"""The renderer's compositing models; "auto" is "exact" where the numba backend renders and "bins"
elsewhere (:func:`resolve_compositing`)."""
"""Compositing models of :func:`render_strands`."""
MAX_BINS = 1024
"""Most depth bins :func:`render_strands` accepts (the per-tile bin tables are bins x pixels)."""

DEFAULT_ALPHA_MIN = math.exp(-4.5)
"""Contributions below this alpha are dropped (the ellipse is cut at 3 standard deviations)."""


def render_strands(
    points: Tensor,  # [B, N, P, 3] world
    K: Tensor,  # [B, 3, 3]
    world_2_cam: Tensor,  # [B, 4, 4]
    width: int,
    height: int,
    strand_width: float = DEFAULT_STRAND_WIDTH,
    head_depth: Tensor | None = None,  # [B, H, W]
    *,
    opacity: float = 1.0,
    dilation: float = DEFAULT_DILATION,
    alpha_min: float = DEFAULT_ALPHA_MIN,
    alpha_max: float = 0.99,
    depth_bin: float = 1e-3,
    bins: int = 32,
    vis_weight: float = 0.3,
    near: float = 1e-2,
    shading: bool = True,
    backend: str = "auto",
    silhouette_opacity: float | None = None,
    compositing: str = "auto",
    t_min: float = 1e-4,
) -> StrandRender:
    """Render strands as strand-aligned Gaussians to silhouette, direction and depth maps.

    Differentiable w.r.t. ``points`` through silhouette, direction and depth. Runs on the device
    of ``points`` (CPU or CUDA); all frames are rendered in one call.

    Args:
        points: [B, N, P, 3] strand points in world space (metres), P >= 2; one set per frame
            (frames may differ because hair moves). N and P may change from call to call.
        K: [B, 3, 3] intrinsics; world_2_cam: [B, 4, 4] extrinsics (OpenCV: x right, y down,
            z forward; pixel centres at integer coordinates, row = y, column = x).
        width, height: image size in pixels.
        strand_width: short-axis size of each 3D Gaussian (metres; default 0.35 mm).
        head_depth: optional [B, H, W] camera z of the head surface, +inf where there is no head
            (e.g. from :func:`vid2haircut.render.mesh_depth.mesh_depth`); hair behind it is hidden.
        opacity: peak opacity of each Gaussian (default 1).
        dilation: screen-space covariance dilation in px^2 (anti-aliasing; default 0.3).
        alpha_min: contributions with alpha below it are dropped (default exp(-4.5): 3 sigma).
        alpha_max: alpha is clamped to it so that log(1 - alpha) stays finite (default 0.99).
        depth_bin, bins: depth compositing resolution: per pixel, contributions are ordered in
            ``bins`` bins of ``depth_bin`` metres from the nearest one (default 32 x 1 mm; see
            :mod:`vid2haircut.render.raster`).
        vis_weight: a segment is visible when its compositing weight reaches this at some pixel.
        near: segments closer than this (metres) are not drawn.
        shading: False renders the silhouette only (much faster); depth, direction and
            visibility are then zeros / False.
        backend: compositing kernels: "torch" (any device), "numba" (fused CPU kernels) or
            "auto" (default: numba for float32/float64 CPU points when numba imports, else torch;
            see :mod:`vid2haircut.render.numba_backend`). Both give the same result up to float
            round-off.
        silhouette_opacity: when given, ``silhouette`` is that of the same strands drawn at this
            peak opacity (e.g. translucent guides in a silhouette term), while ``mask``, depth,
            direction and visibility stay those at ``opacity``: the same as replacing the
            silhouette by that of a second, silhouette-only render at this opacity. The numba
            backend composites both from one window walk when it is below ``opacity``.
        compositing: "exact" (front to back in each Gaussian's depth order, each pixel stopping
            once its transmittance falls below ``t_min``; numba backend only, :mod:`.numba_exact`),
            "bins" (the depth-binned model, :mod:`vid2haircut.render.raster`; both backends) or
            "auto" (default: "exact" where the numba backend renders, else "bins";
            :func:`resolve_compositing`).
        t_min: the transmittance at which a pixel stops compositing with ``compositing="exact"``.

    Returns:
        :class:`StrandRender` (see its field docs for shapes and empty-pixel values).

    Example:
        >>> import torch
        >>> pts = torch.tensor([[[[-0.02, 0.0, 0.5], [0.0, 0.0, 0.5], [0.02, 0.0, 0.5]]]])
        >>> K = torch.tensor([[[400.0, 0, 31.5], [0, 400.0, 31.5], [0, 0, 1]]])
        >>> out = render_strands(pts, K, torch.eye(4)[None], 64, 64)
        >>> out.silhouette.shape, bool(out.mask[0, 31, 31]), round(float(out.angle[0, 31, 31]), 3)
        (torch.Size([1, 64, 64]), True, 0.0)
    """
    width, height, bins = _whole("width", width), _whole("height", height), _whole("bins", bins)
    if not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE):
        raise ValueError(f"image size must be positive and at most {MAX_SIDE} a side, got {width} x {height}")
    if not 0.0 < opacity <= 1.0 or not 0.0 < alpha_min < min(opacity, alpha_max) or not alpha_max < 1.0:
        raise ValueError(f"need 0 < alpha_min < min(opacity, alpha_max) and alpha_max < 1, got "
                         f"alpha_min={alpha_min}, opacity={opacity}, alpha_max={alpha_max}")
    if not (0.0 < depth_bin < math.inf and 2 <= bins <= MAX_BINS):
        raise ValueError(f"need a finite depth_bin > 0 and 2 <= bins <= {MAX_BINS} (one bin has no depth order), "
                         f"got depth_bin={depth_bin}, bins={bins}")
    if not (0.0 <= strand_width < math.inf and 0.0 <= dilation < math.inf and 0.0 <= near < math.inf):
        raise ValueError(f"need finite strand_width, dilation and near >= 0 (metres, pixels, metres), got "
                         f"strand_width={strand_width}, dilation={dilation}, near={near}")
    if not vis_weight > 0.0:  # a weight of 0 would call every segment whose window touches the image visible
        raise ValueError(f"vis_weight must be > 0, got {vis_weight}")
    if silhouette_opacity is not None and not alpha_min < silhouette_opacity <= 1.0:
        raise ValueError(f"silhouette_opacity must be in (alpha_min, 1] = ({alpha_min}, 1], got {silhouette_opacity}")
    points = torch.as_tensor(points)
    check_points(points)
    use_numba = resolve_backend(backend, points) == "numba"
    compositing = resolve_compositing(compositing, "numba" if use_numba else "torch")
    if compositing == "exact" and not use_numba:
        raise ValueError("compositing='exact' needs the numba backend (CPU float32 / float64 points, numba installed)")
    if compositing == "exact" and not 0.0 < t_min < 1.0:  # (also when "auto" names the exact model)
        raise ValueError(f"t_min must be in (0, 1), got {t_min}")
    exact_t_min = t_min if compositing == "exact" else None
    B, N, P = points.shape[0], points.shape[1], points.shape[2]
    if points.device.type == "cpu":
        tune_cpu_allocator()  # see vid2haircut.render.allocator
    if head_depth is not None:
        head_depth = torch.as_tensor(head_depth, device=points.device)
        if head_depth.shape != (B, height, width) or not head_depth.is_floating_point():
            raise ValueError(f"head_depth must be a float tensor of shape ({B}, {height}, {width}), got "
                             f"{head_depth.dtype} {tuple(head_depth.shape)}")
        hd = head_depth.detach()  # (checked on the CPU only: on a GPU it would be a device sync per render)
        if hd.device.type == "cpu" and bool(np.isnan(hd.numpy() if hd.dtype in NUMPY_FLOATS else hd.float().numpy()).any()):
            raise ValueError("head_depth has NaN entries (use inf where there is no head)")
    K = torch.as_tensor(K, device=points.device)
    world_2_cam = torch.as_tensor(world_2_cam, device=points.device)
    K, world_2_cam = (t if t.is_floating_point() else t.to(points.dtype) for t in (K, world_2_cam))
    check_cameras(K, world_2_cam, B)
    S = N * (P - 1)
    G = B * S
    table = None  # the numba backend's [G, 8] Gaussian table
    # the numba projection, when gradients need to reach the points only
    if use_numba and not (K.requires_grad or world_2_cam.requires_grad):
        table, covs, valid = project_fused(points, K, world_2_cam, strand_width, dilation, near)
        g = Gaussians2D(table[:, 0:2].reshape(B, S, 2), covs.reshape(B, S, 3), table[:, 5].reshape(B, S),
                        table[:, 6:8].reshape(B, S, 2), valid.reshape(B, S))
    else:
        g = segment_gaussians(points, K, world_2_cam, strand_width, dilation, near)
    frame = torch.arange(B, device=points.device)[:, None].expand(B, S).reshape(G)  # (a copy: faster than repeat_interleave)
    log_op = math.log(opacity)
    # CPU: cache-sized chunks; GPU: one chunk (each chunk costs kernel launches, not memory traffic)
    chunk = 262_144 if points.device.type == "cpu" else 1 << 62
    consts = KernelConsts(log_op, alpha_min, alpha_max, depth_bin, int(bins), vis_weight, shading, chunk)
    flat = (g.means.reshape(G, 2), g.covs.reshape(G, 3), g.depths.reshape(G), g.dirs.reshape(G, 2))
    power_min = math.log(alpha_min) - log_op
    # a translucent silhouette below the opacity comes from the same walk in the numba backend
    fused_second = (use_numba and silhouette_opacity is not None and silhouette_opacity < opacity
                    and exact_t_min is None)
    log_t2 = None
    if use_numba:
        torch_projection = table is None
        if torch_projection:
            table = gaussian_table(*flat)
        ratio = silhouette_opacity / opacity if fused_second else 0.0
        sums, visible, log_t2 = composite_fused(table, flat[1], g.valid.reshape(G), frame, B, height, width, consts,
                                                power_min, head_depth, torch_windows=torch_projection,
                                                silhouette_ratio=ratio, t_min=exact_t_min)
    else:
        fp = build_footprint(flat[0], flat[1], g.valid.reshape(G), frame, height, width, power_min)
        sums, visible = composite(*flat, fp, B, height, width, consts, head_depth)
    out = _finish(sums, visible.reshape(B, N, P - 1), g, fused=use_numba)
    if log_t2 is not None:
        return out._replace(silhouette=-torch.expm1(log_t2) + 0.0)
    if silhouette_opacity is not None and silhouette_opacity != opacity:  # a second render
        second = render_strands(points, K, world_2_cam, width, height, strand_width, head_depth,
                                opacity=silhouette_opacity, dilation=dilation, alpha_min=alpha_min,
                                alpha_max=alpha_max, near=near, shading=False, backend=backend,
                                compositing=compositing, t_min=t_min)
        return out._replace(silhouette=second.silhouette)
    return out


def resolve_compositing(compositing: str, backend: str) -> str:
    """The compositing model ("bins" or "exact") that ``compositing`` names for a render by
    ``backend`` (the resolved one, "numba" or "torch": :func:`.numba_backend.resolve_backend`):
    "auto" is "exact" with the numba kernels (the CPU; within 5x of a scatter-add of its window
    contributions, README "Performance") and "bins" with the torch kernels (any device), which have
    only that model. The named models are returned as they are.

    Raises ValueError for an unknown name.
    """
    if compositing not in COMPOSITINGS:
        raise ValueError(f"compositing must be one of {COMPOSITINGS}, got {compositing!r}")
    if compositing == "auto":
        return "exact" if backend == "numba" else "bins"
    return compositing


def _whole(name: str, value) -> int:
    """``value`` as an int (:func:`vid2haircut.checks.as_whole`); TypeError naming ``name`` otherwise."""
    v = as_whole(value)
    if v is None:
        raise TypeError(f"{name} must be a whole number, got {value!r}")
    return v


def _finish(sums: PixelSums, visibility: Tensor, g, fused: bool = False) -> StrandRender:
    """Pixel sums -> image channels (``fused``: by the numba backend's kernels, the same values)."""
    silhouette = sums.weight
    if fused:
        depth, direction, mask = channels_fused(sums.weight, sums.depth, sums.dirs)
    else:
        weight = sums.weight
        filled = weight > 1e-12
        safe_w = torch.where(filled, weight, 1.0)  # scalar branches: no filled tensors to allocate
        depth = torch.where(filled, sums.depth / safe_w, 0.0)
        norm2 = (sums.dirs * sums.dirs).sum(-1)
        has_dir = norm2 > 1e-20
        inv = torch.where(has_dir, torch.rsqrt(torch.where(has_dir, norm2, 1.0)), 0.0)
        direction = sums.dirs * inv[..., None]  # (0, 0) where there is no direction (StrandRender.angle)
        mask = (silhouette > 0.5) & filled
    depth_normalized = normalize_depth_fused(depth, mask) if fused else normalize_depth(depth, mask)
    return StrandRender(silhouette, direction, depth, depth_normalized, mask, visibility, g)


def normalize_depth(depth: Tensor, mask: Tensor) -> Tensor:
    """Min-max normalise [B, H, W] depth to [0, 1] inside the [B, H, W] bool mask per frame; 0 outside.

    Differentiable (the gradient reaches the pixels holding the minimum and maximum too).
    """
    big = torch.finfo(depth.dtype).max
    dmin = torch.where(mask, depth, big).amin((1, 2), keepdim=True)
    dmax = torch.where(mask, depth, -big).amax((1, 2), keepdim=True)
    any_ = mask.any((1, 2), keepdim=True)
    dmin = torch.where(any_, dmin, 0.0)
    span = torch.where(any_, dmax - dmin, 1.0).clamp_min(1e-8)
    return torch.where(mask, (depth - dmin) / span, 0.0)
