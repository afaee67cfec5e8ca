"""Shared scenes, cameras and the backend fixture of the renderer tests (test_render*.py)."""

from __future__ import annotations

import functools

import numpy as np
import pytest
import torch

from vid2haircut.camera import intrinsics_from_fov, look_at
from vid2haircut.render import mesh_depth, render_strands
from vid2haircut.render.numba_backend import numba_available

DT = torch.float64
BACKENDS = ["torch", pytest.param("numba", marks=pytest.mark.skipif(not numba_available(), reason="needs numba"))]
render_bins = functools.partial(render_strands, compositing="bins")
"""``render_strands`` with the binned compositing model, which both backends implement: the model
that the backend-parametrised tests check (the numba backend's default, the exact model, has its
own tests in test_render_exact.py, which also reruns the physical tests with it)."""


@pytest.fixture(params=BACKENDS)
def backend(request):
    """Every rendering test runs once per compositing backend."""
    return request.param


def simple_camera(size: int = 33, f: float = 400.0, batch: int = 1):
    """Camera at the origin looking down +z (identity extrinsics), principal point at the centre
    (odd sizes put the optical axis on a pixel centre)."""
    c = (size - 1) / 2.0
    K = torch.tensor([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]], dtype=DT).expand(batch, 3, 3)
    return K.contiguous(), torch.eye(4, dtype=DT).expand(batch, 4, 4).contiguous()


def line(p0, p1, n: int = 6) -> torch.Tensor:
    """[n, 3] points evenly spaced from p0 to p1."""
    t = torch.linspace(0, 1, n, dtype=DT)[:, None]
    return torch.tensor(p0, dtype=DT) * (1 - t) + torch.tensor(p1, dtype=DT) * t


def random_scene(seed: int, n: int = 6, p: int = 6, spread: float = 0.02):
    rng = np.random.default_rng(seed)
    roots = rng.uniform(-spread, spread, (n, 3))
    steps = rng.normal(0, 0.004, (n, p - 1, 3)) + np.array([0.0, -0.006, 0.0])
    return np.concatenate([roots[:, None], roots[:, None] + np.cumsum(steps, 1)], 1)[None]


def orbit_camera(size: int):
    K = intrinsics_from_fov(size, size, 30.0)[None]
    E = look_at(np.array([0.0, 0.0, 0.25]), np.zeros(3))[None]
    return K, E


def quad_depth(z: float, size: int, K, E):
    """Head depth of a camera-facing quad at camera depth z covering the view (via mesh_depth)."""
    v = torch.tensor([[[-1.0, -1.0, z], [1.0, -1.0, z], [1.0, 1.0, z], [-1.0, 1.0, z]]], dtype=DT)
    return mesh_depth(v, torch.tensor([[0, 1, 2], [0, 2, 3]]), K, E, size, size)
