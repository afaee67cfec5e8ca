"""Tests of the strand-set type, resampling and tangents."""

import numpy as np
import pytest

from vid2haircut.polylines import (polyline_tangents, resample_polyline_list, resample_polylines, scatter_strands,
                                   vary_lengths)
from vid2haircut.strands import StrandSet


def _arcs(n_strands=3, p=40):
    """Half circles of radius 0.1, 0.2, ... m in the xy plane: (N,P,3), lengths pi*r."""
    th = np.linspace(0.0, np.pi, p)
    r = 0.1 * np.arange(1, n_strands + 1)
    pts = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], -1)[None] * r[:, None, None]
    return pts.astype(np.float32), np.pi * r


def test_resample_straight_line_is_exact_and_uniform():
    # a straight strand with non-uniform spacing: resampled points are exactly uniform
    x = np.array([0.0, 0.01, 0.05, 0.06, 0.1])
    pts = np.stack([x, 2 * x, np.zeros_like(x)], -1)[None]
    out = resample_polylines(pts, 11)
    expected = np.linspace(0, 0.1, 11)
    np.testing.assert_allclose(out[0, :, 0], expected, atol=1e-12)
    np.testing.assert_allclose(out[0, :, 1], 2 * expected, atol=1e-12)
    assert out.dtype == np.float64


def test_resample_preserves_length_and_endpoints():
    pts, true_len = _arcs(p=60)
    s = StrandSet(pts)
    up = s.resample(300)
    assert up.points.shape == (3, 300, 3)
    # chords of a fine resampling keep the (already chordal) length within 0.5 %
    np.testing.assert_allclose(up.lengths(), s.lengths(), rtol=5e-3)
    np.testing.assert_allclose(s.lengths(), true_len, rtol=5e-3)
    # root and tip are kept bit-exactly, also when downsampling
    for n in (2, 7, 300):
        r = s.resample(n)
        assert np.array_equal(r.roots, s.roots) and np.array_equal(r.tips, s.tips)
    # the resampled segment lengths are uniform
    seg = up.segment_lengths()
    assert np.ptp(seg, axis=1).max() < 1e-3 * seg.mean()


def test_resample_degenerate_and_repeated_points():
    pts = np.zeros((2, 5, 3))
    pts[1, :, 2] = [0.0, 0.0, 0.1, 0.1, 0.2]            # repeated points inside
    out = resample_polylines(pts, 5)
    assert np.array_equal(out[0], np.zeros((5, 3)))      # zero-length strand stays at its root
    np.testing.assert_allclose(out[1, :, 2], [0, 0.05, 0.1, 0.15, 0.2], atol=1e-12)
    with pytest.raises(ValueError):
        resample_polylines(pts, 1)
    with pytest.raises(ValueError):
        resample_polylines(np.zeros((2, 5)), 4)


def test_resample_polyline_list_groups_and_keeps_exact():
    a = np.random.default_rng(0).normal(size=(7, 3)).astype(np.float32)
    b = np.array([[0, 0, 0], [0, 0, 0.3]], np.float32)
    out = resample_polyline_list([a, b])
    assert out.shape == (2, 7, 3)
    assert np.array_equal(out[0], a)                     # already the common count: bit-exact
    np.testing.assert_allclose(out[1, :, 2], np.linspace(0, 0.3, 7), atol=1e-7)
    assert resample_polyline_list([a, b], n_points=4).shape == (2, 4, 3)


def test_tangents_unit_central_and_fallback():
    pts, _ = _arcs(p=50)
    t = polyline_tangents(pts)
    np.testing.assert_allclose(np.linalg.norm(t, axis=-1), 1.0, atol=1e-6)
    # on a circle the central-difference tangent is perpendicular to the radius (interior points)
    radial = pts / np.linalg.norm(pts, axis=-1, keepdims=True)
    assert np.abs((t * radial).sum(-1))[:, 1:-1].max() < 1e-5
    # the first tangent of a half circle starting at (r,0) points along +y
    np.testing.assert_allclose(t[:, 0], [[0, 1, 0]] * 3, atol=0.05)
    # repeated points take the neighbour's direction; an all-degenerate strand gives zeros
    rep = np.array([[[0, 0, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0]], [[1, 1, 1]] * 4], np.float32)
    tr = polyline_tangents(rep)
    np.testing.assert_allclose(tr[0], [[1, 0, 0]] * 4, atol=1e-7)
    assert np.array_equal(tr[1], np.zeros((4, 3)))


def test_strandset_validation_subset_transform():
    pts, _ = _arcs()
    color = np.eye(3, dtype=np.float32)
    s = StrandSet(pts, {"color": color}, head_model="proxy-v1")
    assert (s.n_strands, s.n_points, len(s)) == (3, 40, 3)
    sub = s.subset([2, 0])
    assert np.array_equal(sub.points, pts[[2, 0]]) and np.array_equal(sub.attributes["color"], color[[2, 0]])
    assert sub.head_model == "proxy-v1"
    assert s.subset(np.array([True, False, True])).n_strands == 2
    assert s.resample(10).attributes["color"] is color or np.array_equal(s.resample(10).attributes["color"], color)
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [0.0, 0.0, 0.5]
    moved = s.transform(T)
    np.testing.assert_allclose(moved.points[..., 0], -pts[..., 1], atol=1e-7)
    np.testing.assert_allclose(moved.points[..., 2], pts[..., 2] + 0.5, atol=1e-7)
    np.testing.assert_allclose(moved.lengths(), s.lengths(), rtol=1e-6)
    with pytest.raises(ValueError, match="leading dimension"):
        StrandSet(pts, {"color": np.zeros((2, 3))})
    with pytest.raises(ValueError, match="NaN"):
        StrandSet(np.full((1, 3, 3), np.nan))
    with pytest.raises(ValueError, match=r"\(N,P,3\)"):
        StrandSet(np.zeros((3, 3)))
    both = StrandSet.concatenate([s, s.subset([0])])
    assert both.n_strands == 4 and both.attributes["color"].shape == (4, 3)


