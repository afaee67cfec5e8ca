"""Head-mesh depth rasterizer (vectorised triangle z-buffer in torch; not differentiable).

Used as the occluder of the strand renderer: hair behind the head surface is not drawn.
"""

from __future__ import annotations

import torch
from torch import Tensor

from vid2haircut.checks import as_whole

from vid2haircut.render.project import check_cameras, project_camera_points, to_camera


@torch.no_grad()
def mesh_depth(
    vertices: Tensor,  # [B, V, 3] world
    faces: Tensor,  # [F, 3] int
    K: Tensor,  # [B, 3, 3]
    world_2_cam: Tensor,  # [B, 4, 4]
    width: int,
    height: int,
    near: float = 1e-2,
    chunk: int = 4_000_000,
) -> Tensor:
    """Camera depth of the nearest triangle at every pixel centre.

    Each triangle is rasterised over the pixel centres of its screen bounding box (pixel centres
    at integer coordinates); depth is interpolated perspective-correctly (1/z is linear in screen
    space) and the nearest wins (``scatter_reduce`` amin). Triangles with a vertex closer than
    ``near`` are skipped.

    Args:
        vertices: [B, V, 3] mesh vertices per frame (world, metres). faces: [F, 3] vertex indices.
        K: [B, 3, 3]; world_2_cam: [B, 4, 4]; width, height: image size.
        chunk: largest number of (triangle, pixel) candidates handled at once (memory bound).

    Returns:
        [B, H, W] camera z of the surface, +inf where no triangle covers the pixel centre.

    Example:
        >>> v = torch.tensor([[[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [0.0, 1.0, 2.0]]])
        >>> K = torch.tensor([[[10.0, 0, 7.5], [0, 10.0, 7.5], [0, 0, 1]]])
        >>> d = mesh_depth(v, torch.tensor([[0, 1, 2]]), K, torch.eye(4)[None], 16, 16)
        >>> float(d[0, 8, 8]), bool(torch.isinf(d[0, 0, 0]))
        (2.0, True)
    """
    if vertices.ndim != 3 or vertices.shape[-1] != 3:
        raise ValueError(f"vertices must have shape (B, V, 3), got {tuple(vertices.shape)}")
    if faces.ndim != 2 or faces.shape[-1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {tuple(faces.shape)}")
    if faces.is_floating_point() or faces.dtype == torch.bool:
        raise ValueError(f"faces must hold integer vertex indices, got {faces.dtype}")
    if faces.numel() and not (0 <= int(faces.min()) and int(faces.max()) < vertices.shape[1]):
        raise ValueError(f"faces index vertices {int(faces.min())}..{int(faces.max())}, the mesh has "
                         f"{vertices.shape[1]} (0..{vertices.shape[1] - 1})")
    w, h = as_whole(width), as_whole(height)
    if w is None or h is None:
        raise TypeError(f"image size must be whole numbers, got {width!r} x {height!r}")
    width, height = w, h
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    B = vertices.shape[0]
    check_cameras(K, world_2_cam, B)
    dev = vertices.device
    out_dtype = vertices.dtype
    cam = to_camera(vertices.to(torch.float64), world_2_cam.to(torch.float64))
    uv, z = project_camera_points(cam, K.to(torch.float64), near)
    faces = faces.to(device=dev, dtype=torch.int64)
    tri_uv = uv[:, faces]  # [B, F, 3, 2]
    tri_z = z[:, faces]  # [B, F, 3]
    F = faces.shape[0]
    ok = (tri_z > near).all(-1)
    lo = torch.ceil(tri_uv.amin(2)).clamp_min(0)
    hi = torch.floor(tri_uv.amax(2))
    hi = torch.minimum(hi, torch.tensor([width - 1.0, height - 1.0], dtype=hi.dtype, device=dev))
    ext = (hi - lo + 1).clamp_min(0)
    count = torch.where(ok, (ext[..., 0] * ext[..., 1]), torch.zeros_like(ext[..., 0])).to(torch.int64).reshape(-1)

    out = torch.full((B * height * width,), float("inf"), dtype=torch.float64, device=dev)
    tri_uv = tri_uv.reshape(B * F, 3, 2)
    tri_z = tri_z.reshape(B * F, 3)
    lo = lo.reshape(B * F, 2).to(torch.int64)
    ext_x = ext[..., 0].reshape(B * F).to(torch.int64)
    ends = torch.cumsum(count, 0)
    start = 0
    while start < B * F:
        # take as many triangles as fit in one chunk (at least one)
        limit = (ends[start - 1] if start > 0 else 0) + chunk
        stop = max(start + 1, int(torch.searchsorted(ends, torch.as_tensor(limit, device=dev), right=True)))
        stop = min(stop, B * F)
        _raster_chunk(out, torch.arange(start, stop, device=dev), count[start:stop], tri_uv, tri_z, lo, ext_x,
                      F, height, width)
        start = stop
    return out.reshape(B, height, width).to(out_dtype)


def _raster_chunk(out: Tensor, tris: Tensor, count: Tensor, tri_uv: Tensor, tri_z: Tensor, lo: Tensor,
                  ext_x: Tensor, F: int, height: int, width: int) -> None:
    """Rasterise triangles ``tris`` (indices into the flattened [B * F] list) into ``out``."""
    t = torch.repeat_interleave(tris, count)
    if t.numel() == 0:
        return
    first = torch.cumsum(count, 0) - count
    local = torch.arange(t.shape[0], device=t.device) - torch.repeat_interleave(first, count)
    ex = ext_x[t]
    px = (lo[t, 0] + local % ex).to(torch.float64)
    py = (lo[t, 1] + local // ex).to(torch.float64)
    a, b, c = tri_uv[t, 0], tri_uv[t, 1], tri_uv[t, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    w0 = (b[:, 0] - px) * (c[:, 1] - py) - (b[:, 1] - py) * (c[:, 0] - px)
    w1 = (c[:, 0] - px) * (a[:, 1] - py) - (c[:, 1] - py) * (a[:, 0] - px)
    w2 = area - w0 - w1
    sgn = torch.sign(area)
    inside = (area.abs() > 1e-12) & (w0 * sgn >= 0) & (w1 * sgn >= 0) & (w2 * sgn >= 0)
    safe = torch.where(inside, area, torch.ones_like(area))
    inv_z = (w0 / tri_z[t, 0] + w1 / tri_z[t, 1] + w2 / tri_z[t, 2]) / safe
    zpix = torch.where(inside, 1.0 / inv_z, torch.full_like(inv_z, float("inf")))
    frame = t // F
    idx = (frame * height + py.to(torch.int64)) * width + px.to(torch.int64)
    out.scatter_reduce_(0, idx, zpix, "amin")
