"""Strand codec: orthonormal Fourier features, whitened PCA, exactness, gradients, persistence."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vid2haircut.prior.codec import StrandCodec, component_mask, features_to_offsets, strand_features


def synthetic_strands(n: int, p: int = 100, seed: int = 0) -> np.ndarray:
    """(n,p,3) float32 smooth wavy strands hanging from roots on a 9 cm sphere."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d[:, 1] = np.abs(d[:, 1])
    roots = 0.09 * d / np.linalg.norm(d, axis=1, keepdims=True)
    t = np.linspace(0.0, 1.0, p)[None, :, None]
    length = rng.uniform(0.1, 0.4, (n, 1, 1))
    amp = rng.uniform(0.0, 0.02, (n, 1, 1))
    freq = rng.uniform(2.0, 6.0, (n, 1, 1))
    phase = rng.uniform(0.0, 2 * np.pi, (n, 1, 1))
    out_dir = roots[:, None, :] / 0.09
    down = np.array([0.0, -1.0, 0.0])
    pts = (roots[:, None, :] + 0.03 * t * out_dir + length * t * down
           + amp * np.sin(2 * np.pi * freq * t + phase) * np.array([1.0, 0.0, 0.3]))
    return pts.astype(np.float32)


@pytest.fixture(scope="module")
def strands() -> np.ndarray:
    return synthetic_strands(600)


@pytest.mark.parametrize("p", [100, 10, 11])
def test_features_are_orthonormal_and_invertible(p: int) -> None:
    x = torch.as_tensor(synthetic_strands(20, p, seed=1), dtype=torch.float64)
    f = strand_features(x)
    assert f.shape == (20, 3 * (p - 1))
    off = x[:, 1:] - x[:, :1]
    torch.testing.assert_close(f.norm(dim=-1), off.flatten(1).norm(dim=-1))        # Parseval
    torch.testing.assert_close(features_to_offsets(f, p), off)


def test_exact_at_full_rank(strands: np.ndarray) -> None:
    codec = StrandCodec.fit(strands, k=297)
    assert codec.k == codec.full_rank == 297
    x = torch.as_tensor(synthetic_strands(50, seed=7))                  # unseen strands
    y = codec.decode(codec.encode(x), x[:, 0])
    assert y.shape == x.shape
    assert float((y - x).norm(dim=-1).max()) < 1e-5
    assert torch.equal(y[:, 0], x[:, 0])


def test_whitened_coefficients_and_truncation(strands: np.ndarray) -> None:
    codec = StrandCodec.fit(strands, k=16)
    c = codec.encode(torch.as_tensor(strands))
    assert c.shape == (600, 16)
    torch.testing.assert_close(c.mean(0), torch.zeros(16), atol=1e-3, rtol=0)
    torch.testing.assert_close(c.std(0), torch.ones(16), atol=1e-3, rtol=0)
    assert bool((codec.scales[:-1] >= codec.scales[1:]).all())           # by decreasing variance
    errs = []
    for k in (2, 8, 16):
        ck = codec.truncate(k)
        x = torch.as_tensor(strands)
        errs.append(float((ck.decode(ck.encode(x), x[:, 0]) - x).norm(dim=-1).mean()))
    assert errs[0] > errs[1] > errs[2]
    # decoding the first k coefficients of a K-code equals the truncated codec
    x = torch.as_tensor(strands[:5])
    torch.testing.assert_close(codec.decode(codec.encode(x)[:, :8], x[:, 0]),
                               codec.truncate(8).decode(codec.truncate(8).encode(x), x[:, 0]))


def test_zero_coefficients_give_mean_offsets(strands: np.ndarray) -> None:
    codec = StrandCodec.fit(strands, k=8)
    roots = torch.tensor([[0.0, 0.1, 0.0], [0.05, 0.0, 0.02]])
    y = codec.decode(torch.zeros(2, 8), roots)
    mean_off = torch.as_tensor(strands[:, 1:] - strands[:, :1], dtype=torch.float64).mean(0).float()
    torch.testing.assert_close(y[:, 1:] - y[:, :1], mean_off.expand(2, -1, -1), atol=1e-6, rtol=0)
    torch.testing.assert_close(y[:, 0], roots)


def test_batched_broadcast_and_mask(strands: np.ndarray) -> None:
    codec = StrandCodec.fit(strands, k=12)
    x = torch.as_tensor(strands[:24]).reshape(2, 3, 4, 100, 3)
    c = codec.encode(x)
    assert c.shape == (2, 3, 4, 12)
    y = codec.decode(c, x[..., 0, :])
    assert y.shape == x.shape
    # one root broadcast to many codes
    assert codec.decode(c, torch.zeros(3)).shape == x.shape
    m = component_mask(5, 12)
    assert m.tolist() == [1.0] * 5 + [0.0] * 7
    with pytest.raises(ValueError):
        component_mask(13, 12)


def test_differentiable(strands: np.ndarray) -> None:
    codec = StrandCodec.fit(strands, k=6).to(dtype=torch.float64)
    roots = torch.tensor([[0.0, 0.09, 0.0]], dtype=torch.float64)
    c = torch.randn(1, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(0), requires_grad=True)
    assert torch.autograd.gradcheck(lambda q: codec.decode(q, roots)[..., ::9, :], (c,))
    small = StrandCodec.fit(synthetic_strands(200, p=12), k=5).to(dtype=torch.float64)
    x = torch.as_tensor(synthetic_strands(2, p=12, seed=3), dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: small.encode(p), (x,))
    # the gradient of a point loss reaches every coefficient
    c2 = torch.zeros(4, 6, requires_grad=True)
    codec32 = codec.to(dtype=torch.float32)
    codec32.decode(c2, torch.zeros(4, 3))[:, -1, 1].sum().backward()
    assert c2.grad is not None and bool((c2.grad.abs().sum(0) > 0).any())


def test_save_load_roundtrip(tmp_path, strands: np.ndarray) -> None:
    codec = StrandCodec.fit(strands, k=10, meta={"note": "test"})
    path = tmp_path / "codec.npz"
    codec.save(path)
    back = StrandCodec.load(path)
    assert back.k == 10 and back.n_points == 100
    assert back.fingerprint() == codec.fingerprint()
    assert back.meta["note"] == "test"
    torch.testing.assert_close(back.basis, codec.basis, rtol=0, atol=0)
    assert not list(tmp_path.glob(".codec.npz*"))                       # no temporary left


def test_bad_inputs(tmp_path, strands: np.ndarray) -> None:
    codec = StrandCodec.fit(strands, k=4)
    with pytest.raises(ValueError, match="resample"):
        codec.encode(torch.zeros(3, 50, 3))
    with pytest.raises(ValueError, match="k must be"):
        StrandCodec.fit(strands, k=298)
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        StrandCodec.load(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="bad.npz"):
        StrandCodec.load(bad)
    path = tmp_path / "c.npz"
    codec.save(path)
    data = dict(np.load(path))
    data["mean"] = data["mean"] + 1.0
    np.savez(path, **data)
    with pytest.raises(ValueError, match="fingerprint"):
        StrandCodec.load(path)


def test_fit_is_deterministic(strands: np.ndarray) -> None:
    a = StrandCodec.fit(strands, k=8)
    b = StrandCodec.fit(strands.copy(), k=8)
    assert a.fingerprint() == b.fingerprint()
