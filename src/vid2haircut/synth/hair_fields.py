"""Fields over the scalp for procedural hair: root sampling, combing direction, length map,
cut levels and the face keep-out zone.

Angles follow the head's scalp-UV convention: polar angle ``theta`` from +y (0 at the crown),
azimuth ``phi = atan2(x, z)`` (0 towards the face, +pi/2 towards +x).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.ndimage import map_coordinates

from .hair_params import HairParams

__all__ = ["Roots", "FaceZone", "forehead_weight", "sample_roots", "uv_to_angles", "region_weights",
           "comb_direction", "length_map", "cut_level", "face_zone", "in_face_zone",
           "fringe_weights", "hairline_angles", "smoothstep", "zone_half_width"]

_RHO_TO_THETA = 2.0 * np.pi / 3.0


class Roots(NamedTuple):
    """Sampled strand roots."""

    uv: np.ndarray       # (N,2) float32 scalp uv
    points: np.ndarray   # (N,3) float64 root points on the head surface
    normals: np.ndarray  # (N,3) float64 unit outward normals
    theta: np.ndarray    # (N,) polar angle from the crown (radians)
    phi: np.ndarray      # (N,) azimuth, 0 = face direction (radians)


class FaceZone(NamedTuple):
    """Region in front of the face that hair must not enter (head frame, metres).

    In the x-y plane it is the super-ellipse ``|x/x_half|^4 + |(y-y_mid)/y_half|^4 < 1`` spanning
    from ``y_bottom`` (below the chin) to ``y_top`` (the eyebrows); in depth, everything in front
    of ``z_min``. Its rounded top corners leave the temples free.
    """

    y_top: float     # eyebrow height: the top of the zone
    y_bottom: float  # the zone ends below the chin
    x_half: float    # largest half-width (outer eye corners plus a margin)
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
    # area Jacobian on a coarse texel grid, bilinearly interpolated at the candidates
    jres = 64
    cj = (np.arange(jres) + 0.5) / jres
    ju, jv = np.meshgrid(cj, cj, indexing="xy")                         # [row=v, col=u]
    jac_map = _area_jacobian(head, np.stack([ju, jv], -1).reshape(-1, 2)).reshape(jres, jres)
    coarse = mask.reshape(jres, mask_res // jres, jres, mask_res // jres).any(axis=(1, 3)) \
        if mask_res % jres == 0 else np.ones((jres, jres), bool)
    jmax = float(jac_map[coarse].max()) * 1.05
    accept = mask.mean() * float(jac_map[coarse].mean()) / jmax

    def jac_at(uv: np.ndarray) -> np.ndarray:
        return map_coordinates(jac_map, [uv[:, 1] * jres - 0.5, uv[:, 0] * jres - 0.5],
                               order=1, mode="nearest")

    g = int(np.ceil(np.sqrt(1.15 * n / max(accept, 1e-6)))) + 2
    for _ in range(20):
        ii, jj = np.meshgrid(np.arange(g), np.arange(g), indexing="xy")
        uv = (np.stack([ii, jj], -1).reshape(-1, 2) + rng.uniform(size=(g * g, 2))) / g
        col = np.clip((uv[:, 0] * mask_res).astype(int), 0, mask_res - 1)
        row = np.clip((uv[:, 1] * mask_res).astype(int), 0, mask_res - 1)
        uv = uv[mask[row, col]]
        keep = rng.uniform(size=len(uv)) * jmax < jac_at(uv)
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


def comb_direction(x: np.ndarray, normal: np.ndarray, p: HairParams, fringe_w: np.ndarray,
                   crown: np.ndarray) -> np.ndarray:
    """Combing direction at points ``x`` (N,3), tangent to the surface with unit ``normal`` (N,3).

    A blend of: flow away from the crown whorl (``crown`` (3,), the top of the head moved to
    ``p.crown_z``), sideways flow away from the parting line and backward flow (both on the
    front-top of the head), a downward and a slight backward pull, and for fringe strands (weight ``fringe_w`` (N,)) a
    forward-and-down flow.

    Returns:
        (N,3) unit vectors orthogonal to ``normal``.
    """
    radial = x - np.array([crown[0], crown[1], p.crown_z])
    radial /= np.maximum(np.linalg.norm(radial, axis=-1, keepdims=True), 0.03)   # fades at the whorl
    top_front = smoothstep(p.crown_z - 0.01, p.crown_z + 0.04, x[:, 2]) * smoothstep(-0.01, 0.04, x[:, 1])
    side = np.tanh((x[:, 0] - p.part_x) / 0.006)
    fw = fringe_w[:, None]
    c = p.radial_weight * radial * (1.0 - 0.5 * fw) * (1.0 - 0.8 * top_front[:, None] * (1.0 - fw))
    c = c + (1.0 - fw) * top_front[:, None] * (
        p.part_weight * side[:, None] * np.array([1.0, 0.0, 0.0])
        + p.back_weight * np.array([0.0, 0.0, -1.0]))
    c = c + fw * np.array([0.0, -0.4, 1.0]) * 2.0
    c = c + p.down_weight * np.array([0.0, -1.0, 0.0]) + 0.2 * np.array([0.0, 0.0, -1.0])
    c = c - (c * normal).sum(-1, keepdims=True) * normal
    norm = np.linalg.norm(c, axis=-1, keepdims=True)
    fallback = np.array([0.0, -1.0, -1.0]) - (normal @ np.array([0.0, -1.0, -1.0]))[:, None] * normal
    c = np.where(norm > 1e-6, c / np.maximum(norm, 1e-12), fallback)
    return c / np.maximum(np.linalg.norm(c, axis=-1, keepdims=True), 1e-12)


def forehead_weight(x: np.ndarray, zone: FaceZone) -> np.ndarray:
    """(N,) in [0,1]: 1 for points (N,3) above the face (in front, between the temples, above
    the eyebrows), where non-fringe hair must keep following its combing direction."""
    return (smoothstep(zone.z_min - 0.03, zone.z_min, x[:, 2])
            * (1.0 - smoothstep(zone.x_half, zone.x_half + 0.02, np.abs(x[:, 0])))
            * smoothstep(zone.y_top - 0.01, zone.y_top + 0.01, x[:, 1]))


def face_zone(landmarks: np.ndarray) -> FaceZone:
    """The keep-out box in front of the face from iBUG-68 landmarks (68,3)."""
    lm = np.asarray(landmarks, np.float64)
    brows, eyes = lm[17:27], lm[36:48]
    y_brow = float(brows[:, 1].mean())
    return FaceZone(y_top=y_brow, y_bottom=float(lm[8, 1]) - 0.03,
                    x_half=float(np.abs(eyes[:, 0]).max()) + 0.014,
                    z_min=float(eyes[:, 2].min()) - 0.04, y_brow=y_brow)


def zone_half_width(y: np.ndarray, zone: FaceZone) -> np.ndarray:
    """Half-width (...) of the face zone at heights ``y`` (...); 0 above / below it."""
    mid, half = 0.5 * (zone.y_top + zone.y_bottom), 0.5 * (zone.y_top - zone.y_bottom)
    r = np.clip(1.0 - ((np.asarray(y, np.float64) - mid) / half) ** 4, 0.0, None)
    return zone.x_half * r ** 0.25


def in_face_zone(points: np.ndarray, zone: FaceZone) -> np.ndarray:
    """Boolean (...) mask of points (...,3) inside the face keep-out zone."""
    pts = np.asarray(points)
    cand = ((pts[..., 2] > zone.z_min) & (np.abs(pts[..., 0]) < zone.x_half)
            & (pts[..., 1] < zone.y_top) & (pts[..., 1] > zone.y_bottom))
    sel = pts[cand]
    cand[cand] = np.abs(sel[:, 0]) < zone_half_width(sel[:, 1], zone)
    return cand
