"""Fields over the scalp for procedural hair: root sampling, combing direction, length map,
cut levels and the face keep-out zone.

Angles follow the head's scalp-UV convention: polar angle ``theta`` from +y (0 at the crown),
azimuth ``phi = atan2(x, z)`` (0 towards the face, +pi/2 towards +x).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .hair_params import HairParams

__all__ = ["Roots", "FaceZone", "sample_roots", "uv_to_angles", "region_weights",
           "comb_direction", "length_map", "cut_level", "face_zone", "in_face_zone",
           "fringe_weights", "hairline_angles", "smoothstep"]

_RHO_TO_THETA = 2.0 * np.pi / 3.0


class Roots(NamedTuple):
    """Sampled strand roots."""

    uv: np.ndarray       # (N,2) float32 scalp uv
    points: np.ndarray   # (N,3) float64 root points on the head surface
    normals: np.ndarray  # (N,3) float64 unit outward normals
    theta: np.ndarray    # (N,) polar angle from the crown (radians)
    phi: np.ndarray      # (N,) azimuth, 0 = face direction (radians)


class FaceZone(NamedTuple):
    """Box in front of the face that hair must not enter (head frame, metres)."""

    y_top: float     # eyebrow height: no hair below it in front of the face
    y_bottom: float  # below the chin the zone ends
    x_half: float    # half-width of the zone (outer eye corners plus a margin)
    z_min: float     # the zone is in front of this depth
    y_brow: float    # mean eyebrow height (fringe cut reference)


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """Cubic smooth step from 0 at ``e0`` to 1 at ``e1`` (any shape)."""
    t = np.clip((np.asarray(x, np.float64) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def uv_to_angles(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scalp uv (...,2) -> (theta (...), phi (...)) in radians."""
    du, dv = uv[..., 0] - 0.5, uv[..., 1] - 0.5
    return 2.0 * np.hypot(du, dv) * _RHO_TO_THETA, np.arctan2(du, dv)


def _area_jacobian(head, uv: np.ndarray, eps: float = 1e-3) -> np.ndarray:
    """(M,) surface area per unit uv area at ``uv`` (M,2), by central differences."""
    e = np.array([[eps, 0.0], [0.0, eps]])
    stacked = np.concatenate([uv + e[0], uv - e[0], uv + e[1], uv - e[1]])
    p = np.asarray(head.scalp_uv_to_root(stacked.astype(np.float32))[0], np.float64)
    pu_p, pu_m, pv_p, pv_m = np.split(p, 4)
    return np.linalg.norm(np.cross(pu_p - pu_m, pv_p - pv_m), axis=-1) / (4.0 * eps * eps)


def sample_roots(head, n: int, rng: np.random.Generator, mask_res: int = 512) -> Roots:
    """Sample ``n`` roots evenly over the scalp surface.

    A jittered grid in uv, restricted to ``head.scalp_mask`` and thinned with probability
    proportional to the surface-area Jacobian of the uv map (so density is uniform on the head,
    not in uv); a random subset of exactly ``n`` survivors is kept.

    Args:
        head: head model (``scalp_mask``, ``scalp_uv_to_root``).
        n: number of roots N >= 1.
        rng: random generator.
        mask_res: resolution of the scalp mask lookup.

    Returns:
        :class:`Roots` with N entries.
    """
    if n < 1:
        raise ValueError(f"n_strands must be >= 1, got {n}")
    mask = np.asarray(head.scalp_mask(mask_res), bool)
    if not mask.any():
        raise ValueError(f"head {getattr(head, 'name', '?')!r} has an empty scalp mask")
    # expected acceptance from a coarse evaluation of the Jacobian over the mask
    rows, cols = np.nonzero(mask[::8, ::8])
    probe = (np.stack([cols, rows], -1) * 8 + 4.5) / mask_res
    jac = _area_jacobian(head, probe)
    jmax = float(jac.max()) * 1.05
    accept = mask.mean() * float(jac.mean()) / jmax
    g = int(np.ceil(np.sqrt(1.15 * n / max(accept, 1e-6)))) + 2
    for _ in range(20):
        ii, jj = np.meshgrid(np.arange(g), np.arange(g), indexing="xy")
        uv = (np.stack([ii, jj], -1).reshape(-1, 2) + rng.uniform(size=(g * g, 2))) / g
        col = np.clip((uv[:, 0] * mask_res).astype(int), 0, mask_res - 1)
        row = np.clip((uv[:, 1] * mask_res).astype(int), 0, mask_res - 1)
        uv = uv[mask[row, col]]
        keep = rng.uniform(size=len(uv)) * jmax < _area_jacobian(head, uv)
        uv = uv[keep]
        if len(uv) >= n:
            break
        g = int(np.ceil(g * 1.15)) + 1
    else:  # pragma: no cover - only for degenerate masks
        raise ValueError(f"could not sample {n} roots on the scalp of {getattr(head, 'name', '?')!r}")
    uv = uv[np.sort(rng.choice(len(uv), n, replace=False))].astype(np.float32)
    pts, nrm = head.scalp_uv_to_root(uv)
    theta, phi = uv_to_angles(uv.astype(np.float64))
    return Roots(uv, np.asarray(pts, np.float64), np.asarray(nrm, np.float64), theta, phi)


