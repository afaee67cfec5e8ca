"""iBUG-68 facial landmarks of the proxy head.

Points are given as approximate positions on the base (unscaled) proxy head -- x to the subject's
left, y up, z forward, origin between the ears -- for the subject's right half and the midline;
the left half is mirrored. Only their directions from the head centre matter: the proxy casts
each direction onto its surface, so the landmarks lie exactly on the surface for every shape.
Index convention (iBUG): 0-16 jaw from the subject's right ear side (-x) to the left, 17-21 right
brow (outer to inner), 22-26 left brow (inner to outer), 27-30 nose bridge (top to tip), 31-35
nose base (right to left), 36-41 right eye and 42-47 left eye (6-point contours), 48-59 outer
mouth and 60-67 inner mouth.
"""

from __future__ import annotations

import numpy as np

LANDMARK_GROUPS: dict[str, list[int]] = {
    "jaw": list(range(0, 17)),
    "right_brow": list(range(17, 22)),
    "left_brow": list(range(22, 27)),
    "nose_bridge": list(range(27, 31)),
    "nose_base": list(range(31, 36)),
    "right_eye": list(range(36, 42)),
    "left_eye": list(range(42, 48)),
    "mouth_outer": list(range(48, 60)),
    "mouth_inner": list(range(60, 68)),
}

# index -> approximate (x, y, z) in metres, subject's right side (x <= 0) and midline only.
_RIGHT_AND_MID: dict[int, tuple[float, float, float]] = {
    0: (-0.070, 0.018, 0.040), 1: (-0.069, 0.000, 0.045), 2: (-0.067, -0.018, 0.050),
    3: (-0.063, -0.036, 0.056), 4: (-0.057, -0.053, 0.063), 5: (-0.048, -0.068, 0.071),
    6: (-0.037, -0.081, 0.078), 7: (-0.020, -0.092, 0.084), 8: (0.000, -0.097, 0.088),
    17: (-0.055, 0.036, 0.075), 18: (-0.045, 0.043, 0.085), 19: (-0.033, 0.046, 0.092),
    20: (-0.021, 0.045, 0.096), 21: (-0.010, 0.040, 0.098),
    27: (0.000, 0.028, 0.100), 28: (0.000, 0.015, 0.105), 29: (0.000, 0.002, 0.112),
    30: (0.000, -0.011, 0.120),
    31: (-0.015, -0.022, 0.100), 32: (-0.008, -0.025, 0.104), 33: (0.000, -0.027, 0.106),
    36: (-0.045, 0.019, 0.078), 37: (-0.037, 0.025, 0.085), 38: (-0.026, 0.025, 0.088),
    39: (-0.018, 0.019, 0.090), 40: (-0.026, 0.015, 0.088), 41: (-0.037, 0.015, 0.085),
    48: (-0.025, -0.048, 0.085), 49: (-0.016, -0.041, 0.093), 50: (-0.007, -0.038, 0.098),
    51: (0.000, -0.039, 0.099), 57: (0.000, -0.058, 0.097), 58: (-0.008, -0.057, 0.096),
    59: (-0.017, -0.054, 0.092),
    60: (-0.021, -0.048, 0.088), 61: (-0.009, -0.046, 0.096), 62: (0.000, -0.046, 0.097),
    66: (0.000, -0.049, 0.097), 67: (-0.009, -0.049, 0.096),
}

# left-side index -> its mirror image on the right side
_MIRROR: dict[int, int] = {
    **{16 - i: i for i in range(8)},
    **{26 - i: 17 + i for i in range(5)},
    34: 32, 35: 31,
    42: 39, 43: 38, 44: 37, 45: 36, 46: 41, 47: 40,
    52: 50, 53: 49, 54: 48, 55: 59, 56: 58,
    63: 61, 64: 60, 65: 67,
}


def landmark_targets() -> np.ndarray:
    """(68, 3) float64 approximate landmark positions on the base proxy head (metres)."""
    out = np.full((68, 3), np.nan)
    for i, p in _RIGHT_AND_MID.items():
        out[i] = p
    for i, j in _MIRROR.items():
        out[i] = out[j] * np.array([-1.0, 1.0, 1.0])
    assert not np.isnan(out).any()
    return out


def landmark_directions() -> np.ndarray:
    """(68, 3) float64 unit directions from the head centre towards the landmarks."""
    t = landmark_targets()
    return t / np.linalg.norm(t, axis=-1, keepdims=True)
