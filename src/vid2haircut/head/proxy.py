"""The built-in procedural head "proxy-v1": a deformed UV sphere over the radial function.

The mesh is a UV sphere whose vertices are pushed onto the star-shaped surface of
:mod:`vid2haircut.head.radial`; the rings are spaced evenly in arc length of the profile (so the
long neck gets as many rings as it needs) and the poles are closed by triangle fans, so the mesh
is watertight with outward (counter-clockwise) winding.
"""

from __future__ import annotations

import functools

import numpy as np

from vid2haircut.head.landmarks import landmark_directions
from vid2haircut.head.meshdist import closest_points_on_mesh
from vid2haircut.head.model import HeadModel
from vid2haircut.head.radial import RadialShape, dirs_from_angles
from vid2haircut.head.scalp import PROXY_EARS_DEG
from vid2haircut.head.sdf import SDFGrid, build_sdf_grid

PROXY_NAME = "proxy-v1"
N_RINGS = 78      # latitude rings between the poles
N_SEGMENTS = 120  # vertices per ring


def _ring_thetas(shape: RadialShape, n_rings: int) -> np.ndarray:
    """(n_rings,) polar angles of the rings, evenly spaced in mean profile arc length."""
    theta = np.linspace(0.0, np.pi, 2001)
    phi = np.linspace(-np.pi, np.pi, 16, endpoint=False)
    pts = shape.surface_points(dirs_from_angles(theta[:, None], phi[None, :]))  # (T, P, 3)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=-1).mean(axis=1)
    # Blend arc length with angle so that no ring gap collapses where the surface is steep.
    seg = 0.8 * seg / seg.sum() + 0.2 / len(seg)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    targets = np.linspace(0.0, cum[-1], n_rings + 2)[1:-1]
    return np.interp(targets, cum, theta)


def _segment_phis(n_segments: int) -> np.ndarray:
    """(n_segments,) azimuths in [-pi, pi), denser on the face (nose) and at the ears."""
    phi = np.linspace(-np.pi, np.pi, 4001)
    density = (1.0 + 2.0 * np.exp(-0.5 * (phi / 0.35) ** 2)
               + 0.8 * np.exp(-0.5 * ((np.abs(phi) - 1.71) / 0.2) ** 2))
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(phi))])
    targets = np.linspace(0.0, cum[-1], n_segments, endpoint=False)
    return np.interp(targets, cum, phi)


def build_proxy_mesh(shape: RadialShape, n_rings: int = N_RINGS,
                     n_segments: int = N_SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """Mesh the radial surface.

    Returns:
        vertices: (2 + n_rings * n_segments, 3) float64, metres (vertex 0 top pole, 1 bottom).
        faces: (2 * n_rings * n_segments, 3) int64, counter-clockwise seen from outside.
    """
    thetas = _ring_thetas(shape, n_rings)
    phis = _segment_phis(n_segments)
    dirs = np.concatenate([
        np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]),
        dirs_from_angles(thetas[:, None], phis[None, :]).reshape(-1, 3),
    ])
    verts = shape.surface_points(dirs)

    def vid(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return 2 + i * n_segments + (j % n_segments)

    j = np.arange(n_segments)
    faces = [np.stack([np.zeros_like(j), vid(0, j), vid(0, j + 1)], axis=1)]
    for i in range(n_rings - 1):
        a, b = vid(i, j), vid(i, j + 1)
        c, d = vid(i + 1, j), vid(i + 1, j + 1)
        faces.append(np.stack([a, c, d], axis=1))
        faces.append(np.stack([a, d, b], axis=1))
    last = n_rings - 1
    faces.append(np.stack([np.ones_like(j), vid(last, j + 1), vid(last, j)], axis=1))
    return verts, np.concatenate(faces).astype(np.int64)


@functools.lru_cache(maxsize=8)
def build_proxy_head(scale: float = 1.0, width: float = 1.0, depth: float = 1.0,
                     crown: float = 1.0) -> HeadModel:
    """Build (and cache) the proxy head for the given shape factors."""
    shape = RadialShape(scale=scale, width=width, depth=depth, crown=crown)
    verts, faces = build_proxy_mesh(shape)
    # Landmarks: rays through the base-shape landmark directions, mapped by the shape's axes,
    # then snapped onto the mesh (sub-millimetre move) so that they lie on the drawn surface.
    base = RadialShape(crown=crown)
    lm = base.surface_points(landmark_directions()) * shape.axes
    lm = closest_points_on_mesh(verts, faces, lm, k=32)[2]

    def cast(dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return shape.surface_points(dirs), shape.normals(dirs)

    def make_sdf() -> SDFGrid:
        return build_sdf_grid(verts, faces, inside=lambda p: shape.implicit(p) < 0.0)

    return HeadModel(
        name=PROXY_NAME,
        vertices=verts.astype(np.float32),
        faces=faces,
        landmarks=lm.astype(np.float32),
        sdf_source=make_sdf,
        center=np.zeros(3, dtype=np.float32),
        caster=cast,
        params={"scale": scale, "width": width, "depth": depth, "crown": crown},
        ears_deg=PROXY_EARS_DEG,
    )
