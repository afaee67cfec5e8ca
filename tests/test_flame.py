"""Tests of the FLAME loader (restricted unpickler, skinning) on a small fake model file."""

from __future__ import annotations

import builtins
import os
import pickle
import sys
import types

import numpy as np
import pytest
import scipy.sparse
import trimesh

from vid2haircut.geometry import axis_angle_to_matrix
from vid2haircut.head import load_flame
from vid2haircut.head.safepickle import safe_load_pickle

N_SHAPE, N_EXPR = 3, 2


class _FakeCh:
    """Pickles like a chumpy array (module ``chumpy.ch``, class ``Ch``, state {'x': array})."""

    def __init__(self, x):
        self.x = x


# pickle looks the class up as chumpy.ch.Ch (registered in sys.modules only while dumping)
_FakeCh.__module__, _FakeCh.__qualname__ = "chumpy.ch", "Ch"

def _fake_flame_dict(rng: np.random.Generator) -> dict:
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    v = np.asarray(sphere.vertices, dtype=np.float64)
    nv = len(v)
    jr = np.zeros((5, nv))
    for j in range(5):                      # each joint: mean of a few vertices
        jr[j, rng.choice(nv, 4, replace=False)] = 0.25
    weights = np.zeros((nv, 5))
    weights[np.arange(nv), rng.integers(0, 5, nv)] = 1.0
    kintree = np.array([[4294967295, 0, 1, 1, 1], [0, 1, 2, 3, 4]], dtype=np.uint32)
    return {
        "v_template": v,
        "f": np.asarray(sphere.faces, dtype=np.uint32),
        "shapedirs": _FakeCh(rng.normal(0.0, 0.01, (nv, 3, N_SHAPE + N_EXPR))),
        "posedirs": _FakeCh(rng.normal(0.0, 0.001, (nv, 3, 36))),
        "J_regressor": scipy.sparse.csc_matrix(jr),
        "weights": _FakeCh(weights),
        "kintree_table": kintree,
        "bs_style": "lbs",
    }


def _dump_with_fake_chumpy(obj, path, monkeypatch) -> None:
    """Pickle ``obj`` (protocol 2, like the Python 2 files) with _FakeCh posing as chumpy.ch.Ch."""
    pkg, mod = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")
    mod.Ch = _FakeCh
    monkeypatch.setitem(sys.modules, "chumpy", pkg)
    monkeypatch.setitem(sys.modules, "chumpy.ch", mod)
    with open(path, "wb") as fh:
        pickle.dump(obj, fh, protocol=2)
    monkeypatch.undo()


@pytest.fixture()
def fake_flame(tmp_path, monkeypatch):
    data = _fake_flame_dict(np.random.default_rng(0))
    path = tmp_path / "generic_model.pkl"
    _dump_with_fake_chumpy(data, path, monkeypatch)
    assert "chumpy" not in sys.modules
    return path, data


def test_load_shapes_and_zero_pose(fake_flame):
    path, data = fake_flame
    model = load_flame(path, n_shape=N_SHAPE)
    nv = len(data["v_template"])
    assert model.shapedirs.shape == (nv, 3, N_SHAPE + N_EXPR)
    assert model.posedirs.shape == (36, nv * 3)
    assert model.j_regressor.shape == (5, nv) and model.weights.shape == (nv, 5)
    assert model.parents.tolist() == [-1, 0, 1, 1, 1]
    assert model.n_expression == N_EXPR and model.faces.dtype == np.int64
    np.testing.assert_allclose(model.vertices(), data["v_template"], atol=1e-12)


def test_shape_expression_and_pose(fake_flame):
    path, data = fake_flame
    model = load_flame(path, n_shape=N_SHAPE)
    sd = data["shapedirs"].x
    v = model.vertices(shape=[1.5], expression=[0.0, -2.0])
    np.testing.assert_allclose(v, data["v_template"] + 1.5 * sd[:, :, 0] - 2.0 * sd[:, :, N_SHAPE + 1],
                               atol=1e-12)
    # a global rotation turns everything about the root joint (no pose correctives for the root)
    rot = np.array([0.0, np.pi / 2, 0.0])
    j0 = model.j_regressor[0] @ data["v_template"]
    v, joints = model.forward(pose=np.concatenate([rot, np.zeros(12)]), translation=[0, 0, 1])
    expect = (data["v_template"] - j0) @ axis_angle_to_matrix(rot).T + j0 + [0, 0, 1]
    np.testing.assert_allclose(v, expect, atol=1e-12)
    # a jaw rotation moves exactly the jaw-weighted vertices about the jaw joint (+ correctives)
    pose = np.zeros((5, 3))
    pose[2] = [0.3, 0.0, 0.0]
    v = model.vertices(pose=pose)
    r = axis_angle_to_matrix(pose[2])
    corr = ((r - np.eye(3)).reshape(-1) @ model.posedirs[9:18]).reshape(-1, 3)
    j2 = model.j_regressor[2] @ data["v_template"]
    jaw = data["weights"].x[:, 2] == 1
    np.testing.assert_allclose(v[jaw], (data["v_template"][jaw] + corr[jaw] - j2) @ r.T + j2, atol=1e-12)
    np.testing.assert_allclose(v[~jaw], data["v_template"][~jaw] + corr[~jaw], atol=1e-12)
    with pytest.raises(ValueError, match="shape parameters"):
        model.vertices(shape=np.ones(N_SHAPE + 1))


