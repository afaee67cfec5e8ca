"""USD export of a hairstyle: linear ``BasisCurves`` (one curve per strand) and an optional head mesh.

Stage layout (metres, y up)::

    /Hairstyle            Xform (default prim)
    /Hairstyle/Strands    BasisCurves, type linear, curveVertexCounts = [P] * N,
                          points (N*P,3), widths per vertex, displayColor per curve if known
    /Hairstyle/Head       Mesh (triangles), when a head is given
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from vid2haircut.io.atomic import atomic_path
from vid2haircut.strands import StrandSet

__all__ = ["DEFAULT_WIDTH", "write_usd_curves", "read_usd_curves"]

#: Strand width (diameter, metres) used when the strand set has no ``width`` attribute.
DEFAULT_WIDTH = 1e-4


def write_usd_curves(path: str | os.PathLike, strands: StrandSet, head_vertices: np.ndarray | None = None,
                     head_faces: np.ndarray | None = None) -> Path:
    """Atomically write ``strands`` (and a head mesh) as a ``.usda`` / ``.usdc`` / ``.usd`` stage.

    Args:
        path: output file; the suffix picks the USD encoding.
        strands: N strands of P points.
        head_vertices: optional (V,3) float head mesh vertices (metres, same frame as the strands).
        head_faces: optional (F,3) int triangles (counter-clockwise seen from outside).

    Returns:
        The written path.
    """
    from pxr import Gf, Usd, UsdGeom, Vt

    path = Path(path)
    if path.suffix.lower() not in (".usda", ".usdc", ".usd"):
        raise ValueError(f"{path}: USD export needs a .usda, .usdc or .usd suffix")
    n, p = strands.points.shape[:2]
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/Hairstyle")
    stage.SetDefaultPrim(root.GetPrim())
    if strands.head_model:
        root.GetPrim().SetCustomDataByKey("vid2haircut:head_model", strands.head_model)

    curves = UsdGeom.BasisCurves.Define(stage, "/Hairstyle/Strands")
    curves.CreateTypeAttr(UsdGeom.Tokens.linear)
    curves.CreateWrapAttr(UsdGeom.Tokens.nonperiodic)
    curves.CreateCurveVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(n, p, np.int32)))
    flat = np.ascontiguousarray(strands.points.reshape(-1, 3), np.float32)
    curves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(flat))
    width = np.asarray(strands.attributes.get("width", np.full(n, DEFAULT_WIDTH)), np.float32).reshape(n)
    curves.CreateWidthsAttr(Vt.FloatArray.FromNumpy(np.repeat(width, p).astype(np.float32)))
    curves.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
    if "color" in strands.attributes:
        color = np.asarray(strands.attributes["color"], np.float32).reshape(n, 3)
        curves.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set(Vt.Vec3fArray.FromNumpy(color))
    extent = _extent(flat, width.max(initial=0.0) / 2)
    curves.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, e)) for e in extent]))

    if head_vertices is not None and head_faces is not None:
        verts = np.ascontiguousarray(head_vertices, np.float32).reshape(-1, 3)
        faces = np.ascontiguousarray(head_faces, np.int64).reshape(-1, 3)
        if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
            raise ValueError(f"{path}: head face indices out of range [0,{len(verts)})")
        mesh = UsdGeom.Mesh.Define(stage, "/Hairstyle/Head")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(verts))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1).astype(np.int32)))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, e)) for e in _extent(verts, 0.0)]))

    with atomic_path(path) as tmp:
        if not stage.GetRootLayer().Export(str(tmp)):
            raise OSError(f"{path}: USD could not write the stage")
    return path


def _extent(points: np.ndarray, pad: float) -> np.ndarray:
    """(2,3) axis-aligned bounds of (M,3) points grown by ``pad``; zeros for no points."""
    if len(points) == 0:
        return np.zeros((2, 3))
    return np.stack([points.min(0) - pad, points.max(0) + pad])


def read_usd_curves(path: str | os.PathLike, prim_path: str = "/Hairstyle/Strands") -> StrandSet:
    """Read linear BasisCurves with equal vertex counts back into a :class:`StrandSet`."""
    from pxr import Usd, UsdGeom

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: USD file not found")
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath(prim_path) if stage else None
    if not prim or not prim.IsA(UsdGeom.BasisCurves):
        raise ValueError(f"{path}: no BasisCurves prim at {prim_path}")
    curves = UsdGeom.BasisCurves(prim)
    counts = np.asarray(curves.GetCurveVertexCountsAttr().Get(), np.int64)
    pts = np.asarray(curves.GetPointsAttr().Get(), np.float32)
    if len(counts) == 0 or counts.min() != counts.max() or counts.sum() != len(pts):
        raise ValueError(f"{path}: curves at {prim_path} do not all have the same vertex count")
    attrs = {}
    widths = curves.GetWidthsAttr().Get()
    if widths is not None and len(widths) == len(pts):
        attrs["width"] = np.asarray(widths, np.float32).reshape(len(counts), -1)[:, 0]
    head = stage.GetDefaultPrim().GetCustomDataByKey("vid2haircut:head_model") if stage.GetDefaultPrim() else None
    return StrandSet(pts.reshape(len(counts), int(counts[0]), 3), attrs, head)
