"""The target silhouettes' distance field: the outside loss (vid2haircut.fit.image_terms.outside_loss),
silhouette carving of the dense output (vid2haircut.fit.carve) and strand cutting."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vid2haircut.fit.carve import carve_lengths, carve_strands, silhouette_excess
from vid2haircut.fit.data import downsample_targets
from vid2haircut.fit.image_terms import outside_loss
from vid2haircut.polylines import cut_strands


def _camera(width: int = 32, height: int = 24):
    """One keyframe 1 m in front of the origin; the 'silhouette' is the image's left half: the
    distance field is 0 up to column 15 and grows by 1 per pixel to the right of it."""
    K = torch.tensor([[[100.0, 0.0, (width - 1) / 2], [0.0, 100.0, (height - 1) / 2], [0.0, 0.0, 1.0]]])
    cfh = torch.eye(4)[None].clone()
    cfh[0, 2, 3] = 1.0
    cols = torch.arange(width, dtype=torch.float32)
    outside = torch.clamp(cols - 15.0, min=0.0)[None, None].expand(1, height, width).contiguous()
    return K, cfh, outside


def _strand_along_x(x0: float, x1: float, p: int = 11) -> np.ndarray:
    return np.stack([np.linspace(x0, x1, p), np.zeros(p), np.zeros(p)], -1)[None].astype(np.float32)


def test_cut_strands_resamples_the_kept_part_and_leaves_the_rest():
    pts = np.concatenate([_strand_along_x(0.0, 0.1), _strand_along_x(0.0, -0.1)])
    out = cut_strands(pts, np.array([6, 11]))
    assert np.allclose(out[0, :, 0], np.linspace(0.0, 0.05, 11), atol=1e-7)   # ends at point 5, evenly spaced
    assert np.array_equal(out[1], pts[1]) and out.dtype == pts.dtype
    with pytest.raises(ValueError, match="keep must lie"):
        cut_strands(pts, np.array([1, 11]))
    with pytest.raises(ValueError, match="keep must be"):
        cut_strands(pts, np.array([5]))


def test_excess_is_zero_where_a_keyframe_cannot_tell():
    K, cfh, outside = _camera()
    # u = 15.5 + 100 x: x in [-0.2, 0.2] runs from column -4.5 to 35.5, past both edges of the image
    pts = torch.as_tensor(_strand_along_x(-0.2, 0.2, 41))
    ex = silhouette_excess(pts, K, cfh, outside)[0]
    u = 15.5 + 100 * pts[0, :, 0]
    inside_img = (u.round() >= 0) & (u.round() <= 31)
    assert (~inside_img).sum() > 4 and float(ex[~inside_img].abs().max()) == 0.0   # outside the image: no verdict
    assert torch.allclose(ex[inside_img], torch.clamp(u[inside_img].round() - 15, min=0))
    head_near = torch.full_like(outside, 0.5)                              # a head surface in front of the hair
    assert float(silhouette_excess(pts, K, cfh, outside, head_near).max()) == 0.0


def test_carve_cuts_strands_leaving_the_silhouette_but_keeps_bulges():
    ex = np.zeros((3, 10))
    ex[0, 6:] = 3.0                              # leaves at point 6 and stays out: cut to 6 points
    ex[1, 3:5] = 3.0                             # a bulge (2 of the last 7 points out): kept
    ex[2, 0:] = 0.5                              # within the tolerance: kept
    keep = carve_lengths(ex, tolerance=1.0, min_fraction=0.5)
    assert keep.tolist() == [6, 10, 10]
    assert carve_lengths(ex, 1.0, 0.0).tolist() == [6, 3, 10]              # min_fraction 0: cut at any exit
    out = np.zeros((1, 10)); out[0, :] = 5.0
    assert carve_lengths(out, 1.0).tolist() == [2]                         # the first segment always stays


def test_carve_strands_on_fit_data():
    from vid2haircut.fit.toy import toy_problem
    from vid2haircut.fit.outputs import dense_strands

    toy = toy_problem(size=40, n_frames=3, map_res=12, k=12)
    dense = dense_strands(toy.z_gt, toy.mask, toy.data.head, toy.codec, 300, 0, "proxy-v1")
    pts = dense.points
    # the truth's own strands stay (nearly) whole; the same strands stretched 3x leave the silhouettes
    kept = carve_strands(pts, toy.data, 1.0)
    roots = pts[:, :1]
    long = roots + 3.0 * (pts - roots)
    cut = carve_strands(long, toy.data, 1.0)
    assert kept.cut_fraction < 0.2 and cut.cut_fraction > kept.cut_fraction + 0.3
    assert np.array_equal(cut.points[:, 0], long[:, 0])                    # roots stay
    lens = lambda x: np.linalg.norm(np.diff(x, axis=1), axis=-1).sum(1)
    assert (lens(cut.points) <= lens(long) + 1e-6).all()
    with pytest.raises(ValueError, match="tolerance"):
        carve_strands(pts, toy.data, -1.0)


def test_outside_loss_counts_only_shown_points_beyond_the_silhouette():
    K, cfh, outside = _camera()
    # column u = 15.5 + 100 x (z = 1): x = 0.05 -> u = 20.5, 5 px beyond column 15
    pts = torch.tensor([[[[0.05, 0.0, 0.0], [-0.05, 0.0, 0.0]]]])            # (B=1,N=1,P=2,3)
    loss = outside_loss(pts, K, cfh, outside, None, tolerance=0.5)
    assert float(loss) == pytest.approx((5.5 - 0.5) / 2, abs=1e-4)          # the point on the mask pays 0
    # hidden behind a head surface nearer than the point: pays nothing; a surface behind it: pays
    near_head = torch.full_like(outside, 0.5)
    far_head = torch.full_like(outside, 2.0)
    assert float(outside_loss(pts, K, cfh, outside, near_head)) == 0.0
    assert float(outside_loss(pts, K, cfh, outside, far_head)) == pytest.approx(float(loss))
    # outside the image (u > W - 1) or behind the camera: nothing
    off = torch.tensor([[[[0.5, 0.0, 0.0], [0.0, 0.0, -1.5]]]])
    assert float(outside_loss(off, K, cfh, outside, None)) == 0.0


def test_outside_loss_gradient_points_towards_the_silhouette():
    K, cfh, outside = _camera()
    pts = torch.tensor([[[[0.052, 0.01, 0.0]]]], requires_grad=True)
    outside_loss(pts, K, cfh, outside, None).backward()
    g = pts.grad[0, 0, 0]
    assert float(g[0]) > 0 and abs(float(g[1])) < 1e-6           # descending moves the point left, onto the mask
    # finite differences of the bilinear field
    eps = 1e-4
    with torch.no_grad():
        f = (lambda dx: float(outside_loss(pts + torch.tensor([dx, 0.0, 0.0]), K, cfh, outside, None)))
        assert float(g[0]) == pytest.approx((f(eps) - f(-eps)) / (2 * eps), rel=1e-2)


def test_downsample_targets_outside_distance():
    h = w = 16
    mask = np.zeros((h, w), np.float32)
    mask[:, :8] = 1.0
    t = {"mask": mask, "angle": np.zeros((h, w), np.float32), "confidence": np.ones((h, w), np.float32),
         "depth": np.zeros((h, w), np.float32), "depth_valid": np.ones((h, w), bool)}
    lo = downsample_targets(t, 8, 8)
    out = lo["outside"]
    assert out.shape == (8, 8) and (out[:, :4] == 0).all()
    # full-resolution distances 1..8 of columns 8..15, averaged in pairs and halved: 0.75, 1.75, ...
    assert np.allclose(out[0, 4:], [0.75, 1.75, 2.75, 3.75], atol=0.05)
    t["mask"] = np.zeros((h, w), np.float32)                      # an empty mask constrains nothing
    assert (downsample_targets(t, 8, 8)["outside"] == 0).all()
