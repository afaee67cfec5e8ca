"""Hairstyle family parameters: one typed parameter set per family, randomised by a seed.

Every family is a :class:`HairParams` of defaults; :func:`sample_params` jitters the continuous
fields around those defaults (and draws discrete choices such as the parting side) so that
different seeds give different styles of the same family. Lengths and offsets are in metres in the
head's canonical frame (y up, face towards +z); "cut" levels are heights (y) below which hair is cut.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

__all__ = ["HairParams", "FAMILY_PARAMS", "sample_params", "NO_CUT"]

NO_CUT = -10.0
"""Cut level meaning "no cut" (far below any head)."""


@dataclass(frozen=True)
class HairParams:
    """Parameters of one procedural hairstyle (all lengths in metres)."""

    # -- length map: maximum strand length by scalp region (blended by root azimuth / polar angle)
    l_top: float = 0.6
    """Length of strands rooted near the crown."""
    l_front: float = 0.6
    """Length of strands rooted at the front hairline."""
    l_side: float = 0.6
    """Length of strands rooted above the ears."""
    l_back: float = 0.6
    """Length of strands rooted at the nape."""
    length_jitter: float = 0.05
    """Relative per-strand log-normal length jitter."""
    # -- cut levels: strands are cut where they first fall below these heights (by azimuth)
    cut_front: float = NO_CUT
    """Cut height in front of / beside the face."""
    cut_side: float = NO_CUT
    """Cut height at the sides."""
    cut_back: float = NO_CUT
    """Cut height at the back."""
    cut_jitter: float = 0.008
    """Per-strand standard deviation of the cut height."""
    # -- combing field
    part_x: float = 0.0
    """x position of the parting line (0 = centre parting)."""
    part_weight: float = 1.0
    """Strength of the sideways flow away from the parting on the front-top of the head."""
    back_weight: float = 0.4
    """Strength of the backward flow on the front-top of the head (combed back)."""
    radial_weight: float = 1.0
    """Strength of the flow radially away from the crown."""
    down_weight: float = 0.3
    """Strength of the downward flow."""
    crown_z: float = -0.03
    """z of the crown whorl (the flow centre)."""
    # -- fringe (bangs)
    fringe: float = 0.0
    """Fraction of front roots that form a fringe combed forward (0 = no fringe)."""
    fringe_depth: float = 0.55
    """How far back from the front hairline fringe roots reach (radians of polar angle)."""
    fringe_width: float = 0.9
    """Half-width of the fringe region in root azimuth (radians)."""
    fringe_stop: float = 0.012
    """Fringe tips stop this high above the eyebrows."""
    # -- growth
    lift: float = 0.5
    """Initial normal (standing-up) component of the strand direction at the root."""
    gravity: float = 30.0
    """Curvature towards gravity (1/m): larger falls faster."""
    comb_strength: float = 60.0
    """Curvature towards the combing direction (1/m), decaying with arc length."""
    comb_decay: float = 0.06
    """Arc length over which the combing pull decays."""
    offset0: float = 0.002
    """Distance from the scalp that a strand keeps near its root."""
    volume: float = 0.06
    """Growth of that distance per metre of arc length (hair layering / volume)."""
    max_offset: float = 0.03
    """Largest distance from the scalp that a strand keeps while on the head."""
    collision_margin: float = 0.001
    """Distance from the head that collision handling restores (short hair may lie closer)."""
    # -- curl / wave
    curl: str = "none"
    """"none", "wave" (planar sine) or "helix" (corkscrew curl)."""
    curl_amp: float = 0.0
    """Wave amplitude or helix radius."""
    curl_period: float = 0.05
    """Arc length of one wave / curl turn along the centreline."""
    curl_start: float = 0.04
    """Arc length over which the curl amplitude ramps in from the root."""
    curl_phase_jitter: float = 0.6
    """Per-strand phase jitter around the clump phase (radians)."""
    # -- clumping and frizz
    strands_per_clump: float = 40.0
    """Mean number of strands per clump."""
    clump_strength: float = 0.3
    """Pull towards the clump centre strand at the tip (0..1)."""
    clump_power: float = 1.5
    """Tip weighting exponent of the clump pull."""
    frizz_amp: float = 0.0015
    """Amplitude of smooth per-strand frizz noise at the tip."""
    frizz_period: float = 0.05
    """Typical wavelength of the frizz noise."""
    # -- colour
    palette: tuple[float, ...] = (1, 2, 3, 2, 1, 1, 1, 0.3)
    """Relative weights of the base colours in :data:`~vid2haircut.synth.hair_color.BASE_COLORS`."""


_MEDIUM = dict(l_top=0.6, l_front=0.6, l_side=0.6, l_back=0.6, part_weight=1.0, back_weight=0.35,
               gravity=32.0, volume=0.05, max_offset=0.02)

FAMILY_PARAMS: dict[str, HairParams] = {
    "buzz": HairParams(l_top=0.008, l_front=0.006, l_side=0.005, l_back=0.005, length_jitter=0.12,
                       part_weight=0.0, back_weight=0.3, radial_weight=1.0, lift=0.35, gravity=0.0,
                       comb_strength=150.0, comb_decay=0.02, offset0=0.0008, volume=0.05,
                       max_offset=0.003, collision_margin=0.0003, strands_per_clump=1.0,
                       clump_strength=0.0,
                       frizz_amp=0.0002, frizz_period=0.004, palette=(3, 3, 2, 1, 0.5, 0.2, 0.3, 1)),
    "short_straight": HairParams(l_top=0.055, l_front=0.05, l_side=0.02, l_back=0.025,
                                 length_jitter=0.1, part_weight=0.3, back_weight=1.0, lift=0.7,
                                 gravity=14.0, comb_strength=70.0, comb_decay=0.05, offset0=0.002,
                                 volume=0.12, max_offset=0.012, strands_per_clump=25.0,
                                 clump_strength=0.35, frizz_amp=0.001, frizz_period=0.03,
                                 palette=(3, 3, 2, 1, 1, 0.3, 0.5, 0.5)),
    "bob": HairParams(**_MEDIUM, cut_front=-0.075, cut_side=-0.08, cut_back=-0.075,
                      cut_jitter=0.004, strands_per_clump=50.0, clump_strength=0.25),
    "shoulder_straight": HairParams(**_MEDIUM, cut_front=-0.2, cut_side=-0.21, cut_back=-0.2,
                                    cut_jitter=0.012),
    "long_straight": HairParams(**{**_MEDIUM, "l_top": 0.75, "l_front": 0.75, "l_side": 0.75,
                                   "l_back": 0.75},
                                cut_front=-0.38, cut_side=-0.4, cut_back=-0.42, cut_jitter=0.02),
    "wavy": HairParams(**{**_MEDIUM, "volume": 0.09, "gravity": 26.0}, cut_front=-0.26,
                       cut_side=-0.28, cut_back=-0.3, cut_jitter=0.02, curl="wave",
                       curl_amp=0.011, curl_period=0.08, curl_start=0.05, strands_per_clump=60.0,
                       clump_strength=0.45, frizz_amp=0.002),
    "curly": HairParams(**{**_MEDIUM, "volume": 0.18, "gravity": 16.0, "lift": 0.8,
                           "max_offset": 0.05}, cut_front=-0.17, cut_side=-0.19, cut_back=-0.2,
                        cut_jitter=0.02, curl="helix", curl_amp=0.011, curl_period=0.03,
                        curl_start=0.025, curl_phase_jitter=0.35, strands_per_clump=30.0,
                        clump_strength=0.7, clump_power=0.7, frizz_amp=0.003, frizz_period=0.02,
                        palette=(3, 3, 2, 1, 0.5, 0.2, 0.8, 0.2)),
    "side_parted": HairParams(**{**_MEDIUM, "part_x": 0.035, "part_weight": 1.6,
                                 "back_weight": 0.25}, cut_front=-0.1, cut_side=-0.12,
                              cut_back=-0.13, cut_jitter=0.008),
    "bangs": HairParams(**_MEDIUM, cut_front=-0.22, cut_side=-0.24, cut_back=-0.25,
                        cut_jitter=0.012, fringe=1.0, fringe_depth=0.8),
    "afro": HairParams(l_top=0.16, l_front=0.12, l_side=0.13, l_back=0.13, part_weight=0.0,
                       back_weight=0.2, radial_weight=1.0, lift=1.0, gravity=4.0,
                       comb_strength=20.0, volume=0.35, max_offset=0.07, curl="helix",
                       curl_amp=0.006, curl_period=0.012, curl_start=0.01,
                       curl_phase_jitter=0.3, strands_per_clump=20.0, clump_strength=0.6,
                       clump_power=0.6, frizz_amp=0.004, frizz_period=0.015,
                       palette=(5, 3, 1, 0.3, 0, 0, 0.2, 0.3)),
}
"""Default parameters of each named family."""

# field -> (kind, amount): "rel" multiplies by U(1-a, 1+a), "abs" adds U(-a, a)
_JITTER: dict[str, tuple[str, float]] = {
    "l_top": ("rel", 0.15), "l_front": ("rel", 0.15), "l_side": ("rel", 0.15),
    "l_back": ("rel", 0.15), "cut_front": ("abs", 0.02), "cut_side": ("abs", 0.02),
    "cut_back": ("abs", 0.025), "part_x": ("abs", 0.008), "part_weight": ("rel", 0.2),
    "back_weight": ("rel", 0.3), "crown_z": ("abs", 0.01), "fringe_depth": ("rel", 0.15),
    "fringe_stop": ("rel", 0.3), "lift": ("rel", 0.2), "gravity": ("rel", 0.15),
    "volume": ("rel", 0.25), "curl_amp": ("rel", 0.25), "curl_period": ("rel", 0.2),
    "strands_per_clump": ("rel", 0.3), "clump_strength": ("rel", 0.25),
    "frizz_amp": ("rel", 0.3),
}


def sample_params(family: str, rng: np.random.Generator) -> HairParams:
    """Draw a family member: the family defaults jittered by ``rng``.

    Args:
        family: a key of :data:`FAMILY_PARAMS`.
        rng: random generator (consumed deterministically).

    Returns:
        The jittered :class:`HairParams`. Side partings pick their side at random; cut levels are
        kept ordered so hair never ends above its own roots' cut of "no cut".
    """
    if family not in FAMILY_PARAMS:
        raise ValueError(f"unknown hairstyle family {family!r}; known families: "
                         f"{', '.join(sorted(FAMILY_PARAMS))}")
    base = FAMILY_PARAMS[family]
    values = {}
    for f in fields(HairParams):
        v = getattr(base, f.name)
        kind, amount = _JITTER.get(f.name, ("none", 0.0))
        draw = float(rng.uniform(-1.0, 1.0))          # always drawn: same stream for every family
        if kind == "none" or not isinstance(v, float):
            continue
        if f.name.startswith("cut_") and v <= NO_CUT:
            continue
        values[f.name] = v * (1.0 + amount * draw) if kind == "rel" else v + amount * draw
    side = 1.0 if rng.uniform() < 0.5 else -1.0
    if abs(base.part_x) > 0.01:                       # a side parting: either side
        values["part_x"] = side * abs(values.get("part_x", base.part_x))
    return replace(base, **values)
