"""Hair map on the scalp UV: encoding, guide decoding, dense HAAR upsampling."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vid2haircut.head import get_head
from vid2haircut.prior.codec import StrandCodec
from vid2haircut.prior.hairmap import (HairMap, assign_texels, decode_dense, decode_guides, decode_texels,
                                       encode_strands)
from vid2haircut.prior.roundtrip import hairmap_roundtrip
from vid2haircut.prior.scalp import points_to_scalp_uv, scalp_grid
from vid2haircut.prior.upsample import blend_weight
from vid2haircut.strands import StrandSet

RES = 16


@pytest.fixture(scope="module")
def head():
    return get_head("proxy-v1")


def make_style(head, n: int, seed: int = 0, keep=None, side_sign: bool = False) -> StrandSet:
    """Strands on the real scalp: out along the normal, down, with a small wave; ``keep(uv)``
    restricts the roots; ``side_sign`` combs the left half to +x and the right half to -x."""
    rng = np.random.default_rng(seed)
    m = head.scalp_mask(256)
    uv = rng.random((n * 4, 2))
    ij = np.minimum((uv * 256).astype(int), 255)
    ok = m[ij[:, 1], ij[:, 0]]
    if keep is not None:
        ok &= keep(uv)
    uv = uv[ok][:n]
    roots, nrm = head.scalp_uv_to_root(uv)
    t = np.linspace(0.0, 1.0, 100)[None, :, None]
    side = np.where(uv[:, :1] < 0.5, 1.0, -1.0)[:, :, None] if side_sign else 0.0
    down = 0.05 if side_sign else 0.2
    pts = (roots[:, None] + 0.02 * t * nrm[:, None] + down * t * np.array([0.0, -1.0, 0.0])
           + 0.2 * side * t * np.array([1.0, 0.0, 0.0])
           + 0.008 * (np.sin(10 * t + 6 * uv[:, None, :1]) - np.sin(6 * uv[:, None, :1]))
           * np.array([1.0, 0.0, 0.2]))
    return StrandSet(pts.astype(np.float32), {"uv": uv.astype(np.float32)})


def fine_mask(mask: torch.Tensor, uv: torch.Tensor, up: int) -> torch.Tensor:
    """(M,) the x``up`` bilinearly upsampled mask at the fine texel holding each UV."""
    hi = mask.shape[0] * up
    m = torch.nn.functional.interpolate(mask[None, None], size=(hi, hi), mode="bilinear",
                                        align_corners=False)[0, 0]
    ij = (uv * hi).floor().long().clamp(0, hi - 1)
    return m[ij[:, 1], ij[:, 0]]


@pytest.fixture(scope="module")
def style(head) -> StrandSet:
    return make_style(head, 1500)


@pytest.fixture(scope="module")
def codec(style) -> StrandCodec:
    return StrandCodec.fit(style.points, k=297)


def test_scalp_grid_cached_and_on_surface(head) -> None:
    g = scalp_grid(head, RES)
    assert scalp_grid(head, RES) is g
    assert g.valid.shape == (RES, RES) and g.index.size == g.valid.sum() > 0
    np.testing.assert_allclose(points_to_scalp_uv(g.roots[g.valid]), g.uv[g.valid], atol=1e-4)


def test_encode_shapes_and_mask(head, style, codec) -> None:
    hm = encode_strands(style, head, codec, res=RES)
    assert hm.z.shape == (codec.k, RES, RES) and hm.mask.shape == (RES, RES)
    valid = torch.as_tensor(head.scalp_mask(RES))
    assert bool((hm.mask[~valid] == 0).all()) and bool((hm.z[:, ~valid] == 0).all())
    assert float(hm.mask[valid].mean()) > 0.95                           # dense roots: all hair
    # roots only in the front half: texels far behind are bald
    front = make_style(head, 800, keep=lambda uv: uv[:, 1] > 0.5)
    hf = encode_strands(front, head, codec, res=RES)
    v = (torch.arange(RES) + 0.5) / RES
    back = valid & (v[:, None] < 0.5 - 2.0 / RES)
    assert bool(back.any()) and bool((hf.mask[back] == 0).all())
    assert float(hf.mask[valid & (v[:, None] > 0.6)].mean()) > 0.9
    # without the "uv" attribute the UV comes from the roots: same assignment
    a1 = assign_texels(front, head, RES)
    a2 = assign_texels(StrandSet(front.points), head, RES)
    assert (a1.hair == a2.hair).all()
    assert (a1.strand_index[a1.hair] == a2.strand_index[a1.hair]).all()


def test_guides_on_scalp_and_roundtrip(head, style, codec) -> None:
    hm = encode_strands(style, head, codec, res=RES)
    g = decode_guides(hm, head, codec)
    n = int(((hm.mask >= 0.5) & torch.as_tensor(head.scalp_mask(RES))).sum())
    assert g.points.shape == (n, 100, 3) and g.texel_index.shape == (n,)
    assert np.abs(head.sdf_np(g.points[:, 0].numpy())).max() < 1e-3
    assert head.scalp_mask(RES).ravel()[g.texel_index.numpy()].all()
    rt = hairmap_roundtrip(style, head, codec, res=RES)
    assert rt.n_guides == n
    assert rt.shape_error < 1e-5                                          # full-rank codec
    spacing = 4.19 / RES * 0.1                                            # ~ texel spacing in metres
    assert rt.root_error < spacing and rt.point_error < spacing
    assert g.to_strand_set().n_strands == n


def test_decode_texels_batched(head, style, codec) -> None:
    hm = encode_strands(style, head, codec, res=RES)
    z = torch.stack([hm.z, torch.zeros_like(hm.z)])
    pts = decode_texels(z, head, codec)
    nv = int(head.scalp_mask(RES).sum())
    assert pts.shape == (2, nv, 100, 3)
    g = decode_guides(HairMap(hm.z, torch.ones(RES, RES)), head, codec)
    torch.testing.assert_close(pts[0], g.points)


def test_blend_weight_values() -> None:
    s = torch.tensor([-1.0, 0.0, 0.5, 0.9, 0.95, 1.0])
    w = blend_weight(s)
    expect = [1.0, 1.0, 1.0 - 1.63 * 0.5 ** 5, 1.0 - 1.63 * 0.9 ** 5, 0.4 - 0.4 * 0.95, 0.0]
    torch.testing.assert_close(w, torch.tensor(expect))


def test_dense_shapes_blend_and_gradients(head, style, codec) -> None:
    hm = encode_strands(style, head, codec, res=RES)
    z = hm.z.clone().requires_grad_(True)
    d = decode_dense(HairMap(z, hm.mask), head, codec, n_strands=700, seed=3)
    assert d.points.shape == (700, 100, 3) and d.uv.shape == (700, 2)
    assert np.abs(head.sdf_np(d.points[:, 0].detach().numpy())).max() < 1e-3
    smp = d.samples
    torch.testing.assert_close(smp.weight, blend_weight(smp.similarity))
    w = smp.weight[:, None]
    blended = w * smp.z_nearest + (1 - w) * smp.z_bilinear
    torch.testing.assert_close(d.points, codec.decode(blended, d.points[:, 0]), atol=1e-6, rtol=0)
    assert bool((fine_mask(hm.mask, d.uv, 4) >= 0.99).all())              # hard mask threshold
    d.points[:, -1].sum().backward()
    assert z.grad is not None and float(z.grad.abs().sum()) > 0
    again = decode_dense(hm, head, codec, n_strands=700, seed=3)
    assert torch.equal(again.points, d.points.detach())
    other = decode_dense(hm, head, codec, n_strands=700, seed=4)
    assert not torch.equal(other.uv, d.uv)


def test_dense_keeps_partings_and_smooths_flows(head) -> None:
    """Opposite combing on both halves: at the parting the nearest guide wins (w=1); inside a
    uniform half the guides are similar and bilinear interpolation dominates (w small)."""
    style = make_style(head, 1500, side_sign=True)
    codec = StrandCodec.fit(style.points, k=64)
    hm = encode_strands(style, head, codec, res=RES)
    d = decode_dense(hm, head, codec, n_strands=2000, seed=0)
    u = d.uv[:, 0]
    near_part = (u - 0.5).abs() < 0.5 / RES
    inside = (u - 0.5).abs() > 2.5 / RES
    assert bool(near_part.any()) and bool(inside.any())
    assert float(d.samples.weight[near_part].min()) > 0.95
    assert float(d.samples.weight[inside].mean()) < 0.1
    # strands at the parting keep their side's direction (no averaged, collapsed strands)
    dx = d.points[:, -1, 0] - d.points[:, 0, 0]
    assert float(dx[near_part].abs().min()) > 0.05


def test_dense_mask_thresholds(head, style, codec) -> None:
    hm = encode_strands(style, head, codec, res=RES)
    bald = decode_dense(HairMap(hm.z, torch.zeros(RES, RES)), head, codec, n_strands=100)
    assert bald.points.shape == (0, 100, 3)
    soft = HairMap(hm.z, hm.mask * 0.8)                                    # soft: threshold 0.5
    ds = decode_dense(soft, head, codec, n_strands=300)
    assert ds.points.shape[0] == 300 and bool((fine_mask(soft.mask, ds.uv, 4) >= 0.5).all())
    assert decode_dense(soft, head, codec, n_strands=300, mask_threshold=0.99).points.shape[0] == 0


def test_hairmap_validation() -> None:
    with pytest.raises(ValueError, match="H == W"):
        HairMap(torch.zeros(4, 8, 16), torch.zeros(8, 16))
    with pytest.raises(ValueError, match="does not match"):
        HairMap(torch.zeros(4, 8, 8), torch.zeros(4, 4))


def test_generated_corpus_and_roundtrip(head, tmp_path) -> None:
    """A tiny generated corpus: cached to disk unchanged, codec fitted on it, hair-map round trip."""
    from vid2haircut.prior.corpus import CorpusConfig, build_corpus, fit_codec, load_corpus, save_corpus

    corpus = build_corpus(["wavy"], [0], 400, head=head)
    assert corpus.points.shape == (400, 100, 3) and corpus.styles == (("wavy", 0),)
    save_corpus(tmp_path / "c.npz", corpus)
    back = load_corpus(tmp_path / "c.npz")
    assert back.styles == corpus.styles and np.array_equal(back.points, corpus.points)
    codec = fit_codec(corpus, k=64)
    assert codec.meta["corpus_styles"] == [["wavy", 0]]
    rt = hairmap_roundtrip(corpus.strand_set(0), head, codec, res=RES)
    assert rt.n_guides > 0.9 * head.scalp_mask(RES).sum()
    assert rt.shape_error < 1.5e-3                                         # codec part, K=64, seen data
    assert rt.root_error < 4.19 / RES * 0.1                                # under one texel spacing
    with pytest.raises(ValueError, match="overlap"):
        CorpusConfig(train_seeds=(0, 1), test_seeds=(1, 2))
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        load_corpus(tmp_path / "nope.npz")
