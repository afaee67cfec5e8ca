"""Shared set-up of the Stage 2 tests: the toy problem and fast settings."""

from __future__ import annotations

import torch

from vid2haircut.fit.config import Stage2Config
from vid2haircut.fit.settings import apply_overrides
from vid2haircut.fit.toy import toy_problem

FAST = {"iterations": 8, "canonical_steps": 3, "ramp_steps": 2, "lr_z": 0.1, "render": {"n_points": 16},
        "n_dense": 300, "checkpoint_every": 3}


def make_toy():
    """The small toy problem the Stage 2 tests fit (40 px, 3 frames, 12x12 map)."""
    return toy_problem(size=40, n_frames=3, map_res=12, k=12)


def cfg(**extra) -> Stage2Config:
    """The default Stage 2 settings with :data:`FAST` and ``extra`` applied."""
    return apply_overrides(Stage2Config(), {**FAST, **extra})


def start(toy):
    """Initial map: the mean strand on every scalp texel."""
    return torch.zeros_like(toy.z_gt), toy.mask.clone()
