"""Head trajectory and hair sway of the synthetic head-motion sequences.

The head turns frontal -> +yaw -> -yaw -> frontal with a little downward pitch at the sides,
rotating about a neck pivot below the head centre. Hair lags the rotation: every strand point
is offset by ``-gain * w(s) * (omega_lagged x (p - root))`` in the head's canonical frame, where
``omega_lagged`` is the body-frame angular velocity of the head, delayed by ``sway_lag`` and
Gaussian-smoothed in time, and ``w(s) = s^2`` with ``s`` the arc-length fraction along the strand
(0 at the root). The offset is soft-clamped (``m * tanh(|d| / m)``) to ``sway_max_m`` and then
pushed out of the head SDF. Everything is a pure function of :class:`MotionParams` (stored in
``ground_truth/meta.json`` under ``"motion"``), so each frame's moved strands are reproducible.

Time is measured in "sequence units": ``s = t / (n_frames - 1)`` runs from 0 to 1, so the
motion (and the sway amplitude) does not depend on the frame count.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import NamedTuple

import numpy as np

from vid2haircut.geometry import axis_angle_to_matrix, make_transform, matrix_to_axis_angle


@dataclass(frozen=True)
class MotionParams:
    """Parameters of the head trajectory and the hair sway (all stored in meta.json)."""

    n_frames: int = 48
    """Number of frames; frame t is at sequence time s = t / (n_frames - 1)."""
    yaw_max_deg: float = 60.0
    """Peak yaw (turn about the vertical axis), reached at s = 0.25 (+) and s = 0.75 (-)."""
    pitch_max_deg: float = 15.0
    """Peak downward pitch (nod), reached at the two yaw extremes; 0 at the frontal frames."""
    pivot: tuple[float, float, float] = (0.0, -0.09, -0.02)
    """Rotation centre (neck) in the head's canonical frame, metres."""
    sway_max_m: float = 0.015
    """Soft bound of the per-point hair offset, metres."""
    sway_gain: float = 0.012
    """Offset per (rad per sequence unit) per metre of root-to-point lever."""
    sway_lag: float = 0.06
    """Delay of the hair behind the head rotation, sequence units (~3 frames of 48)."""
    sway_smooth: float = 0.03
    """Gaussian smoothing (sigma) of the lagged angular velocity, sequence units."""

    def to_dict(self) -> dict:
        d = asdict(self)
        d["pivot"] = list(self.pivot)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "MotionParams":
        names = {f.name for f in fields(cls)}
        kw = {k: v for k, v in d.items() if k in names}
        if "pivot" in kw:
            kw["pivot"] = tuple(float(x) for x in kw["pivot"])
        return cls(**kw)


def _ease(s: np.ndarray) -> np.ndarray:
    """Smoothstep of s clamped to [0, 1] (zero velocity at both ends)."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def head_angles(params: MotionParams, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sequence time s (...,) -> (yaw (...,), pitch (...,)) in radians."""
    e = _ease(np.asarray(s, dtype=np.float64))
    wave = np.sin(2.0 * np.pi * e)
    yaw = np.radians(params.yaw_max_deg) * wave
    pitch = np.radians(params.pitch_max_deg) * wave**2
    return yaw, pitch


def head_rotation(params: MotionParams, s: np.ndarray) -> np.ndarray:
    """(...,) sequence times -> (..., 3, 3) world_from_head rotations R_y(yaw) @ R_x(pitch)."""
    yaw, pitch = head_angles(params, s)
    ry = axis_angle_to_matrix(np.stack([np.zeros_like(yaw), yaw, np.zeros_like(yaw)], -1))
    rx = axis_angle_to_matrix(np.stack([pitch, np.zeros_like(pitch), np.zeros_like(pitch)], -1))
    return ry @ rx


def frame_time(params: MotionParams, t: int | np.ndarray) -> np.ndarray:
    """Frame index -> sequence time in [0, 1]."""
    return np.asarray(t, dtype=np.float64) / max(params.n_frames - 1, 1)


