"""Export a reconstructed hairstyle to the formats other tools read: USD BasisCurves, Cem Yuksel
``.hair``, USC ``.data``, PLY polylines, the project's ``.npz``, and the head as ``head.obj``."""

from __future__ import annotations

import io
import logging
import os
from pathlib import Path

import numpy as np

from vid2haircut.export.usd import write_usd_curves
from vid2haircut.io.atomic import check_outputs, write_text
from vid2haircut.io.strand_formats import load_strands, save_strands
from vid2haircut.strands import StrandSet, check_exported_attributes

__all__ = ["export_hairstyle", "export_files", "write_obj"]

log = logging.getLogger(__name__)


def write_obj(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray) -> Path:
    """Atomically write a triangle mesh as Wavefront OBJ (1-based indices, ``%.9g`` floats).

    Args:
        vertices: (V,3) float; faces: (F,3) int, 0-based.
    """
    path = Path(path)
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"{path}: face indices out of range [0,{len(v)})")
    buf = io.StringIO()
    buf.write(f"# vid2haircut head mesh: {len(v)} vertices, {len(f)} faces, metres, y up\n")
    np.savetxt(buf, v, fmt="v %.9g %.9g %.9g")
    np.savetxt(buf, f + 1, fmt="f %d %d %d")
    write_text(path, buf.getvalue())
    return path


def export_hairstyle(strands: StrandSet, out_dir: str | os.PathLike, head_vertices: np.ndarray | None = None,
                     head_faces: np.ndarray | None = None, stem: str = "hair",
                     usd_format: str = "usda") -> dict[str, Path]:
    """Write ``strands`` to ``out_dir`` in every export format.

    Args:
        strands: N strands of P points, metres, head frame.
        out_dir: output folder (created).
        head_vertices, head_faces: optional head mesh (V,3) / (F,3) written as ``head.obj`` and
            as ``/Hairstyle/Head`` in the USD stage.
        stem: file name stem of the strand files.
        usd_format: ``"usda"`` (text) or ``"usdc"`` (binary crate).

    Returns:
        {"usd", "hair", "data", "ply", "npz"[, "head_obj"]} -> written paths.
    """
    if usd_format not in ("usda", "usdc"):
        raise ValueError(f"export_hairstyle: usd_format must be 'usda' or 'usdc', got {usd_format!r}")
    if (head_vertices is None) != (head_faces is None):
        raise ValueError("export_hairstyle: give both head_vertices and head_faces, or neither")
    if strands.n_strands == 0:
        raise ValueError("export_hairstyle: the strand set is empty")
    check_exported_attributes(strands, "export_hairstyle")  # before the first file (one had been half-written)
    out = Path(out_dir)
    check_outputs([out / f"{stem}.{fmt}" for fmt in (usd_format, "hair", "data", "ply", "npz")]
                  + ([out / "head.obj"] if head_vertices is not None else []))
    out.mkdir(parents=True, exist_ok=True)
    written = {"usd": write_usd_curves(out / f"{stem}.{usd_format}", strands, head_vertices, head_faces)}
    for fmt in ("hair", "data", "ply", "npz"):
        written[fmt] = save_strands(out / f"{stem}.{fmt}", strands)
    if head_vertices is not None:
        written["head_obj"] = write_obj(out / "head.obj", head_vertices, head_faces)
    return written


def export_files(strands_path: str | os.PathLike, out_dir: str | os.PathLike, head: str | None = None,
                 stem: str = "hair", usd_format: str = "usda") -> dict[str, Path]:
    """Load a strand file and export it with :func:`export_hairstyle`.

    Args:
        strands_path: any strand file :func:`~vid2haircut.io.strand_formats.load_strands` reads.
        head: optional head model name for :func:`vid2haircut.head.get_head` (e.g. ``"proxy-v1"``).
    """
    strands = load_strands(strands_path)
    if strands.n_strands == 0:
        raise ValueError(f"{strands_path}: the strand file holds no strands")
    check_exported_attributes(strands, str(strands_path))
    verts = faces = None
    if head:
        from vid2haircut.head import get_head

        model = get_head(head)
        if strands.head_model and strands.head_model != model.name:
            log.warning("%s: strands are in the frame of head model %r, exporting with head %r",
                        strands_path, strands.head_model, model.name)
        verts, faces = model.vertices, model.faces
    written = export_hairstyle(strands, out_dir, verts, faces, stem=stem, usd_format=usd_format)
    log.info("exported %d strands x %d points to %s", strands.n_strands, strands.n_points, out_dir)
    return written
