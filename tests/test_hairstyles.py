"""Tests of the procedural hairstyle generator (vid2haircut.synth.hairstyles and its helpers)."""

import numpy as np
import pytest

from vid2haircut.head import get_head
from vid2haircut.synth.hair_fields import sample_roots
from vid2haircut.synth.hair_grow import sample_prefix
from vid2haircut.synth.hair_sdf import HeadSDF
from vid2haircut.synth.hairstyles import FAMILIES, generate_hairstyle, hairstyle_params

N = 1000  # strands per style in these tests


@pytest.fixture(scope="module")
def head():
    return get_head("proxy-v1")


@pytest.fixture(scope="module")
def styles(head):
    """One style per family (seed 0), generated once for the whole module."""
    return {f: generate_hairstyle(f, 0, head=head, n_strands=N, n_points=100) for f in FAMILIES}


def _curvature(points):
    """Median over strands of total turning angle per metre of arc length."""
    d = np.diff(points.astype(np.float64), axis=1)
    seg = np.linalg.norm(d, axis=-1)
    u = d / np.maximum(seg[..., None], 1e-12)
    ang = np.arccos(np.clip((u[:, 1:] * u[:, :-1]).sum(-1), -1.0, 1.0))
    return float(np.median(ang.sum(1) / seg.sum(1)))


def test_families_listed():
    required = {"buzz", "short_straight", "bob", "shoulder_straight", "long_straight", "wavy",
                "curly", "side_parted", "bangs"}
    assert required <= set(FAMILIES)


def test_unknown_family_raises_listing_families(head):
    with pytest.raises(ValueError) as err:
        generate_hairstyle("mohawk_xl", 0, head=head, n_strands=10)
    msg = str(err.value)
    assert "mohawk_xl" in msg
    for f in FAMILIES:
        assert f in msg
    with pytest.raises(ValueError):
        hairstyle_params("nope", 0)
    with pytest.raises(ValueError):
        generate_hairstyle("bob", 0, head=head, n_strands=0)


@pytest.mark.parametrize("family", FAMILIES)
def test_style_shapes_and_attributes(styles, family):
    s = styles[family]
    assert s.points.shape == (N, 100, 3) and s.points.dtype == np.float32
    assert np.isfinite(s.points).all()
    col, uv = s.attributes["color"], s.attributes["uv"]
    assert col.shape == (N, 3) and col.dtype == np.float32
    assert (col >= 0).all() and (col <= 1).all()
    assert uv.shape == (N, 2) and uv.dtype == np.float32
    assert s.head_model == "proxy-v1"


@pytest.mark.parametrize("family", FAMILIES)
def test_no_point_inside_head(styles, head, family):
    s = styles[family]
    d = head.sdf_np(s.points.reshape(-1, 3))
    assert d.min() >= -1e-4, f"{family}: deepest point {d.min():.2e} m inside the head"


@pytest.mark.parametrize("family", FAMILIES)
def test_roots_on_scalp_at_their_uv(styles, head, family):
    s = styles[family]
    uv = s.attributes["uv"]
    assert np.abs(head.sdf_np(s.roots)).max() <= 1e-3
    ref, _ = head.scalp_uv_to_root(uv)
    assert np.linalg.norm(s.roots - ref, axis=-1).max() <= 1e-3
    res = 256
    mask = head.scalp_mask(res)
    col = np.clip((uv[:, 0] * res).astype(int), 0, res - 1)
    row = np.clip((uv[:, 1] * res).astype(int), 0, res - 1)
    assert mask[row, col].mean() > 0.99
    # roots cover the scalp: all four quadrants around the crown are used
    q = (uv[:, 0] > 0.5).astype(int) * 2 + (uv[:, 1] > 0.5)
    assert np.bincount(q, minlength=4).min() > N // 10


@pytest.mark.parametrize("family", FAMILIES)
def test_face_stays_clear(styles, head, family):
    # no hair point in a box in front of the eyes / face, below the eyebrows
    lm = head.landmarks
    p = styles[family].points
    x_eye = np.abs(lm[36:48, 0]).max()
    box = ((np.abs(p[..., 0]) < x_eye) & (p[..., 1] < lm[17:27, 1].mean() - 0.01)
           & (p[..., 1] > lm[8, 1]) & (p[..., 2] > lm[36:48, 2].min() - 0.02))
    assert box.sum() == 0, f"{family}: {box.sum()} points in front of the face"


@pytest.mark.parametrize("family", FAMILIES)
def test_segments_roughly_uniform(styles, family):
    seg = styles[family].segment_lengths()
    ratio = seg.max(1) / np.maximum(np.median(seg, 1), 1e-12)
    assert np.percentile(ratio, 99) < 1.5
    assert ratio.max() < 4.0


