"""Bad arguments to the Python API (camera, strands, metrics, codec, mesh depth): an error naming the
argument."""

from __future__ import annotations

import numpy as np
import pytest


def test_python_api_arguments_are_named():
    """Researchers' calls with the wrong types or values: an error naming the argument."""
    from vid2haircut.camera import Camera, intrinsics_from_fov, look_at
    from vid2haircut.evaluate.metrics import evaluate_strands
    from vid2haircut.io.strand_formats import save_strands
    from vid2haircut.polylines import resample_polyline_list
    from vid2haircut.strands import StrandSet

    pts = np.zeros((2, 4, 3), np.float32)
    pts[:, :, 2] = np.arange(4) * 0.01
    s = StrandSet(pts)
    with pytest.raises(TypeError, match="pred must be a StrandSet"):
        evaluate_strands(pts, s)
    with pytest.raises(ValueError, match="max_points must be a whole number >= 0"):
        evaluate_strands(s, s, max_points=-5)
    with pytest.raises(TypeError, match="save_strands needs a StrandSet"):
        save_strands("x.npz", pts)
    with pytest.raises(ValueError, match="n_points must be a whole number >= 2, got 5.7"):
        s.resample(5.7)
    with pytest.raises(ValueError, match=r"polyline 1 must be \(P, 3\), got shape \(4, 2\)"):
        resample_polyline_list([pts[0], np.zeros((4, 2))])
    K = intrinsics_from_fov(64, 64, 30.0)
    with pytest.raises(ValueError, match="fov_y_deg must be in"):
        intrinsics_from_fov(64, 64, 180.0)
    with pytest.raises(ValueError, match="eye and target are the same point"):
        look_at(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="parallel to up"):
        look_at(np.array([0.0, 1.0, 0.0]), np.zeros(3))
    E = look_at(np.array([0.0, 0.0, 0.7]), np.zeros(3))
    for args, message in [((np.eye(4), E, 64, 64), "K must be a finite 3x3"), ((K, E, -64, 64), "width must be a "),
                          ((K, np.eye(3), 64, 64), "world_2_cam must be a finite 4x4"),
                          ((K * 0, E, 64, 64), "K must be .* positive focal lengths")]:
        with pytest.raises(ValueError, match=f"Camera: {message}"):
            Camera(*args)
    cam = Camera(K.tolist(), E, 64.0, 64)
    assert isinstance(cam.K, np.ndarray) and cam.width == 64 and isinstance(cam.width, int)


def test_codec_and_mesh_depth_arguments():
    import torch

    from vid2haircut.prior.codec import StrandCodec
    from vid2haircut.render import mesh_depth

    rng = np.random.default_rng(0)
    strands = np.cumsum(rng.normal(size=(20, 5, 3)) * 0.01, axis=1)
    with pytest.raises(ValueError, match="k must be a whole number in"):
        StrandCodec.fit(strands, k=3.5)
    codec = StrandCodec.fit(strands, k=4)
    with pytest.raises(ValueError, match="k must be a whole number in"):
        codec.truncate(2.5)
    half = codec.encode(torch.as_tensor(strands, dtype=torch.float16))  # computed in float32
    assert half.dtype == torch.float32 and torch.isfinite(half).all()
    v = torch.tensor([[[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [0.0, 1.0, 2.0]]])
    K = torch.tensor([[[10.0, 0, 7.5], [0, 10.0, 7.5], [0, 0, 1]]])
    E = torch.eye(4)[None]
    for faces, size, error, message in [(torch.tensor([[0, 1, -1]]), (16, 16), ValueError, "faces index vertices -1..1"),
                                        (torch.tensor([[0, 1, 3]]), (16, 16), ValueError, r"the mesh has 3 \(0..2\)"),
                                        (torch.tensor([[0.0, 1, 2]]), (16, 16), ValueError, "integer vertex indices"),
                                        (torch.tensor([[0, 1, 2]]), (16, -3), ValueError, "must be positive"),
                                        (torch.tensor([[0, 1, 2]]), (16.5, 16), TypeError, "whole numbers")]:
        with pytest.raises(error, match=message):
            mesh_depth(v, faces, K, E, *size)
    assert mesh_depth(v, torch.tensor([[0, 1, 2]]), K, E, np.int64(16), 16).shape == (1, 16, 16)