def hairline_angles(head, phi: np.ndarray, mask_res: int = 256, n_bins: int = 72) -> np.ndarray:
    """Polar angle of the scalp's hairline (...) at azimuths ``phi`` (...), from the scalp mask.

    The largest texel polar angle inside the mask per azimuth bin, circularly smoothed and
    linearly interpolated.
    """
    mask = np.asarray(head.scalp_mask(mask_res), bool)
    c = (np.arange(mask_res) + 0.5) / mask_res
    u, v = np.meshgrid(c, c, indexing="xy")                 # [row=v, col=u]
    th, ph = uv_to_angles(np.stack([u, v], -1))
    b = np.clip(((ph[mask] + np.pi) / (2 * np.pi) * n_bins).astype(int), 0, n_bins - 1)
    edge = np.zeros(n_bins)
    np.maximum.at(edge, b, th[mask])
    edge = np.where(edge > 0, edge, edge.max())
    edge = (np.roll(edge, 1) + 2 * edge + np.roll(edge, -1)) / 4.0
    centres = (np.arange(n_bins) + 0.5) / n_bins * 2 * np.pi - np.pi
    return np.interp(phi, centres, edge, period=2 * np.pi)


def region_weights(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Front / side / back blend weights (each shaped like ``phi``), summing to 1."""
    c = np.cos(phi)
    return np.maximum(c, 0.0) ** 2, np.sin(phi) ** 2, np.maximum(-c, 0.0) ** 2


def length_map(theta: np.ndarray, phi: np.ndarray, p: HairParams) -> np.ndarray:
    """Maximum strand length (N,) from the root angles (N,): crown length blended into the
    front / side / back lengths towards the hairline."""
    wf, ws, wb = region_weights(phi)
    ring = p.l_front * wf + p.l_side * ws + p.l_back * wb
    t = smoothstep(0.35, 1.3, theta)
    return p.l_top * (1.0 - t) + ring * t


def cut_level(points: np.ndarray, p: HairParams) -> np.ndarray:
    """Cut height (...) at each point (...,3), blended by the point's azimuth."""
    wf, ws, wb = region_weights(np.arctan2(points[..., 0], points[..., 2]))
    return p.cut_front * wf + p.cut_side * ws + p.cut_back * wb


def fringe_weights(theta: np.ndarray, phi: np.ndarray, hairline: np.ndarray,
                   p: HairParams) -> np.ndarray:
    """(N,) in [0,1]: how much each root belongs to the fringe (front roots near the hairline).

    Args:
        theta, phi: (N,) root angles.
        hairline: (N,) polar angle of the hairline at each root's azimuth.
    """
    if p.fringe <= 0.0:
        return np.zeros_like(theta)
    near = smoothstep(hairline - p.fringe_depth, hairline - 0.7 * p.fringe_depth, theta)
    front = 1.0 - smoothstep(0.7 * p.fringe_width, p.fringe_width, np.abs(phi))
    return np.clip(p.fringe * near * front, 0.0, 1.0)


def comb_direction(x: np.ndarray, normal: np.ndarray, p: HairParams,
                   fringe_w: np.ndarray) -> np.ndarray:
    """Combing direction at points ``x`` (N,3), tangent to the surface with unit ``normal`` (N,3).

    A blend of: radial flow away from the crown axis, sideways flow away from the parting line and
    backward flow (both on the front-top of the head), a downward pull, and for fringe strands
    (weight ``fringe_w`` (N,)) a forward-and-down flow.

    Returns:
        (N,3) unit vectors orthogonal to ``normal``.
    """
    n_ = len(x)
    radial = np.stack([x[:, 0], np.zeros(n_), x[:, 2] - p.crown_z], -1)
    radial /= np.maximum(np.linalg.norm(radial, axis=-1, keepdims=True), 1e-4)
    top_front = smoothstep(p.crown_z - 0.01, p.crown_z + 0.04, x[:, 2]) * smoothstep(-0.01, 0.04, x[:, 1])
    side = np.tanh((x[:, 0] - p.part_x) / 0.006)
    fw = fringe_w[:, None]
    c = p.radial_weight * radial * (1.0 - 0.5 * fw)
    c = c + (1.0 - fw) * top_front[:, None] * (
        p.part_weight * side[:, None] * np.array([1.0, 0.0, 0.0])
        + p.back_weight * np.array([0.0, 0.0, -1.0]))
    c = c + fw * np.array([0.0, -0.4, 1.0]) * 2.0
    c = c + p.down_weight * np.array([0.0, -1.0, 0.0])
    c = c - (c * normal).sum(-1, keepdims=True) * normal
    norm = np.linalg.norm(c, axis=-1, keepdims=True)
    fallback = np.array([0.0, -1.0, -1.0]) - (normal @ np.array([0.0, -1.0, -1.0]))[:, None] * normal
    c = np.where(norm > 1e-6, c / np.maximum(norm, 1e-12), fallback)
    return c / np.maximum(np.linalg.norm(c, axis=-1, keepdims=True), 1e-12)


def face_zone(landmarks: np.ndarray) -> FaceZone:
    """The keep-out box in front of the face from iBUG-68 landmarks (68,3)."""
    lm = np.asarray(landmarks, np.float64)
    brows, eyes = lm[17:27], lm[36:48]
    y_brow = float(brows[:, 1].mean())
    return FaceZone(y_top=y_brow, y_bottom=float(lm[8, 1]) - 0.03,
                    x_half=float(np.abs(eyes[:, 0]).max()) + 0.012,
                    z_min=float(eyes[:, 2].min()) - 0.02, y_brow=y_brow)


def in_face_zone(points: np.ndarray, zone: FaceZone) -> np.ndarray:
    """Boolean (...) mask of points (...,3) inside the face keep-out box."""
    return ((points[..., 1] < zone.y_top) & (points[..., 1] > zone.y_bottom)
            & (np.abs(points[..., 0]) < zone.x_half) & (points[..., 2] > zone.z_min))
