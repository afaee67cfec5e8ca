"""Procedural hairstyles: named families of strand sets grown on a head model.

A style is built in stages, each in its own module:

1. parameters: the family defaults jittered by the seed (:mod:`.hair_params`);
2. roots: area-uniform jittered samples in the head's scalp-uv mask (:mod:`.hair_fields`);
3. centrelines: grown along a combing field with gravity while hugging the head, then cut at the
   style's cut level / above the eyes (:mod:`.hair_grow`);
4. detail: clumps, waves or curls, frizz (:mod:`.hair_shape`);
5. collisions: no point inside the head's SDF (:mod:`.hair_collide`).

Example::

    from vid2haircut.synth.hairstyles import FAMILIES, generate_hairstyle
    s = generate_hairstyle("bob", seed=3, n_strands=2000)   # StrandSet (2000,100,3)
    s.attributes["color"].shape, s.attributes["uv"].shape   # (2000,3), (2000,2)
"""

from __future__ import annotations

import zlib

import numpy as np

from ..polylines import resample_polylines
from ..strands import StrandSet
from .hair_collide import lift_roots, resolve_collisions
from .hair_color import sample_colors
from .hair_fields import (face_zone, fringe_weights, hairline_angles, length_map,
                          sample_roots)
from .hair_grow import cut_and_sample, grow_centrelines, truncate_at_face
from .hair_params import FAMILY_PARAMS, HairParams, sample_params
from .hair_sdf import HeadSDF
from .hair_shape import apply_clumps, apply_curl, apply_frizz, assign_clumps

__all__ = ["FAMILIES", "generate_hairstyle", "hairstyle_params"]

FAMILIES: tuple[str, ...] = tuple(FAMILY_PARAMS)
"""Names of the hairstyle families."""


def _check_family(family: str) -> None:
    if family not in FAMILY_PARAMS:
        raise ValueError(f"unknown hairstyle family {family!r}; known families: "
                         f"{', '.join(FAMILIES)}")


def _streams(family: str, seed: int) -> list[np.random.Generator]:
    """Independent generators per stage: (params, roots, growth, shape, colour)."""
    ss = np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(seed) >> 32 & 0xFFFFFFFF,
                                 zlib.crc32(family.encode("utf-8"))])
    return [np.random.default_rng(s) for s in ss.spawn(5)]


def hairstyle_params(family: str, seed: int) -> HairParams:
    """The jittered parameters that :func:`generate_hairstyle` uses for ``(family, seed)``."""
    _check_family(family)
    return sample_params(family, _streams(family, seed)[0])


def generate_hairstyle(family: str, seed: int, head=None, n_strands: int = 10000,
                       n_points: int = 100, n_steps: int = 100) -> StrandSet:
    """Generate one hairstyle of a named family.

    Args:
        family: one of :data:`FAMILIES`.
        seed: integer seed; the same (family, seed, head, sizes) give identical arrays.
        head: head model (default ``get_head("proxy-v1")``); points come out in its canonical frame.
        n_strands: N strands.
        n_points: P points per strand (uniform by arc length, root first).
        n_steps: growth integration steps per strand.

    Returns:
        :class:`~vid2haircut.strands.StrandSet` with points (N,P,3) float32 metres and attributes
        ``"color"`` (N,3) float32 linear RGB (the style's base colour with per-strand jitter) and
        ``"uv"`` (N,2) float32 root scalp uv.
    """
    _check_family(family)
    if int(n_strands) < 1:
        raise ValueError(f"n_strands must be >= 1, got {n_strands}")
    if int(n_points) < 2:
        raise ValueError(f"n_points must be >= 2, got {n_points}")
    if int(n_steps) < 2:
        raise ValueError(f"n_steps must be >= 2, got {n_steps}")
    if head is None:
        from ..head import get_head
        head = get_head("proxy-v1")
    n, npts = int(n_strands), int(n_points)
    r_par, r_root, r_grow, r_shape, r_col = _streams(family, seed)
    p = sample_params(family, r_par)

    sdf = HeadSDF(head)
    roots = sample_roots(head, n, r_root)
    root_pts = lift_roots(sdf, roots.points, roots.normals)
    fringe_w = fringe_weights(roots.theta, roots.phi, hairline_angles(head, roots.phi), p)
    lengths = length_map(roots.theta, roots.phi, p) * np.exp(r_grow.normal(0.0, p.length_jitter, n))
    cut_offset = r_grow.normal(0.0, p.cut_jitter, n)
    zone = face_zone(head.landmarks)

    crown = np.asarray(head.scalp_uv_to_root(np.array([[0.5, 0.5]], np.float32))[0][0], np.float64)
    poly = grow_centrelines(sdf, root_pts, roots.normals, lengths, fringe_w, p, zone, crown,
                            int(n_steps))
    pts = cut_and_sample(poly, p, zone, fringe_w, cut_offset, npts)
    clumps = assign_clumps(root_pts, p.strands_per_clump, r_shape)
    pts = apply_clumps(pts, clumps, p.clump_strength, p.clump_power, r_shape)
    pts = apply_curl(pts, p, clumps, r_shape)
    pts = apply_frizz(pts, p, r_shape)
    pts, _ = truncate_at_face(resample_polylines(pts, npts), zone)
    pts = resolve_collisions(sdf, pts, margin=p.collision_margin)
    pts, cut = truncate_at_face(pts, zone)                 # collisions may push hair onto the face
    if len(cut):
        pts[cut] = resolve_collisions(sdf, pts[cut], margin=p.collision_margin)

    _, colors = sample_colors(p.palette, n, r_col)
    return StrandSet(pts.astype(np.float32), {"color": colors, "uv": roots.uv},
                     head_model=getattr(head, "name", None))
