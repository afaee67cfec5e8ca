"""Star-shaped head surface: a radial function r(direction) around the head centre (the origin).

The proxy head is the smooth union (log-sum-exp maximum of radii) of three solids that all contain
the origin -- a cranium (an ellipsoid with separate upper/lower heights), a lower-face ellipsoid
and a neck (a rounded elliptic cylinder) -- plus smooth bumps in direction space (nose, brows,
cheekbones, lips, chin, ears; eye sockets are negative bumps). Every ray from the origin meets the
surface exactly once at ``r(d) * d``, which makes the surface, the inside test and the scalp root
casting exact and cheap.

Angles: polar angle ``theta`` from +y, azimuth ``phi = atan2(x, z)``; bumps are placed by
elevation ``el = 90 deg - theta`` and azimuth (degrees), which is well conditioned on the face.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Smooth-union sharpness (1/m): fillet radius about 1/k.
_UNION_K = 250.0
_NECK_K = 250.0

# (elevation deg, azimuth deg, sigma_el deg, sigma_az deg, amplitude m); mirrored ones listed once
# with positive azimuth and flagged by the last field.
_BUMPS: tuple[tuple[float, float, float, float, float, bool], ...] = (
    (17.0, 19.0, 5.0, 11.0, 0.0055, True),     # brow ridges
    (16.0, 0.0, 6.0, 8.0, 0.0035, False),      # glabella
    (10.5, 21.0, 4.5, 7.0, -0.0055, True),     # eye sockets
    (12.0, 0.0, 5.0, 3.5, 0.0050, False),      # nose bridge
    (3.0, 0.0, 5.0, 4.5, 0.0130, False),       # nose dorsum
    (-5.0, 0.0, 4.5, 6.5, 0.0230, False),      # nose tip
    (-8.5, 7.0, 3.0, 3.5, 0.0080, True),       # nose wings (alae)
    (1.0, 38.0, 9.0, 12.0, 0.0060, True),      # cheekbones
    (-21.0, 0.0, 3.5, 13.0, 0.0050, False),    # upper lip
    (-30.0, 0.0, 3.5, 11.0, 0.0045, False),    # lower lip
    (-51.0, 0.0, 9.0, 16.0, 0.0140, False),    # chin
    (-2.0, 98.0, 11.0, 6.5, 0.0150, True),     # ears
)


@dataclass(frozen=True)
class RadialShape:
    """Shape parameters of the proxy head; each a multiplicative factor, 1 = default.

    Fields:
        scale: overall size.
        width: extra scale along x (ear to ear).
        depth: extra scale along z (back of head to face).
        crown: height of the cranium top above its centre.
    """

    scale: float = 1.0
    width: float = 1.0
    depth: float = 1.0
    crown: float = 1.0

    def __post_init__(self) -> None:
        for name in ("scale", "width", "depth", "crown"):
            v = getattr(self, name)
            if not (np.isfinite(v) and 0.5 <= v <= 2.0):
                raise ValueError(f"head shape parameter {name}={v} must lie in [0.5, 2]")

    @property
    def axes(self) -> np.ndarray:
        """(3,) diagonal of the linear map from the base shape to this shape."""
        return np.array([self.scale * self.width, self.scale, self.scale * self.depth])

    # ----------------------------------------------------------------------------------------
    def radius(self, dirs: np.ndarray) -> np.ndarray:
        """Radial function of this shape: (..., 3) unit directions -> (...,) radius in metres."""
        d = np.asarray(dirs, dtype=np.float64)
        q = d / self.axes
        qn = np.linalg.norm(q, axis=-1)
        return base_radius(q / qn[..., None], self.crown) / qn

    def surface_points(self, dirs: np.ndarray) -> np.ndarray:
        """(..., 3) unit directions -> (..., 3) points on the surface."""
        d = np.asarray(dirs, dtype=np.float64)
        return d * self.radius(d)[..., None]

    def implicit(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) points -> (...,) ``|p| - r(p/|p|)``: negative inside, zero on the surface."""
        p = np.asarray(points, dtype=np.float64)
        n = np.linalg.norm(p, axis=-1)
        safe = np.where(n > 1e-12, n, 1.0)
        d = p / safe[..., None]
        d = np.where((n > 1e-12)[..., None], d, np.array([0.0, 1.0, 0.0]))
        return n - self.radius(d)

    def normals(self, dirs: np.ndarray, h: float = 1e-5) -> np.ndarray:
        """(..., 3) unit directions -> (..., 3) unit outward normals at the surface points.

        Central finite differences of :meth:`implicit` (its gradient is along the normal).
        """
        p = self.surface_points(dirs)
        grad = np.zeros_like(p)
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            grad[..., k] = (self.implicit(p + e) - self.implicit(p - e)) / (2 * h)
        return grad / np.linalg.norm(grad, axis=-1, keepdims=True)


