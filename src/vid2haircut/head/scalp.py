"""Scalp UV parametrisation (polar top view centred on the crown) and the hair-bearing mask.

Convention (shared by every head model): a direction from the head centre with polar angle
``theta`` from +y and azimuth ``phi = atan2(x, z)`` maps to ``rho = theta / (2 pi / 3)``,
``u = 0.5 + 0.5 rho sin(phi)``, ``v = 0.5 + 0.5 rho cos(phi)``: u grows towards +x, v towards the
face (+z), (0.5, 0.5) is the crown and the disk rho <= 1 reaches 120 degrees from the crown.
"""

from __future__ import annotations

import numpy as np

from vid2haircut.head.radial import angles_from_dirs, dirs_from_angles

THETA_MAX = 2.0 * np.pi / 3.0  # polar angle of the UV disk's rim (rho = 1)

# Ears (polar angle, |azimuth|, half-extent in polar angle, half-extent in azimuth), degrees:
# the proxy's ears are kept out of the hair-bearing region.
PROXY_EARS_DEG = (92.0, 98.0, 22.0, 14.0)


def uv_to_angles(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., 2) uv -> (theta, phi), each (...,) radians."""
    uv = np.asarray(uv, dtype=np.float64)
    du, dv = uv[..., 0] - 0.5, uv[..., 1] - 0.5
    rho = 2.0 * np.hypot(du, dv)
    return np.clip(rho * THETA_MAX, 0.0, np.pi), np.arctan2(du, dv)


def uv_to_dirs(uv: np.ndarray) -> np.ndarray:
    """(..., 2) uv -> (..., 3) unit directions from the head centre."""
    return dirs_from_angles(*uv_to_angles(uv))


def dirs_to_uv(dirs: np.ndarray) -> np.ndarray:
    """(..., 3) directions from the head centre -> (..., 2) uv (outside [0,1]^2 below ~150 deg)."""
    theta, phi = angles_from_dirs(dirs)
    rho = theta / THETA_MAX
    return np.stack([0.5 + 0.5 * rho * np.sin(phi), 0.5 + 0.5 * rho * np.cos(phi)], axis=-1)


def hairline_theta(phi: np.ndarray) -> np.ndarray:
    """Polar angle (radians) of the hairline at azimuth phi: 62 deg at the forehead, 95 deg above
    the ears, 112 deg at the nape, smooth in between (a short cosine series)."""
    phi = np.asarray(phi, dtype=np.float64)
    return np.radians(91.0 - 25.0 * np.cos(phi) - 4.0 * np.cos(2.0 * phi))


def scalp_mask_angles(theta: np.ndarray, phi: np.ndarray,
                      ears_deg: tuple[float, float, float, float] | None = None) -> np.ndarray:
    """Hair-bearing test of directions: (...) theta, phi -> (...) bool.

    True above the hairline and inside the UV disk, optionally excluding two elliptic ear
    regions ``(theta0, |phi0|, half_theta, half_phi)`` in degrees.
    """
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    mask = (theta <= hairline_theta(phi)) & (theta <= THETA_MAX)
    if ears_deg is not None:
        t0, p0, ht, hp = ears_deg
        et = (np.degrees(theta) - t0) / ht
        ep = (np.abs(np.degrees(phi)) - p0) / hp
        mask &= et * et + ep * ep > 1.0
    return mask


def texel_uv(res: int) -> np.ndarray:
    """(res, res, 2) uv of texel centres; index [row=v, col=u], value (u, v)."""
    c = (np.arange(res) + 0.5) / res
    vv, uu = np.meshgrid(c, c, indexing="ij")
    return np.stack([uu, vv], axis=-1)


def scalp_mask(res: int, ears_deg: tuple[float, float, float, float] | None = None) -> np.ndarray:
    """(res, res) bool hair-bearing mask of texel centres (index [row=v, col=u])."""
    if res < 1:
        raise ValueError(f"scalp mask resolution must be positive, got {res}")
    return scalp_mask_angles(*uv_to_angles(texel_uv(res)), ears_deg=ears_deg)
