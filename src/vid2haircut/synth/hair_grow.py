"""Growing strand centrelines from the scalp: combing, gravity, hugging the head, cutting.

Strands are integrated as polylines of ``n_steps`` equal segments, all strands at once: the
direction starts between the root normal and the combing direction, bends towards the combing
field (decaying with arc length) and towards gravity, and near the head it is kept at a small,
growing distance from the surface (so hair lies on the head in layers and then falls). Strands are
then cut where they first fall below the style's cut level (or enter the face zone) and sampled
uniformly by arc length.
"""

from __future__ import annotations

import numpy as np

from .hair_fields import (FaceZone, comb_direction, cut_level, forehead_weight, in_face_zone,
                          zone_half_width)
from .hair_params import HairParams
from .hair_sdf import HeadSDF

__all__ = ["grow_centrelines", "cut_and_sample", "sample_prefix", "truncate_at_face"]

_DOWN = np.array([0.0, -1.0, 0.0])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def grow_centrelines(sdf: HeadSDF, roots: np.ndarray, normals: np.ndarray, lengths: np.ndarray,
                     fringe_w: np.ndarray, p: HairParams, zone: FaceZone, crown: np.ndarray,
                     n_steps: int = 100) -> np.ndarray:
    """Integrate strand centrelines from the roots.

    Args:
        sdf: signed distance of the head.
        roots: (N,3) root points (just outside the surface).
        normals: (N,3) unit root normals.
        lengths: (N,) strand length to grow.
        fringe_w: (N,) fringe membership in [0,1]; fringe strands are not deflected by the face
            zone (they are cut above it instead).
        p: style parameters.
        zone: face keep-out box.
        crown: (3,) top of the head (the combing field's centre, see ``comb_direction``).
        n_steps: S segments per strand.

    Returns:
        (N,S+1,3) float64 polylines with S equal segments of length ``lengths / S``.
    """
    n = len(roots)
    seg = (np.asarray(lengths, np.float64) / n_steps)[:, None]              # (N,1)
    x = np.asarray(roots, np.float64).copy()
    nrm = np.asarray(normals, np.float64)
    t = _unit(p.lift * nrm + comb_direction(x, nrm, p, fringe_w, crown))
    out = np.empty((n, n_steps + 1, 3))
    out[:, 0] = x
    deflect = (fringe_w < 0.5)
    for k in range(1, n_steps + 1):
        s = (k - 1) * seg                                                   # (N,1)
        d, g = sdf.value_and_grad(x)
        c = comb_direction(x, g, p, fringe_w, crown)
        # the combing pull decays with arc length, except above the face (non-fringe strands)
        kc = p.comb_strength * (np.exp(-s / p.comb_decay)
                                + 3.0 * (forehead_weight(x, zone) * deflect)[:, None])
        t = t + seg * kc * (c - (c * t).sum(-1, keepdims=True) * t)
        t = t + seg * p.gravity * (_DOWN - (t @ _DOWN)[:, None] * t)
        t = _unit(t)
        # keep the strand at distance h(s) from the head while it lies on it
        h = np.minimum(p.offset0 + p.volume * s[:, 0], p.max_offset)
        scale = np.clip(3.0 * h, 0.002, 0.01)
        want = np.clip((h - d) / scale, 0.0, 0.7)                          # desired d-rate
        tn = (t * g).sum(-1)
        fix = (d < h + 0.002) & (tn < want)
        t = np.where(fix[:, None], _unit(t + (want - tn)[:, None] * g), t)
        x = x + seg * t
        # deflect non-fringe strands sideways out of the face zone
        inside = in_face_zone(x, zone) & deflect
        if inside.any():
            sgn = np.where(x[inside, 0] >= 0.0, 1.0, -1.0)
            x[inside, 0] = sgn * (zone_half_width(x[inside, 1], zone) + 1e-4)
            ti = t[inside]
            ti[:, 0] = sgn * np.maximum(sgn * ti[:, 0], 0.3)
            t[inside] = _unit(ti)
        out[:, k] = x
    return out


