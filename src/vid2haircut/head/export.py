"""Writing a head model to files: ``head.obj``, ``landmarks.json``, ``scalp_uv.npz``."""

from __future__ import annotations

import io
from pathlib import Path
from typing import NamedTuple

import numpy as np

from vid2haircut.head.landmarks import LANDMARK_GROUPS
from vid2haircut.head.model import HeadModel
from vid2haircut.head.scalp import texel_uv
from vid2haircut.io.atomic import write_json, write_npz, write_text


class HeadFiles(NamedTuple):
    """Paths written by :func:`export_head`."""

    mesh: Path        # head.obj: vertices (metres) and 1-based triangles
    landmarks: Path   # landmarks.json: {"name", "params", "landmarks" (68x3 or null), "groups"}
    scalp: Path       # scalp_uv.npz: uv, roots, normals (res,res,{2,3,3}) float32, mask (res,res)


def obj_text(vertices: np.ndarray, faces: np.ndarray, header: str = "") -> str:
    """Wavefront OBJ text of a triangle mesh: (V, 3) vertices, (F, 3) 0-based faces."""
    buf = io.StringIO()
    if header:
        buf.write(f"# {header}\n")
    np.savetxt(buf, np.asarray(vertices, dtype=np.float64), fmt="v %.6f %.6f %.6f")
    np.savetxt(buf, np.asarray(faces, dtype=np.int64) + 1, fmt="f %d %d %d")
    return buf.getvalue()


def export_head(head: HeadModel, out_dir: str | Path, res: int = 64) -> HeadFiles:
    """Write the head mesh, its landmarks and its scalp UV maps (atomically) into ``out_dir``.

    ``scalp_uv.npz`` holds, for the res x res texel centres (index [row=v, col=u]): ``uv``
    (res, res, 2), ``roots`` (res, res, 3) surface points, ``normals`` (res, res, 3) and
    ``mask`` (res, res) bool (hair-bearing).
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: exists and is not a directory")
    files = HeadFiles(out / "head.obj", out / "landmarks.json", out / "scalp_uv.npz")
    write_text(files.mesh, obj_text(head.vertices, head.faces, header=f"vid2haircut head {head.name}"))
    lm = None if head.landmarks is None else np.round(head.landmarks.astype(np.float64), 7).tolist()
    write_json(files.landmarks, {"name": head.name, "params": head.params, "landmarks": lm,
                                 "groups": LANDMARK_GROUPS, "units": "metres"})
    uv = texel_uv(res)
    roots, normals = head.scalp_uv_to_root(uv)
    write_npz(files.scalp, uv=uv.astype(np.float32), roots=roots, normals=normals,
              mask=head.scalp_mask(res))
    return files


def export_proxy_head(out_dir: str | Path, scale: float = 1.0, width: float = 1.0,
                      depth: float = 1.0, crown: float = 1.0, res: int = 64) -> HeadFiles:
    """Build the built-in proxy head with the given shape factors and export it (CLI entry)."""
    from vid2haircut.head import get_head

    return export_head(get_head("proxy-v1", scale=scale, width=width, depth=depth, crown=crown),
                       out_dir, res=res)
