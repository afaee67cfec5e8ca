"""Differentiable strand rasterizer: strands as strand-aligned Gaussians.

Projection and footprints are torch; compositing (forward and backward) runs in fused numba kernels
on the CPU (:mod:`.numba_backend`) and in torch on CUDA or when numba is missing (``backend=``).

Public API:
    render_strands(points, K, world_2_cam, width, height, ...) -> StrandRender
    segment_gaussians(points, K, world_2_cam, ...) -> Gaussians2D
    mesh_depth(vertices, faces, K, world_2_cam, width, height) -> [B, H, W] head depth
    project_points(points, K, world_2_cam) -> (uv, z)
"""

from vid2haircut.render.allocator import tune_cpu_allocator
from vid2haircut.render.api import DEFAULT_ALPHA_MIN, normalize_depth, render_strands
from vid2haircut.render.gaussians import DEFAULT_DILATION, DEFAULT_STRAND_WIDTH, segment_gaussians
from vid2haircut.render.mesh_depth import mesh_depth
from vid2haircut.render.project import project_points
from vid2haircut.render.types import Footprint, Gaussians2D, PixelSums, StrandRender

__all__ = [
    "DEFAULT_ALPHA_MIN", "DEFAULT_DILATION", "DEFAULT_STRAND_WIDTH", "Footprint", "Gaussians2D", "PixelSums",
    "StrandRender", "mesh_depth", "normalize_depth", "project_points", "render_strands", "segment_gaussians",
    "tune_cpu_allocator",
]