def cut_and_sample(poly: np.ndarray, p: HairParams, zone: FaceZone, fringe_w: np.ndarray,
                   cut_offset: np.ndarray, n_points: int, min_length: float = 0.002) -> np.ndarray:
    """Cut grown polylines at the style's cut level and sample them uniformly.

    A strand is cut where it first falls below its cut height (the style's azimuth-blended cut,
    plus ``cut_offset``; fringe strands are cut ``fringe_stop`` above the eyebrows) or, for
    non-fringe strands, first enters the face zone.

    Args:
        poly: (N,S+1,3) polylines with equal segments per strand.
        p: style parameters.
        zone: face keep-out box.
        fringe_w: (N,) fringe membership.
        cut_offset: (N,) per-strand cut height jitter.
        n_points: P points per output strand.
        min_length: shortest strand kept (metres).

    Returns:
        (N,P,3) float64 strands, points equally spaced by arc length along the polyline.
    """
    n, s1, _ = poly.shape
    seg = np.linalg.norm(poly[:, 1] - poly[:, 0], axis=-1)                 # (N,)
    fw = fringe_w[:, None]
    level = cut_level(poly, p) + cut_offset[:, None]
    level = (1.0 - fw) * level + fw * (zone.y_brow + p.fringe_stop)
    margin = poly[..., 1] - level                                           # > 0 is kept
    bad = margin <= 0.0
    bad |= in_face_zone(poly, zone) & (fw < 0.5)
    bad[:, 0] = False
    has_cut = bad.any(1)
    k = np.where(has_cut, np.argmax(bad, axis=1), s1 - 1)                   # first bad index
    rows = np.arange(n)
    a, b = margin[rows, k - 1], margin[rows, k]
    frac = np.where((b <= 0.0) & (a > 0.0), a / np.maximum(a - b, 1e-12), 0.0)
    length = np.where(has_cut, (k - 1 + frac) * seg, (s1 - 1) * seg)
    length = np.minimum(np.maximum(length, min_length), (s1 - 1) * seg)
    return sample_prefix(poly, length, n_points)


def sample_prefix(points: np.ndarray, length: np.ndarray, n_points: int) -> np.ndarray:
    """Sample the first ``length`` (N,) metres of polylines (N,S,3) at ``n_points`` points
    equally spaced by arc length (lengths beyond a polyline's end are clamped to it).

    Returns:
        (N,n_points,3) float64.
    """
    x = np.asarray(points, np.float64)
    n, s1, _ = x.shape
    cum = np.concatenate([np.zeros((n, 1)), np.cumsum(np.linalg.norm(np.diff(x, axis=1), axis=-1), 1)], 1)
    target = np.linspace(0.0, 1.0, n_points)[None] * np.minimum(length, cum[:, -1])[:, None]
    # one global search: offset each row beyond the previous row's range
    offs = (np.arange(n) * (cum[:, -1].max() + 1.0))[:, None]
    j = np.searchsorted((cum + offs).ravel(), (target + offs).ravel(), side="right").reshape(n, n_points)
    j = np.clip(j - np.arange(n)[:, None] * s1 - 1, 0, s1 - 2)
    r = np.arange(n)[:, None]
    c0, c1 = cum[r, j], cum[r, j + 1]
    f = np.clip(np.divide(target - c0, c1 - c0, out=np.zeros_like(target), where=c1 > c0), 0.0, 1.0)
    return x[r, j] + f[..., None] * (x[r, j + 1] - x[r, j])


def truncate_at_face(points: np.ndarray, zone: FaceZone) -> tuple[np.ndarray, np.ndarray]:
    """Cut strands (N,P,3) just before their first point inside the face zone and resample them
    to P points; other strands are returned unchanged.

    Returns:
        (strands (N,P,3) float64, indices (K,) of the strands that were cut).
    """
    x = np.asarray(points, np.float64)
    inside = in_face_zone(x, zone)
    inside[:, 0] = False
    hit = np.nonzero(inside.any(1))[0]
    if len(hit) == 0:
        return x, hit
    k = np.argmax(inside[hit], axis=1)                                      # first inside index
    sub = x[hit]
    cum = np.concatenate([np.zeros((len(hit), 1)),
                          np.cumsum(np.linalg.norm(np.diff(sub, axis=1), axis=-1), 1)], 1)
    out = x.copy()
    out[hit] = sample_prefix(sub, cum[np.arange(len(hit)), k - 1], x.shape[1])
    return out, hit
