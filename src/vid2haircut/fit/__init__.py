"""Fitting stages: Stage 1 (single view, Im2Haircut baseline) and Stage 2 (Vid2Haircut joint refinement).

- :mod:`.config`: the stages' dataclass configs (schedules, learning rates), built from
  :mod:`.components` (loss weights, render settings, ablation switches, decoding defaults);
  :mod:`.settings`: ``--settings`` overrides applied to them.
- :mod:`.data`: keyframes, head poses, targets and cameras as tensors at the fitting resolution.
- :mod:`.image_terms`, :mod:`.losses`: the image and geometry loss terms; :mod:`.scene`: guides of a
  map, rendering, the image terms of a render.
- :mod:`.visibility`: visibility-aware gradient masking; :mod:`.deform`: the deformation MLP.
- :mod:`.trainer`: sums the weighted loss dict and steps; :mod:`.optim`: Adam that moves weakly
  constrained texels slowly; :mod:`.stage1`, :mod:`.stage2`: the models.
- :mod:`.outputs`: artifacts; :mod:`.pipeline`: file-level ``run_stage1`` / ``run_stage2``;
  :mod:`.toy`: a tiny known problem for tests.

The configs and settings import without torch (the workflow checks a config with them when
Snakemake reads it); the fitting names below are imported on first use.
"""

import importlib as _importlib

from vid2haircut.fit.components import LossWeights, RenderSettings, Switches
from vid2haircut.fit.config import Stage1Config, Stage2Config
from vid2haircut.fit.settings import apply_overrides

_LAZY = {"FitData": "data", "load_fit_data": "data", "make_fit_data": "data", "FitResult": "stage1",
         "fit_stage1": "stage1", "fit_stage2": "stage2"}

__all__ = ["LossWeights", "RenderSettings", "Stage1Config", "Stage2Config", "Switches", "apply_overrides",
           *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(_importlib.import_module(f"vid2haircut.fit.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'vid2haircut.fit' has no attribute {name!r}")
