"""Exports read back through their own readers (USD through pxr), and the two CLI sub-commands."""

import argparse
import json
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from vid2haircut.cli import evaluate as cli_evaluate
from vid2haircut.cli import export as cli_export
from vid2haircut.export import export_hairstyle, read_usd_curves
from vid2haircut.io.strand_formats import load_strands, save_strands
from vid2haircut.strands import StrandSet

TETRA_V = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], np.float32)
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], np.int64)


def _set(n=7, p=11):
    rng = np.random.default_rng(4)
    pts = rng.normal(scale=0.01, size=(n, p, 3)).cumsum(1).astype(np.float32)
    return StrandSet(pts, {"color": rng.random((n, 3)).astype(np.float32),
                           "width": np.full(n, 8e-5, np.float32)}, "proxy-v1")


def _parse(module, argv):
    parser = argparse.ArgumentParser()
    module.register(parser.add_subparsers(dest="command"))
    return parser.parse_args(argv)


@pytest.mark.parametrize("usd_format", ["usda", "usdc"])
def test_export_all_formats_read_back(tmp_path, usd_format):
    from pxr import Usd, UsdGeom

    s = _set()
    files = export_hairstyle(s, tmp_path / "out", TETRA_V, TETRA_F, usd_format=usd_format)
    assert set(files) == {"usd", "hair", "data", "ply", "npz", "head_obj"}
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(
        ["hair.hair", "hair.data", "hair.ply", "hair.npz", f"hair.{usd_format}", "head.obj"])
    for fmt in ("hair", "data", "ply", "npz"):
        assert np.array_equal(load_strands(files[fmt]).points, s.points), fmt

    stage = Usd.Stage.Open(str(files["usd"]))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    curves = UsdGeom.BasisCurves(stage.GetPrimAtPath("/Hairstyle/Strands"))
    assert curves.GetTypeAttr().Get() == UsdGeom.Tokens.linear
    assert list(curves.GetCurveVertexCountsAttr().Get()) == [11] * 7          # one curve per strand
    assert np.array_equal(np.asarray(curves.GetPointsAttr().Get()), s.points.reshape(-1, 3))
    widths = np.asarray(curves.GetWidthsAttr().Get())
    assert widths.shape == (77,) and np.allclose(widths, 8e-5)
    colors = np.asarray(curves.GetDisplayColorPrimvar().Get())
    assert np.array_equal(colors, s.attributes["color"])
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Hairstyle/Head"))
    assert np.array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()), TETRA_F.ravel())
    back = read_usd_curves(files["usd"])
    assert np.array_equal(back.points, s.points) and back.head_model == "proxy-v1"

    lines = files["head_obj"].read_text().splitlines()
    v = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("v ")])
    f = np.array([[int(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("f ")])
    assert np.array_equal(v.astype(np.float32), TETRA_V) and np.array_equal(f - 1, TETRA_F)
    import trimesh

    tm = trimesh.load(files["head_obj"], process=False)
    assert tm.is_watertight and tm.volume > 0                                 # outward winding kept


def test_export_without_head_and_errors(tmp_path):
    s = StrandSet(_set().points)                                              # no attributes
    files = export_hairstyle(s, tmp_path, stem="x")
    assert "head_obj" not in files and not (tmp_path / "head.obj").exists()
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(files["usd"]))
    curves = UsdGeom.BasisCurves(stage.GetPrimAtPath("/Hairstyle/Strands"))
    assert len(curves.GetWidthsAttr().Get()) == 77
    with pytest.raises(ValueError, match="usd_format"):
        export_hairstyle(s, tmp_path, usd_format="abc")
    with pytest.raises(ValueError, match="both"):
        export_hairstyle(s, tmp_path, head_vertices=TETRA_V)


def test_cli_export_with_head(tmp_path, monkeypatch):
    src = save_strands(tmp_path / "in.data", _set())
    calls = []

    def fake_get_head(name, **kw):
        calls.append(name)
        return SimpleNamespace(name=name, vertices=TETRA_V, faces=TETRA_F)

    # a stand-in for the head package (HEAD CONTRACT: get_head(name) -> .name, .vertices, .faces)
    monkeypatch.setitem(sys.modules, "vid2haircut.head", SimpleNamespace(get_head=fake_get_head))
    args = _parse(cli_export, ["export", "--strands", str(src), "--out-dir", str(tmp_path / "o"),
                               "--head", "proxy-v1", "--usd-format", "usdc"])
    assert args.func(args) == 0
    assert calls == ["proxy-v1"]
    assert (tmp_path / "o" / "hair.usdc").is_file() and (tmp_path / "o" / "head.obj").is_file()
    assert np.array_equal(load_strands(tmp_path / "o" / "hair.npz").points, _set().points)


def test_cli_evaluate(tmp_path):
    s = _set()
    save_strands(tmp_path / "gt.npz", s)
    save_strands(tmp_path / "pred.hair", s)
    args = _parse(cli_evaluate, ["evaluate", "--pred", str(tmp_path / "pred.hair"), "--gt",
                                 str(tmp_path / "gt.npz"), "--out", str(tmp_path / "m.json"), "--n-points", "11",
                                 "--max-points", "50", "--seed", "3"])
    assert args.func(args) == 0
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["chamfer_pts"] == 0.0 and m["f1_2mm_20deg"] == 1.0
    assert m["n_points_pred"] == 50 and m["seed"] == 3 and m["points_per_strand"] == 11
