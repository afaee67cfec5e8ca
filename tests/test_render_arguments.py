"""Tests of the strand renderer (vid2haircut.render): bad arguments are refused with clear errors."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest
import torch


sys.path.insert(0, str(Path(__file__).parent))
from render_scenes import (BACKENDS, DT, backend, line, orbit_camera, quad_depth, random_scene,  # noqa: E402,F401
                           simple_camera)
from render_scenes import render_bins as render_strands  # noqa: E402  (the binned model on both backends)


def test_bad_input_raises_clear_errors():
    K, E = simple_camera()
    with pytest.raises(ValueError, match="points"):
        render_strands(torch.zeros(1, 2, 3, dtype=DT), K, E, 32, 32)
    with pytest.raises(ValueError, match="at least 2 points"):
        render_strands(torch.zeros(1, 2, 1, 3, dtype=DT), K, E, 32, 32)
    with pytest.raises(ValueError, match="K must have shape"):
        render_strands(torch.zeros(2, 2, 3, 3, dtype=DT), K, E, 32, 32)
    with pytest.raises(ValueError, match="head_depth"):
        render_strands(torch.zeros(1, 2, 3, 3, dtype=DT), K, E, 32, 32, head_depth=torch.zeros(1, 16, 16))
    with pytest.raises(ValueError, match="image size"):
        render_strands(torch.zeros(1, 2, 3, 3, dtype=DT), K, E, 0, 32)
    with pytest.raises(ValueError, match="vis_weight"):
        render_strands(torch.zeros(1, 2, 3, 3, dtype=DT), K, E, 32, 32, vis_weight=0.0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_bad_arguments_are_refused_before_any_kernel(backend):
    """Arguments a kernel would misread are refused up front: one depth bin (the numba kernels had
    written out of bounds: a crash), sizes that are not whole numbers or too large (tile counts
    overflow), half-precision points (covariances overflow to a blank image), non-finite or
    impossible cameras, widths and depth maps (blank or mirrored images)."""
    pts = torch.tensor([[[[-0.02, 0.0, 0.5], [0.0, 0.0, 0.5], [0.02, 0.0, 0.5]]]], dtype=DT)
    K = torch.tensor([[[400.0, 0, 31.5], [0, 400.0, 31.5], [0, 0, 1]]], dtype=DT)
    E = torch.eye(4, dtype=DT)[None]
    cases = [
        (dict(bins=1), ValueError, "2 <= bins <= 1024"),
        (dict(bins=10**9), ValueError, "2 <= bins <= 1024"),
        (dict(bins=2.5), TypeError, "bins must be a whole number"),
        (dict(depth_bin=float("nan")), ValueError, "finite depth_bin > 0"),
        (dict(width=64.5), TypeError, "width must be a whole number"),
        (dict(width=2**36, height=2**36), ValueError, "at most 16384 a side"),
        (dict(points=pts.half()), ValueError, "float32 or float64 tensor, got torch.float16"),
        (dict(K=K * float("nan")), ValueError, "K and world_2_cam must be finite"),
        (dict(K=K * 0.0), ValueError, "positive focal lengths"),
        (dict(world_2_cam=E * float("inf")), ValueError, "must be finite"),
        (dict(strand_width=-1e-3), ValueError, "strand_width, dilation and near >= 0"),
        (dict(strand_width=float("nan")), ValueError, "strand_width, dilation and near >= 0"),
        (dict(near=-1.0), ValueError, "strand_width, dilation and near >= 0"),
        (dict(dilation=-0.2), ValueError, "strand_width, dilation and near >= 0"),
        (dict(head_depth=torch.full((1, 64, 64), float("nan"), dtype=DT)), ValueError, "head_depth has NaN"),
        (dict(head_depth=torch.ones((1, 64, 64), dtype=torch.bool)), ValueError, "head_depth must be a float"),
    ]
    for kw, error, message in cases:
        args = dict(points=pts, K=K, world_2_cam=E, width=64, height=64, backend=backend)
        args.update(kw)
        with pytest.raises(error, match=re.escape(message)):
            render_strands(**args)
    # whole numbers of other types and a numpy head depth map are fine
    out = render_strands(pts, K, E, np.int64(64), torch.tensor(64), backend=backend,
                         head_depth=np.full((1, 64, 64), np.inf))
    assert float(out.silhouette.sum()) > 1
    # integer cameras are cast to the points' dtype (as before these checks), 64.0 is a whole number
    same = render_strands(pts, torch.tensor([[[400, 0, 31], [0, 400, 31], [0, 0, 1]]]), torch.eye(4, dtype=torch.int64)[None],
                          64.0, 64, backend=backend)
    assert float(same.silhouette.sum()) > 1
