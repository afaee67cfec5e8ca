"""Applying ``--settings`` overrides to the fitting configs (:mod:`vid2haircut.fit.config`), with
checks that name the key that is unknown, of the wrong type or out of range, and the config's
JSON form for the stage records.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from vid2haircut.fit.components import (COMPOSITINGS, DEPTH_ALIGNMENTS, HIDDEN_DIRECTION_SOURCES, SMOOTH_DIRECTION_FORMS,
                                        LossWeights)

__all__ = ["apply_overrides", "load_settings", "config_to_dict"]


# Settings whose value must lie in [low, high): checked when overrides are applied, so a bad value
# stops a run before it fits rather than when it writes its output.
_RANGES = {"length_spread": (0.0, 1.0 / 3.0), "tip_scatter": (0.0, 0.05), "carve_tolerance": (0.0, 1.0e3),
           "carve_min_fraction": (0.0, math.nextafter(1.0, 2.0)), "pca_from": (0, math.inf),
           "smooth_direction_from": (0, math.inf), "smooth_length_from": (0, math.inf),
           "smooth_seen_weight": (0.0, math.inf), "smooth_unseen_weight": (0.0, math.inf),
           # counts, sizes and steps
           "iterations": (1, math.inf), "coarse_steps": (0, math.inf), "coarse_components": (0, math.inf),
           "map_res": (2, 1025), "n_dense": (1, math.inf), "seed": (0, 2**63), "canonical_steps": (0, math.inf),
           "ramp_steps": (0, math.inf), "n_keyframes": (1, math.inf), "frames_per_step": (0, math.inf),
           "lr_decay_steps": (0, math.inf), "checkpoint_every": (0, math.inf), "render_dense": (0, math.inf),
           "gate_bins_every": (0, math.inf),
           "dense_from_step": (-1, math.inf), "size": (8, 4097), "n_points": (2, 1025), "bins": (2, 257),
           # rates, widths, fractions
           "lr_prior": (0.0, math.inf), "weight_decay_prior": (0.0, math.inf), "lr_z": (0.0, math.inf),
           "lr_mlp": (0.0, math.inf), "lr_codes": (0.0, math.inf), "lr_final": (0.0, math.inf),
           "strand_width": (1e-6, math.inf), "dense_width": (1e-6, math.inf), "depth_bin": (1e-6, math.inf),
           "mask_threshold": (0.0, 1.0), "observed_fraction": (0.0, math.nextafter(1.0, 2.0)),
           # the renderer's own limits: an opacity above its alpha_min (exp(-4.5)), a visibility weight > 0
           "silhouette_opacity": (math.nextafter(math.exp(-4.5), 1.0), math.nextafter(1.0, 2.0)),
           "dense_silhouette_opacity": (math.nextafter(math.exp(-4.5), 1.0), math.nextafter(1.0, 2.0)),
           "vis_weight": (1e-9, math.nextafter(1.0, 2.0)), "dense_vis_weight": (1e-9, math.nextafter(1.0, 2.0)),
           "max_offset": (0.0, math.inf), "code_init_std": (0.0, math.inf), "t_min": (1e-12, 1.0)}
# Every loss weight (``weights.*``) lies in [0, inf): a negative weight would reward the term.
# Settings that name one of a few modes, checked the same way.
_CHOICES = {"depth_align": DEPTH_ALIGNMENTS, "smooth_direction_form": SMOOTH_DIRECTION_FORMS,
            "hidden_direction_from": HIDDEN_DIRECTION_SOURCES, "compositing": COMPOSITINGS}


def _set(obj: Any, path: list[str], value: Any, full: str) -> None:
    name = path[0]
    if not dataclasses.is_dataclass(obj) or name not in {f.name for f in dataclasses.fields(obj)}:
        known = sorted(f.name for f in dataclasses.fields(obj)) if dataclasses.is_dataclass(obj) else []
        raise ValueError(f"settings: unknown key {full!r} (known here: {known})")
    cur = getattr(obj, name)
    if len(path) > 1:
        _set(cur, path[1:], value, full)
    elif dataclasses.is_dataclass(cur):
        if not isinstance(value, dict):
            raise ValueError(f"settings: {full!r} must be an object, got {value!r}")
        for k, v in value.items():
            _set(cur, [k], v, f"{full}.{k}")
    else:
        if isinstance(cur, bool) and not isinstance(value, bool):
            raise ValueError(f"settings: {full!r} must be true or false, got {value!r}")
        if isinstance(cur, (int, float)) and not isinstance(cur, bool):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"settings: {full!r} must be a number, got {value!r}")
            if isinstance(cur, int) and not float(value).is_integer():
                raise ValueError(f"settings: {full!r} must be an integer, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"settings: {full!r} must be a finite number, got {value!r}")
            value = type(cur)(value)
            low, high = (0.0, math.inf) if isinstance(obj, LossWeights) else _RANGES.get(name, (-math.inf, math.inf))
            if not low <= value < high:
                raise ValueError(f"settings: {full!r} must be in [{low:g}, {high:g}), got {value!r}")
        if name in _CHOICES and value not in _CHOICES[name]:
            raise ValueError(f"settings: {full!r} must be one of {_CHOICES[name]}, got {value!r}")
        setattr(obj, name, value)


def apply_overrides(cfg: Any, overrides: dict | None) -> Any:
    """A deep copy of the config dataclass ``cfg`` with ``overrides`` applied.

    Args:
        cfg: a config dataclass (e.g. :class:`Stage2Config`).
        overrides: nested ``{"weights": {"depth": 0.1}}`` or dotted ``{"weights.depth": 0.1}`` keys.

    Raises:
        ValueError naming the key when it is unknown or has the wrong type.
    """
    out = copy.deepcopy(cfg)
    for key, value in (overrides or {}).items():
        _set(out, str(key).split("."), value, str(key))
    return out


def load_settings(text_or_path: str | None) -> dict:
    """Parse ``--settings``: a JSON object given inline or as the path of a JSON file ({} for None)."""
    if not text_or_path:
        return {}
    p = Path(text_or_path)
    if not text_or_path.lstrip().startswith("{") and p.suffix == ".json":
        if not p.is_file():
            raise FileNotFoundError(f"{p}: settings file not found")
        text, where = p.read_text(), str(p)
    else:
        text, where = text_or_path, "--settings"
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{where}: not valid JSON ({e})") from None
    if not isinstance(obj, dict):
        raise ValueError(f"{where}: settings must be a JSON object, got {type(obj).__name__}")
    return obj


def config_to_dict(cfg: Any) -> dict:
    """JSON-able dict of a config dataclass."""
    return dataclasses.asdict(cfg)
