"""Tests of the built-in proxy head: mesh, landmarks, scalp UV, SDF, export."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh

from vid2haircut.head import HeadModel, SDFGrid, get_head
from vid2haircut.head.meshdist import closest_point_on_triangles, winding_number
from vid2haircut.head.scalp import dirs_to_uv, uv_to_dirs


@pytest.fixture(scope="module")
def head() -> HeadModel:
    return get_head("proxy-v1")


def _brute_sdf(v: np.ndarray, f: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Reference signed distance: exact distance to every triangle, winding-number sign."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    d = np.array([np.linalg.norm(closest_point_on_triangles(np.broadcast_to(p, a.shape), a, b, c)[0]
                                 - p, axis=1).min() for p in pts])
    return np.where(winding_number(v, f, pts) > 0.5, -d, d)


def test_closest_point_on_triangle_regions():
    a, b, c = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])
    cases = {(0.2, 0.2, 0.5): ((0.2, 0.2, 0.0), 0), (-1, -1, 0): ((0, 0, 0), 1),
             (2, -0.5, 0): ((1, 0, 0), 2), (-0.5, 2, 1): ((0, 1, 0), 3),
             (0.5, -1, 0): ((0.5, 0, 0), 4), (1, 1, 0): ((0.5, 0.5, 0), 5), (-1, 0.5, 0): ((0, 0.5, 0), 6)}
    for p, (q_ref, feat_ref) in cases.items():
        q, feat = closest_point_on_triangles(np.array([p], float), a, b, c)
        np.testing.assert_allclose(q[0], q_ref, atol=1e-12)
        assert feat[0] == feat_ref


def test_mesh_watertight_and_sized(head):
    assert head.name == "proxy-v1"
    assert head.vertices.dtype == np.float32 and head.faces.dtype == np.int64
    assert 5000 <= len(head.vertices) <= 12000
    mesh = trimesh.Trimesh(head.vertices, head.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0.003  # outward winding gives positive volume (m^3)
    v = head.vertices
    cranium = v[np.abs(v[:, 1] - 0.03) < 0.005]        # a slice above the ears
    width = cranium[:, 0].max() - cranium[:, 0].min()
    assert 0.14 < width < 0.18
    height = v[:, 1].max() - v[:, 1].min()
    assert 0.21 < height < 0.27
    # face towards +z: the nose tip (landmark 30) is the most frontal landmark
    assert np.argmax(head.landmarks[:, 2]) == 30
    assert head.vertices[:, 2].max() == pytest.approx(head.landmarks[30, 2], abs=0.005)


def test_shape_parameters_and_cache():
    assert get_head("proxy-v1") is get_head("proxy-v1", scale=1.0)
    big = get_head("proxy-v1", scale=1.1, width=1.05)
    base = get_head("proxy-v1")
    ratio = np.ptp(big.vertices, axis=0) / np.ptp(base.vertices, axis=0)
    np.testing.assert_allclose(ratio, [1.155, 1.1, 1.1], rtol=1e-3)
    assert np.abs(big.sdf_np(big.landmarks)).max() < 1e-3
    tall = get_head("proxy-v1", crown=1.15)
    assert tall.vertices[:, 1].max() > base.vertices[:, 1].max() + 0.01
    with pytest.raises(ValueError, match="unknown head"):
        get_head("nope")
    with pytest.raises(ValueError, match="scale"):
        get_head("proxy-v1", scale=-1.0)


def test_landmarks_on_surface_and_plausible(head):
    lm = head.landmarks
    assert lm.shape == (68, 3) and lm.dtype == np.float32
    assert np.abs(head.sdf_np(lm)).max() < 1e-3
    # jaw from the subject's right (-x) to the left (+x), chin lowest
    assert lm[0, 0] < -0.05 and lm[16, 0] > 0.05 and np.argmin(lm[:17, 1]) == 8
    np.testing.assert_allclose(lm[0] * [-1, 1, 1], lm[16], atol=1e-3)   # mirror symmetric
    # eyes above the nose tip above the mouth above the chin; eyes 5-8 cm apart
    eye_r, eye_l = lm[36:42].mean(0), lm[42:48].mean(0)
    assert 0.05 < eye_l[0] - eye_r[0] < 0.08
    assert eye_r[1] > lm[30, 1] > lm[48:60, 1].mean() > lm[8, 1]
    # not coplanar: the jaw ends lie well behind the nose tip
    assert lm[30, 2] - lm[[0, 16], 2].mean() > 0.05
    sv = np.linalg.svd(lm - lm.mean(0), compute_uv=False)
    assert sv[2] / sv[0] > 0.15


def test_scalp_uv_roots_on_surface(head):
    rng = np.random.default_rng(0)
    uv = rng.uniform(0.1, 0.9, size=(200, 2))
    pts, nrm = head.scalp_uv_to_root(uv)
    assert pts.shape == (200, 3) and nrm.shape == (200, 3) and pts.dtype == np.float32
    assert np.abs(head.sdf_np(pts)).max() < 1e-3
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-5)
    assert np.all((nrm * pts).sum(1) > 0)                       # outward
    # normals agree with the SDF gradient (finite differences) on the smooth cranium
    top = uv[np.linalg.norm(uv - 0.5, axis=1) < 0.3]
    p, n = head.scalp_uv_to_root(top)
    g = np.stack([(head.sdf_np(p + e) - head.sdf_np(p - e)) for e in np.eye(3) * 1e-3], axis=1)
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    assert np.mean((g * n).sum(1)) > 0.98
    # uv <-> direction round trip and conventions: crown, face side, +x side
    np.testing.assert_allclose(dirs_to_uv(uv_to_dirs(uv)), uv, atol=1e-9)
    crown, _ = head.scalp_uv_to_root(np.array([0.5, 0.5]))
    assert crown[1] == pytest.approx(head.vertices[:, 1].max(), abs=2e-3)
    front, _ = head.scalp_uv_to_root(np.array([0.5, 0.9]))
    left, _ = head.scalp_uv_to_root(np.array([0.9, 0.5]))
    assert front[2] > 0.05 and left[0] > 0.05


def test_scalp_mask(head):
    m = head.scalp_mask(64)
    assert m.shape == (64, 64) and m.dtype == bool
    assert m[32, 32]                        # crown
    assert not m[63, 32]                    # face (v -> 1 is towards +z, far below the hairline)
    assert not m[0, 0] and not m[63, 63]    # outside the UV disk
    assert m[2, 32]                         # back of the head (nape side is hair-bearing)
    frac = m.mean()
    assert 0.35 < frac < 0.7
    # forehead: the hairline passes between the crown and the face
    col = m[32:, 32]
    first_false = int(np.argmin(col))
    assert 8 < first_false < 26


def test_sdf_sign_and_accuracy(head):
    assert isinstance(head.sdf_grid, SDFGrid)
    vals = head.sdf_grid.values
    assert vals.ndim == 3 and len(set(vals.shape)) == 1 and vals.dtype == np.float32
    assert head.sdf_np(np.zeros(3)) < -0.05
    far = head.sdf_np(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -0.5]]))
    assert far[0] > 0.8 and far[1] > 0.3
    rng = np.random.default_rng(1)
    v = head.vertices.astype(np.float64)
    pts = v[rng.choice(len(v), 200)] + rng.normal(0.0, 0.01, size=(200, 3))
    ref = _brute_sdf(v, head.faces, pts)
    err = np.abs(head.sdf_np(pts) - ref)
    near = np.abs(ref) < 0.005
    assert near.sum() > 60
    assert err[near].max() < 1e-3 and err.max() < 2e-3 and err.mean() < 2e-4
    assert np.all(np.sign(head.sdf_np(pts[np.abs(ref) > 1e-3])) == np.sign(ref[np.abs(ref) > 1e-3]))


def test_sdf_torch_gradient(head):
    rng = np.random.default_rng(2)
    v = head.vertices.astype(np.float64)
    pts = v[rng.choice(len(v), 50)] + rng.normal(0.0, 0.02, size=(50, 3))
    pts = np.concatenate([pts, [[0.5, 0.1, 0.2]]])             # one outside the grid
    p = torch.tensor(pts, dtype=torch.float64, requires_grad=True)
    d = head.sdf(p)
    assert d.dtype == torch.float64 and d.shape == (51,)
    np.testing.assert_allclose(d.detach().numpy(), head.sdf_np(pts), atol=1e-6)
    d.sum().backward()
    g = p.grad.numpy()
    h = 1e-8  # trilinear is piecewise: a tiny step rarely crosses a cell face
    fd = np.stack([(head.sdf(torch.tensor(pts + e)) - head.sdf(torch.tensor(pts - e))).numpy() / (2 * h)
                   for e in np.eye(3) * h], axis=1)
    np.testing.assert_allclose(g, fd, atol=1e-4)
    assert np.all(np.linalg.norm(g, axis=1) > 0.5)
    # float32 input and batch shapes are kept
    out = head.sdf(torch.zeros(2, 4, 3))
    assert out.shape == (2, 4) and out.dtype == torch.float32


def test_export_and_cli(tmp_path, head):
    import argparse

    from vid2haircut.cli import head as head_cli
    from vid2haircut.head import export_head

    files = export_head(head, tmp_path / "a")
    mesh = trimesh.load(files.mesh, process=False)
    np.testing.assert_allclose(mesh.vertices, head.vertices, atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, head.faces)
    info = json.loads(files.landmarks.read_text())
    np.testing.assert_allclose(info["landmarks"], head.landmarks, atol=1e-6)
    assert info["groups"]["jaw"] == list(range(17)) and info["name"] == "proxy-v1"
    with np.load(files.scalp) as z:
        assert z["uv"].shape == (64, 64, 2) and z["roots"].shape == (64, 64, 3)
        np.testing.assert_array_equal(z["mask"], head.scalp_mask(64))
        np.testing.assert_allclose(z["roots"][32, 32], head.scalp_uv_to_root(z["uv"][32, 32])[0])
        assert np.all((z["normals"] * z["roots"]).sum(-1)[z["mask"]] > 0)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["head.obj", "landmarks.json", "scalp_uv.npz"]
    # the CLI writes the same bytes (deterministic) for the default shape
    parser = argparse.ArgumentParser()
    head_cli.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["head", "export", str(tmp_path / "b")])
    assert args.func(args) == 0
    for name in ("head.obj", "landmarks.json", "scalp_uv.npz"):
        assert (tmp_path / "b" / name).read_bytes() == (tmp_path / "a" / name).read_bytes()


def _trilinear_reference(grid: SDFGrid, p: np.ndarray) -> float:
    """Slow per-point trilinear interpolation of the grid (clamped to the box, plus the distance to it)."""
    lo, hi, vals = np.asarray(grid.bbox_min, float), np.asarray(grid.bbox_max, float), grid.values.astype(float)
    c = np.clip(p, lo, hi)
    g = (c - lo) / (hi - lo) * (np.array(vals.shape) - 1)
    i = np.clip(np.floor(g).astype(int), 0, np.array(vals.shape) - 2)
    t = g - i
    out = 0.0
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (t[0] if dx else 1 - t[0]) * (t[1] if dy else 1 - t[1]) * (t[2] if dz else 1 - t[2])
                out += w * vals[i[0] + dx, i[1] + dy, i[2] + dz]
    return out + float(np.linalg.norm(p - c))


def test_sdf_lookup_matches_a_slow_trilinear_reference(head):
    rng = np.random.default_rng(5)
    lo, hi = np.asarray(head.sdf_grid.bbox_min), np.asarray(head.sdf_grid.bbox_max)
    pts = rng.uniform(lo - 0.05, hi + 0.05, size=(300, 3))    # inside and outside the box
    ref = np.array([_trilinear_reference(head.sdf_grid, p) for p in pts])
    got = head.sdf(torch.tensor(pts, dtype=torch.float64)).numpy()
    np.testing.assert_allclose(got, ref, atol=1e-9)
    got32 = head.sdf(torch.tensor(pts, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(got32, ref, atol=2e-6)
    assert head.sdf(torch.zeros(4, 7, 3)).shape == (4, 7)