def world_from_head(params: MotionParams, t: int | np.ndarray) -> np.ndarray:
    """Frame index (or indices (T,)) -> (4, 4) (or (T, 4, 4)) world_from_head rigid transforms.

    The world frame is the head's canonical frame at rest; the head rotates about ``pivot``.
    """
    rot = head_rotation(params, frame_time(params, t))
    piv = np.asarray(params.pivot, dtype=np.float64)
    trans = piv - rot @ piv
    return make_transform(rot, trans)


def angular_velocity(params: MotionParams, s: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """Body-frame angular velocity of the head, (...,) times -> (..., 3) rad per sequence unit."""
    s = np.asarray(s, dtype=np.float64)
    r0, r1 = head_rotation(params, s - h), head_rotation(params, s + h)
    return matrix_to_axis_angle(np.swapaxes(r0, -1, -2) @ r1) / (2.0 * h)


def lagged_angular_velocity(params: MotionParams, t: int) -> np.ndarray:
    """(3,) angular velocity felt by the hair at frame t: delayed by sway_lag, Gaussian-smoothed."""
    x = np.linspace(-2.5, 2.5, 11)
    w = np.exp(-0.5 * x**2)
    w /= w.sum()
    s = frame_time(params, t) - params.sway_lag + params.sway_smooth * x
    return (w[:, None] * angular_velocity(params, s)).sum(0)


def arc_fraction(points: np.ndarray) -> np.ndarray:
    """(N, P, 3) strands -> (N, P) arc-length fraction (0 at the root, 1 at the tip)."""
    seg = np.linalg.norm(np.diff(points, axis=1), axis=-1)
    cum = np.concatenate([np.zeros((points.shape[0], 1)), np.cumsum(seg, axis=1)], axis=1)
    return cum / np.maximum(cum[:, -1:], 1e-12)


def _sdf_gradient(head, p: np.ndarray, eps: float = 5e-4) -> np.ndarray:
    """(K, 3) -> (K, 3) unit SDF gradients by central differences of ``head.sdf_np``."""
    off = np.eye(3) * eps
    q = np.concatenate([p[:, None] + off, p[:, None] - off], axis=1)  # (K, 6, 3)
    d = np.asarray(head.sdf_np(q.astype(np.float32)), dtype=np.float64)
    g = d[:, :3] - d[:, 3:]
    return g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-12)


def _push_out(head, rest: np.ndarray, moved: np.ndarray, mag: np.ndarray, bound: float, margin: float,
              rest_sdf: np.ndarray | None) -> np.ndarray:
    """Push moved points that ended inside the head back out, re-impose the offset bound.

    Only points whose rest SDF is below their offset (+2 mm slack for the grid interpolation)
    can have entered the head (the SDF is 1-Lipschitz), so only those are evaluated.
    Points still inside after three Newton-like steps fall back to their rest position.
    """
    if rest_sdf is None:
        rest_sdf = head.sdf_np(rest.astype(np.float32))
    rest_flat = rest.reshape(-1, 3)
    flat = moved.reshape(-1, 3).copy()
    idx = np.flatnonzero((mag > 1e-9) & (np.asarray(rest_sdf, np.float64).reshape(-1) < mag + 2e-3))
    if idx.size == 0:
        return moved
    sdf = np.asarray(head.sdf_np(flat[idx].astype(np.float32)), dtype=np.float64)
    inside = sdf < 0.0
    for _ in range(3):
        if not inside.any():
            break
        k = idx[inside]
        flat[k] += (margin - sdf[inside])[:, None] * _sdf_gradient(head, flat[k])
        sdf[inside] = np.asarray(head.sdf_np(flat[k].astype(np.float32)), dtype=np.float64)
        inside = sdf < 0.0
    off = flat[idx] - rest_flat[idx]
    n = np.linalg.norm(off, axis=-1, keepdims=True)
    flat[idx] = rest_flat[idx] + off * np.minimum(1.0, bound / np.maximum(n, 1e-12))
    still = np.asarray(head.sdf_np(flat[idx].astype(np.float32))) < 0.0
    flat[idx[still]] = rest_flat[idx[still]]
    return flat.reshape(rest.shape)