def dirs_from_angles(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Polar angle from +y and azimuth atan2(x, z) (radians, broadcast) -> (..., 3) unit dirs."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, np.float64), np.asarray(phi, np.float64))
    st = np.sin(theta)
    return np.stack([st * np.sin(phi), np.cos(theta), st * np.cos(phi)], axis=-1)


def angles_from_dirs(dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., 3) directions -> (theta, phi) in radians (see :func:`dirs_from_angles`)."""
    d = np.asarray(dirs, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return np.arccos(np.clip(d[..., 1], -1.0, 1.0)), np.arctan2(d[..., 0], d[..., 2])


# ------------------------------------------------------------------------------------------------
def _ray_ellipsoid(d: np.ndarray, centre: np.ndarray, semi: np.ndarray) -> np.ndarray:
    """Exit distance of rays origin + t d from an ellipsoid containing the origin. (...,3)->(...)."""
    a = d / semi
    o = -centre / semi
    qa = np.sum(a * a, axis=-1)
    qb = 2.0 * np.sum(a * o, axis=-1)
    qc = np.sum(o * o) - 1.0
    return (-qb + np.sqrt(qb * qb - 4.0 * qa * qc)) / (2.0 * qa)


def _cranium(d: np.ndarray, crown: float) -> np.ndarray:
    centre = np.array([0.0, 0.012, -0.012])
    up = _ray_ellipsoid(d, centre, np.array([0.077, 0.098 * crown, 0.099]))
    down = _ray_ellipsoid(d, centre, np.array([0.077, 0.090, 0.099]))
    y_up = up * d[..., 1]
    return np.where(y_up >= centre[1], up, down)


def _face(d: np.ndarray) -> np.ndarray:
    return _ray_ellipsoid(d, np.array([0.0, -0.035, 0.012]), np.array([0.062, 0.072, 0.080]))


def _neck(d: np.ndarray) -> np.ndarray:
    """Rounded elliptic cylinder (axis along y through x=0, z=-0.015), y in [-0.14, 0.03]."""
    cz, rx, rz, y_bot, y_top = -0.015, 0.056, 0.052, -0.14, 0.03
    a = (d[..., 0] / rx) ** 2 + (d[..., 2] / rz) ** 2
    b = -2.0 * d[..., 2] * cz / rz**2
    c = (cz / rz) ** 2 - 1.0
    safe_a = np.maximum(a, 1e-12)
    t_cyl = np.where(a > 1e-12, (-b + np.sqrt(b * b - 4 * safe_a * c)) / (2 * safe_a), 10.0)
    dy = d[..., 1]
    t_bot = np.where(dy < -1e-9, y_bot / np.minimum(dy, -1e-9), 10.0)
    t_top = np.where(dy > 1e-9, y_top / np.maximum(dy, 1e-9), 10.0)
    ts = np.stack([t_cyl, t_bot, t_top], axis=0)
    m = ts.min(axis=0)
    return m - np.log(np.exp(-_NECK_K * (ts - m)).sum(axis=0)) / _NECK_K


def _bumps(d: np.ndarray) -> np.ndarray:
    el = np.degrees(np.arcsin(np.clip(d[..., 1], -1.0, 1.0)))
    az = np.degrees(np.arctan2(d[..., 0], d[..., 2]))
    out = np.zeros(d.shape[:-1])
    for el0, az0, s_el, s_az, amp, mirrored in _BUMPS:
        for sign in ((1.0, -1.0) if mirrored else (1.0,)):
            daz = (az - sign * az0 + 180.0) % 360.0 - 180.0
            out += amp * np.exp(-0.5 * ((el - el0) / s_el) ** 2 - 0.5 * (daz / s_az) ** 2)
    return out


def base_radius(dirs: np.ndarray, crown: float = 1.0) -> np.ndarray:
    """Radial function of the unscaled proxy head: (..., 3) unit directions -> (...,) metres."""
    d = np.asarray(dirs, dtype=np.float64)
    rs = np.stack([_cranium(d, crown), _face(d), _neck(d)], axis=0)
    m = rs.max(axis=0)
    r = m + np.log(np.exp(_UNION_K * (rs - m)).sum(axis=0)) / _UNION_K
    return r + _bumps(d)