def test_deterministic_and_seed_dependent(head):
    a = generate_hairstyle("wavy", 7, head=head, n_strands=300)
    b = generate_hairstyle("wavy", 7, head=head, n_strands=300)
    c = generate_hairstyle("wavy", 8, head=head, n_strands=300)
    np.testing.assert_array_equal(a.points, b.points)
    for key in ("color", "uv"):
        np.testing.assert_array_equal(a.attributes[key], b.attributes[key])
    assert not np.array_equal(a.points, c.points)
    assert not np.array_equal(a.attributes["uv"], c.attributes["uv"])
    assert hairstyle_params("wavy", 7) == hairstyle_params("wavy", 7)
    assert hairstyle_params("wavy", 7) != hairstyle_params("wavy", 8)


def test_lengths_ordered(styles):
    mean = {f: float(s.lengths().mean()) for f, s in styles.items()}
    assert mean["buzz"] < 0.015
    assert mean["buzz"] < mean["short_straight"] < mean["bob"] < mean["shoulder_straight"] \
        < mean["long_straight"]
    # long hair really hangs below the head, a bob ends around the jaw
    assert np.median(styles["long_straight"].tips[:, 1]) < -0.3
    assert -0.15 < np.median(styles["bob"].tips[:, 1]) < -0.03


def test_curls_and_waves_are_curved(styles):
    straight = max(_curvature(styles[f].points) for f in ("long_straight", "shoulder_straight"))
    assert _curvature(styles["wavy"].points) > 2.0 * straight
    assert _curvature(styles["curly"].points) > 2.0 * _curvature(styles["wavy"].points)


def test_bangs_cover_forehead_and_stop_above_eyes(styles, head):
    lm = head.landmarks
    y_brow, y_eye = lm[17:27, 1].mean(), lm[36:48, 1].mean()

    def forehead_points(p):
        return ((np.abs(p[..., 0]) < 0.035) & (p[..., 1] > y_brow) & (p[..., 1] < y_brow + 0.03)
                & (p[..., 2] > lm[36:48, 2].min() - 0.02)).sum()

    assert forehead_points(styles["bangs"].points) > 5 * forehead_points(styles["long_straight"].points) + 50
    front = np.abs(styles["bangs"].points[..., 0]) < 0.03
    front &= styles["bangs"].points[..., 2] > lm[36:48, 2].min() - 0.02
    assert (styles["bangs"].points[..., 1][front] > y_eye).all()


def test_side_parting_sweeps_away_from_the_part(head):
    for seed in range(3):
        part_x = hairstyle_params("side_parted", seed).part_x
        s = generate_hairstyle("side_parted", seed, head=head, n_strands=600)
        r = s.roots
        sel = (np.abs(r[:, 0]) < 0.015) & (r[:, 2] > 0.02)      # front-centre roots
        assert sel.sum() > 5
        assert np.sign(s.tips[sel, 0].mean()) == -np.sign(part_x)


def test_styles_vary_with_seed():
    cuts = {round(hairstyle_params("bob", k).cut_side, 4) for k in range(6)}
    assert len(cuts) == 6
    sides = {np.sign(hairstyle_params("side_parted", k).part_x) for k in range(12)}
    assert sides == {-1.0, 1.0}


def test_base_colour_varies_with_seed(head):
    means = [generate_hairstyle("bob", k, head=head, n_strands=50).attributes["color"].mean(0)
             for k in range(8)]
    names = {tuple(np.round(m / m.max(), 1)) for m in means}
    assert len(names) >= 2


def test_head_sdf_matches_head_and_gradient(head):
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.13, 0.13, (3000, 3))
    sdf = HeadSDF(head)
    d, g = sdf.value_and_grad(x)
    np.testing.assert_allclose(d, head.sdf_np(x), atol=1e-6)
    eps = 1e-4
    fd = np.stack([(sdf(x + eps * e) - sdf(x - eps * e)) / (2 * eps) for e in np.eye(3)], -1)
    fd /= np.linalg.norm(fd, axis=-1, keepdims=True)
    assert np.median(np.abs(fd - g)) < 5e-3
    idx, dn = sdf.near(x, 0.01)
    np.testing.assert_array_equal(idx, np.nonzero(d < 0.01)[0])


def test_roots_evenly_spread_on_the_surface(head):
    from scipy.spatial import cKDTree

    r = sample_roots(head, 2000, np.random.default_rng(0))
    d = cKDTree(r.points).query(r.points, k=2)[0][:, 1]
    assert d.std() / d.mean() < 0.45                  # more even than uniform random (~0.52)
    bands = [d[(r.theta >= lo) & (r.theta < hi)].mean() for lo, hi in ((0, 0.6), (0.6, 1.2), (1.2, 2.1))]
    assert max(bands) / min(bands) < 1.25             # same density near the crown and the hairline


def test_sample_prefix_on_straight_polyline():
    x = np.array([0.0, 0.01, 0.05, 0.06, 0.1])
    poly = np.stack([x, np.zeros_like(x), np.zeros_like(x)], -1)[None].repeat(2, 0)
    out = sample_prefix(poly, np.array([0.1, 0.04]), 5)
    np.testing.assert_allclose(out[0, :, 0], np.linspace(0, 0.1, 5), atol=1e-12)
    np.testing.assert_allclose(out[1, :, 0], np.linspace(0, 0.04, 5), atol=1e-12)