def test_resample_vectorised_matches_per_strand():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(20, 13, 3)).cumsum(1)
    all_at_once = resample_polylines(pts, 17)
    one_by_one = np.concatenate([resample_polylines(pts[i:i + 1], 17) for i in range(20)])
    np.testing.assert_allclose(all_at_once, one_by_one, atol=1e-12)
    # every resampled point lies at the requested arc length along its polyline
    seg = np.linalg.norm(np.diff(all_at_once, axis=1), axis=-1)
    total = np.linalg.norm(np.diff(pts, axis=1), axis=-1).sum(1)
    assert np.all(seg.sum(1) <= total + 1e-9)


def test_vary_lengths_scales_each_strand_and_keeps_its_path():
    # 4000 straight strands along -y, 0.3 m: each new length is 0.3 * (1 + 0.04 g), the points
    # stay on the line (cut) or on its straight continuation (extended), uniform by arc length
    n, p = 4000, 30
    pts = np.zeros((n, p, 3), np.float32)
    pts[..., 1] = -np.linspace(0.0, 0.3, p)[None]
    pts[:, :, 0] = np.arange(n)[:, None] * 1e-3
    out = vary_lengths(pts, 0.04, seed=3)
    assert out.shape == pts.shape and out.dtype == np.float32
    np.testing.assert_array_equal(out[:, 0], pts[:, 0])
    np.testing.assert_allclose(out[..., 0], pts[..., 0], atol=1e-7)     # no sideways drift
    lengths = -out[:, -1, 1]
    rel = lengths / 0.3 - 1.0
    assert abs(rel.mean()) < 0.004 and 0.036 < rel.std() < 0.044
    assert np.abs(rel).max() <= 3 * 0.04 + 1e-6                        # draws clipped at 3 sigma
    assert (rel < -0.01).any() and (rel > 0.01).any()                  # cut and extended strands
    step = np.diff(out[..., 1], axis=1)
    np.testing.assert_allclose(step, np.broadcast_to((-lengths / (p - 1))[:, None], step.shape), atol=2e-6)
    # deterministic in the seed, another seed draws other lengths, 0 is the identity
    np.testing.assert_array_equal(vary_lengths(pts, 0.04, seed=3), out)
    assert not np.allclose(vary_lengths(pts, 0.04, seed=4), out)
    np.testing.assert_array_equal(vary_lengths(pts, 0.0), pts)


def test_vary_lengths_extends_a_curved_strand_along_its_tip():
    pts, true_len = _arcs(n_strands=1, p=200)
    many = np.repeat(pts, 500, 0)
    out = vary_lengths(many, 0.05, seed=0)
    lengths = np.linalg.norm(np.diff(out.astype(np.float64), axis=1), axis=-1).sum(1)
    longer = lengths > true_len[0] * 1.02
    assert longer.any()
    # the extension continues along the arc's tip direction (-y at the end of the half circle)
    tip = out[longer][:, -1]
    assert np.all(tip[:, 1] < -1e-3) and np.allclose(tip[:, 0], -0.1, atol=2e-3)
    # a cut strand ends on the circle
    shorter = lengths < true_len[0] * 0.98
    np.testing.assert_allclose(np.linalg.norm(out[shorter][:, -1, :2], axis=-1), 0.1, atol=1e-4)


@pytest.mark.parametrize("bad", [-0.1, 0.5, float("nan")])
def test_vary_lengths_rejects_a_bad_spread(bad):
    pts, _ = _arcs()
    with pytest.raises(ValueError, match="rel_std"):
        vary_lengths(pts, bad)


def test_scatter_strands_fans_tips_out_and_keeps_roots():
    n, p = 5000, 21
    pts = np.zeros((n, p, 3), np.float32)
    pts[..., 1] = -np.linspace(0.0, 0.2, p)[None]                     # straight, uniform: s/L = k/(p-1)
    out = scatter_strands(pts, 0.002, seed=1)
    assert out.shape == pts.shape and out.dtype == np.float32
    np.testing.assert_array_equal(out[:, 0], pts[:, 0])
    tip = (out[:, -1] - pts[:, -1]).astype(np.float64)
    assert np.all(np.abs(tip.std(axis=0) / 0.002 - 1.0) < 0.05) and np.all(np.abs(tip.mean(axis=0)) < 1e-4)
    # the displacement grows with the square root of the arc-length fraction, along one direction
    k = np.arange(p) / (p - 1)
    np.testing.assert_allclose(out - pts, np.sqrt(k)[None, :, None] * tip[:, None, :].astype(np.float32), atol=1e-7)
    np.testing.assert_array_equal(scatter_strands(pts, 0.002, seed=1), out)
    assert not np.allclose(scatter_strands(pts, 0.002, seed=2), out)
    np.testing.assert_array_equal(scatter_strands(pts, 0.0), pts)
    with pytest.raises(ValueError, match="tip_std"):
        scatter_strands(pts, -0.001)
