"""Hair colours: named linear-RGB base colours and per-strand jitter."""

from __future__ import annotations

import numpy as np

__all__ = ["BASE_COLORS", "sample_colors"]

BASE_COLORS: dict[str, tuple[float, float, float]] = {
    "black": (0.012, 0.010, 0.009),
    "dark_brown": (0.040, 0.022, 0.012),
    "brown": (0.110, 0.058, 0.028),
    "light_brown": (0.230, 0.140, 0.070),
    "blonde": (0.520, 0.380, 0.200),
    "platinum": (0.720, 0.650, 0.520),
    "red": (0.300, 0.075, 0.025),
    "grey": (0.330, 0.320, 0.310),
}
"""Base colours (linear RGB), in the order that :attr:`HairParams.palette` weights them."""


def sample_colors(palette: tuple[float, ...], n_strands: int,
                  rng: np.random.Generator) -> tuple[str, np.ndarray]:
    """Pick a base colour by the palette weights and jitter it per strand.

    Args:
        palette: one non-negative weight per entry of :data:`BASE_COLORS`.
        n_strands: N.
        rng: random generator.

    Returns:
        (name of the base colour, (N,3) float32 linear RGB in [0,1]): the base colour with a
        per-style tint, then per-strand brightness (log-normal, 15 %) and channel (4 %) jitter.
    """
    names = list(BASE_COLORS)
    w = np.asarray(palette, np.float64)
    if w.shape != (len(names),) or (w < 0).any() or w.sum() <= 0:
        raise ValueError(f"palette must hold {len(names)} non-negative weights, got {palette}")
    k = int(rng.choice(len(names), p=w / w.sum()))
    base = np.asarray(BASE_COLORS[names[k]]) * np.exp(rng.normal(0.0, 0.08, 3))
    bright = np.exp(rng.normal(0.0, 0.15, (n_strands, 1)))
    chan = np.exp(rng.normal(0.0, 0.04, (n_strands, 3)))
    return names[k], np.clip(base[None] * bright * chan, 0.0, 1.0).astype(np.float32)