class SwayBasis(NamedTuple):
    """Frame-independent parts of the sway of one rest hairstyle (see :func:`sway_basis`).

    rest: (N, P, 3) float32 rest points; lever: (N, P, 3) float32 ``rest - root``;
    weight: (N, P) float32 ``arc_fraction ** 2``; rest_sdf: (N, P) float32 head SDF or None.
    """

    rest: np.ndarray
    lever: np.ndarray
    weight: np.ndarray
    rest_sdf: np.ndarray | None


def sway_basis(rest: np.ndarray, head=None) -> SwayBasis:
    """Precompute the frame-independent sway terms of (N, P, 3) rest strands (SDF only with a head)."""
    rest = np.ascontiguousarray(rest, dtype=np.float32)
    lever = rest - rest[:, :1]
    weight = (arc_fraction(rest.astype(np.float64)) ** 2).astype(np.float32)
    sdf = None if head is None else np.asarray(head.sdf_np(rest), np.float32).reshape(rest.shape[:2])
    return SwayBasis(rest, lever, weight, sdf)


def sway_points(rest: np.ndarray | SwayBasis, params: MotionParams, t: int, head=None,
                margin: float = 2e-4) -> np.ndarray:
    """Moved strands at frame t in the canonical frame.

    Args:
        rest: (N, P, 3) rest strands (root first), canonical head frame, metres, or their
            :class:`SwayBasis` (same result, faster when called for many frames).
        params: the motion record.
        t: frame index.
        head: a head model with ``sdf_np``; when given, moved points are pushed out of the head.
        margin: SDF (metres) a point found inside the head is pushed out to.
    Returns:
        (N, P, 3) float32 points; roots unchanged, ``|moved - rest| <= sway_max_m``.
    """
    basis = rest if isinstance(rest, SwayBasis) else sway_basis(rest, head)
    if head is not None and basis.rest_sdf is None:
        basis = sway_basis(basis.rest, head)
    o = lagged_angular_velocity(params, t).astype(np.float32)
    lx, ly, lz = basis.lever[..., 0], basis.lever[..., 1], basis.lever[..., 2]
    g = np.float32(-params.sway_gain) * basis.weight
    d = np.stack([(o[1] * lz - o[2] * ly) * g, (o[2] * lx - o[0] * lz) * g, (o[0] * ly - o[1] * lx) * g], -1)
    m = np.float32(params.sway_max_m)
    mag = np.sqrt((d * d).sum(-1))
    eff = m * np.tanh(mag / m)
    d *= (eff / np.maximum(mag, np.float32(1e-12)))[..., None]
    moved = basis.rest + d
    if head is not None:
        moved = _push_out(head, basis.rest, moved, eff.reshape(-1), float(m), margin, basis.rest_sdf)
    return moved.astype(np.float32)


def moved_strands(rest, meta: dict, t: int, head=None, rest_sdf: np.ndarray | None = None) -> np.ndarray:
    """Reproduce the moved hair of frame t from a sequence's meta record.

    Args:
        rest: a StrandSet (or (N, P, 3) array) of the rest hairstyle, canonical frame.
        meta: ``ground_truth/meta.json`` as a dict (uses ``meta["motion"]``).
        t: frame index.
        head: the head model of the sequence (for the SDF push-out); None skips it.
        rest_sdf: optional (N, P) SDF of the rest points (speed only; same result).
    Returns:
        (N, P, 3) float32 canonical-frame points at frame t.
    """
    points = getattr(rest, "points", rest)
    if "motion" not in meta:
        raise ValueError("meta record has no 'motion' entry (not written by the synthesiser?)")
    basis = sway_basis(np.asarray(points), None)
    if head is not None:
        basis = basis._replace(rest_sdf=np.asarray(head.sdf_np(basis.rest), np.float32) if rest_sdf is None
                               else np.asarray(rest_sdf, np.float32).reshape(basis.weight.shape))
    return sway_points(basis, MotionParams.from_dict(meta["motion"]), t, head)