class _Evil:
    def __init__(self, func, arg):
        self.func, self.arg = func, arg

    def __reduce__(self):
        return (self.func, (self.arg,))


@pytest.mark.parametrize("kind", ["os.system", "builtins.eval"])
def test_malicious_pickle_is_refused(tmp_path, kind):
    marker = tmp_path / "pwned"
    if kind == "os.system":
        payload = _Evil(os.system, f"touch {marker}")
    else:
        payload = _Evil(builtins.eval, f"open({str(marker)!r}, 'w').write('x')")
    path = tmp_path / "evil.pkl"
    with open(path, "wb") as fh:
        pickle.dump({"v_template": np.zeros((3, 3)), "f": payload}, fh, protocol=2)
    with pytest.raises(ValueError) as err:
        load_flame(path)
    msg = str(err.value)
    assert str(path) in msg and ("system" in msg or "eval" in msg)
    assert not marker.exists()


def test_bad_files(tmp_path, fake_flame):
    with pytest.raises(FileNotFoundError):
        load_flame(tmp_path / "missing.pkl")
    junk = tmp_path / "junk.pkl"
    junk.write_bytes(b"this is not a pickle")
    with pytest.raises(ValueError, match="junk.pkl"):
        load_flame(junk)
    partial = tmp_path / "partial.pkl"
    with open(partial, "wb") as fh:
        pickle.dump({"v_template": np.zeros((3, 3))}, fh, protocol=2)
    with pytest.raises(ValueError, match="missing key"):
        load_flame(partial)
    # plain numpy content loads with the restricted unpickler
    assert safe_load_pickle(partial)["v_template"].shape == (3, 3)


def test_as_head_model(fake_flame):
    path, data = fake_flame
    model = load_flame(path, n_shape=N_SHAPE)
    rng = np.random.default_rng(3)
    face_idx = rng.integers(0, len(data["f"]), 68)
    bary = rng.dirichlet(np.ones(3), 68)
    head = model.as_head_model(landmark_embedding=(face_idx, bary), sdf_res=40)
    assert head.vertices.shape == data["v_template"].shape and head.landmarks.shape == (68, 3)
    assert head.sdf_grid.values.shape == (40, 40, 40)
    assert np.abs(head.sdf_np(head.landmarks)).max() < 1.5e-3
    assert head.sdf_np(np.zeros(3)) < -0.09 and head.sdf_np(np.array([0.3, 0.0, 0.0])) > 0.15
    # exact for the sphere: the SDF is about |p| - r (minus the polygon's chord error)
    p = rng.normal(size=(200, 3))
    p *= rng.uniform(0.05, 0.15, (200, 1)) / np.linalg.norm(p, axis=1, keepdims=True)
    assert np.abs(head.sdf_np(p) - (np.linalg.norm(p, axis=1) - 0.1)).max() < 2.5e-3
    pts, nrm = head.scalp_uv_to_root(rng.uniform(0.1, 0.9, (100, 2)))
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), 0.1, atol=1.5e-3)
    assert np.all((nrm * pts).sum(1) / 0.1 > 0.99)
    assert head.scalp_mask(16)[8, 8]
    # landmarks from a file embedding too; a wrong count is refused
    emb = path.parent / "emb.npz"
    np.savez(emb, lmk_face_idx=face_idx, lmk_b_coords=bary)
    head2 = model.as_head_model(landmark_embedding=emb)
    np.testing.assert_allclose(head2.landmarks, head.landmarks)
    with pytest.raises(ValueError, match="68"):
        model.as_head_model(landmark_embedding=(face_idx[:51], bary[:51]))
