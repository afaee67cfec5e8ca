"""Strand shape details on top of the grown centrelines: clumps, curls / waves and frizz.

All operations are vectorised over strands (loops run over points only) and take their randomness
from an explicit generator.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from .hair_fields import smoothstep
from .hair_params import HairParams

__all__ = ["Clumps", "assign_clumps", "apply_clumps", "strand_frames", "apply_curl", "apply_frizz",
           "arc_lengths"]


class Clumps(NamedTuple):
    """Clump assignment of strands."""

    centre: np.ndarray  # (N,) int index of each strand's clump-centre strand
    label: np.ndarray   # (N,) int clump id in [0, K)
    count: int          # K clumps


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def arc_lengths(points: np.ndarray) -> np.ndarray:
    """(N,P) cumulative arc length along strands (N,P,3), 0 at the root."""
    seg = np.linalg.norm(np.diff(points, axis=1), axis=-1)
    return np.concatenate([np.zeros((len(points), 1)), np.cumsum(seg, axis=1)], axis=1)


def assign_clumps(roots: np.ndarray, strands_per_clump: float, rng: np.random.Generator) -> Clumps:
    """Pick ~N/strands_per_clump random centre strands; every strand joins the clump of the
    centre root nearest to its own root (roots (N,3))."""
    n = len(roots)
    k = int(np.clip(round(n / max(strands_per_clump, 1.0)), 1, n))
    centres = np.sort(rng.choice(n, k, replace=False))
    _, label = cKDTree(roots[centres]).query(roots)
    return Clumps(centres[label], np.asarray(label), k)


def apply_clumps(points: np.ndarray, clumps: Clumps, strength: float, power: float,
                 rng: np.random.Generator) -> np.ndarray:
    """Pull strands (N,P,3) towards their clump centre strand, point by point (same index),
    with weight ``strength * u**power`` (u = 0 at the root, 1 at the tip; per-strand strength
    jitter 70-100 %). Returns the new (N,P,3) points."""
    n, p, _ = points.shape
    s = strength * rng.uniform(0.7, 1.0, n)
    w = s[:, None] * np.linspace(0.0, 1.0, p)[None] ** power                # (N,P)
    return points + w[..., None] * (points[clumps.centre] - points)


def strand_frames(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smooth orthonormal frames along strands (N,P,3).

    The first normal is horizontal-lateral at the root (perpendicular to the tangent and to the
    outward horizontal direction from the head axis), then carried along by projection (a
    discrete parallel transport).

    Returns:
        (tangent, normal, binormal), each (N,P,3) unit vectors.
    """
    d = np.diff(points, axis=1)
    t = _unit(np.concatenate([d[:, :1], 0.5 * (d[:, 1:] + d[:, :-1]), d[:, -1:]], axis=1))
    out = points[:, 0] * np.array([1.0, 0.0, 1.0])
    out = np.where(np.linalg.norm(out, axis=-1, keepdims=True) > 1e-6, out, np.array([0.0, 0.0, -1.0]))
    b = np.cross(t[:, 0], out)
    bad = np.linalg.norm(b, axis=-1) < 1e-6 * np.linalg.norm(out, axis=-1)
    b[bad] = np.cross(t[bad, 0], np.array([1.0, 0.0, 0.0]))
    b = _unit(b)
    normal = np.empty_like(t)
    normal[:, 0] = b
    for k in range(1, t.shape[1]):
        prev = normal[:, k - 1]
        cand = prev - (prev * t[:, k]).sum(-1, keepdims=True) * t[:, k]
        ok = np.linalg.norm(cand, axis=-1, keepdims=True) > 1e-9
        normal[:, k] = np.where(ok, _unit(cand), prev)
    return t, normal, np.cross(t, normal)


def apply_curl(points: np.ndarray, p: HairParams, clumps: Clumps,
               rng: np.random.Generator) -> np.ndarray:
    """Displace strands (N,P,3) into waves or helical curls around their centrelines.

    Wave: ``A(s) sin(w s + phase)`` along the frame normal; helix: ``A(s) (cos, sin)`` in the
    normal plane; ``A`` ramps in over ``p.curl_start`` from the root. Period and phase are shared
    per clump (plus ``p.curl_phase_jitter``) so clumps curl together.

    Returns:
        (N,P,3) displaced points (unchanged when ``p.curl == "none"``).
    """
    if p.curl not in ("none", "wave", "helix"):
        raise ValueError(f"unknown curl type {p.curl!r}; expected none, wave or helix")
    n = len(points)
    k = clumps.count
    clump_phase = rng.uniform(0.0, 2.0 * np.pi, k)
    clump_period = p.curl_period * np.exp(rng.normal(0.0, 0.1, k))
    phase = clump_phase[clumps.label] + rng.normal(0.0, p.curl_phase_jitter, n)
    amp = p.curl_amp * np.exp(rng.normal(0.0, 0.12, n))
    if p.curl == "none" or p.curl_amp <= 0.0:
        return points
    s = arc_lengths(points)                                                 # (N,P)
    a = amp[:, None] * smoothstep(0.0, p.curl_start, s)
    ang = 2.0 * np.pi * s / clump_period[clumps.label][:, None] + phase[:, None]
    _, nrm, bin_ = strand_frames(points)
    if p.curl == "wave":
        off = (a * np.sin(ang))[..., None] * nrm
    else:
        off = (a * np.cos(ang))[..., None] * nrm + (a * np.sin(ang))[..., None] * bin_
    return points + off


def apply_frizz(points: np.ndarray, p: HairParams, rng: np.random.Generator) -> np.ndarray:
    """Add smooth per-strand noise (three random sinusoids in random directions), growing as
    ``u**1.5`` from root (u=0) to tip (u=1) up to ``p.frizz_amp``. Returns (N,P,3)."""
    n, npts, _ = points.shape
    dirs = _unit(rng.normal(size=(n, 3, 3)))
    lam = p.frizz_period * rng.uniform(0.5, 1.5, (n, 3))
    ph = rng.uniform(0.0, 2.0 * np.pi, (n, 3))
    wgt = rng.uniform(0.3, 1.0, (n, 3))
    amp = p.frizz_amp * np.exp(rng.normal(0.0, 0.5, n))                   # a few flyaways
    if p.frizz_amp <= 0.0:
        return points
    s = arc_lengths(points)
    u = np.linspace(0.0, 1.0, npts)[None] ** 1.5                           # (1,P)
    wave = wgt[:, None, :] * np.sin(2.0 * np.pi * s[..., None] / lam[:, None, :] + ph[:, None, :])
    off = np.einsum("npj,njc->npc", wave, dirs) / 1.5
    return points + (amp[:, None] * u)[..., None] * off
