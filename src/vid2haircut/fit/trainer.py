"""A small trainer (nerfstudio style): the model owns its parameters and its loss dict; the trainer
only sums weighted terms, steps the optimisers, records the history and calls back for checkpoints.

A model implements::

    get_param_groups() -> list[dict]            # torch optimiser groups (each with a "name")
    get_loss_dict(step: int) -> dict[str, Tensor]   # keys are fields of LossWeights
    after_backward(step: int) -> None           # optional (gradient surgery)
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import torch
from torch import Tensor

from vid2haircut.fit.components import LossWeights

__all__ = ["History", "weighted_total", "lr_decay_factor", "Trainer"]

log = logging.getLogger(__name__)


@dataclass
class History:
    """Per-step record of the loss terms (unweighted) and the weighted total.

    Attributes:
        steps: step numbers.
        terms: {name: values} of the unweighted terms (NaN where a term was absent at a step).
        total: weighted totals.
        seconds: wall time spent in steps.
    """

    steps: list[int] = field(default_factory=list)
    terms: dict[str, list[float]] = field(default_factory=dict)
    total: list[float] = field(default_factory=list)
    seconds: float = 0.0

    def add(self, step: int, terms: dict[str, float], total: float) -> None:
        """Append one step."""
        n = len(self.steps)
        for k in terms:
            if k not in self.terms:
                self.terms[k] = [float("nan")] * n
        for k, vals in self.terms.items():
            vals.append(float(terms.get(k, float("nan"))))
        self.steps.append(int(step))
        self.total.append(float(total))

    def to_dict(self) -> dict:
        """JSON-able form."""
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "History":
        """Inverse of :meth:`to_dict`."""
        return History([int(s) for s in d["steps"]], {k: list(v) for k, v in d["terms"].items()},
                       list(d["total"]), float(d.get("seconds", 0.0)))


def weighted_total(losses: dict[str, Tensor], weights: LossWeights) -> Tensor:
    """sum_k weights.k * losses[k]; a key that is not a weight raises ValueError."""
    names = {f.name for f in dataclasses.fields(weights)}
    total = None
    for k, v in losses.items():
        if k not in names:
            raise ValueError(f"loss term {k!r} has no weight (known: {sorted(names)})")
        term = getattr(weights, k) * v
        total = term if total is None else total + term
    if total is None:
        raise ValueError("empty loss dict")
    return total


def lr_decay_factor(step: int, total: int, decay_steps: int, final: float) -> float:
    """Learning-rate factor at ``step`` of ``total``: 1, then over the last ``decay_steps`` steps a
    half cosine down to ``final`` at the last step (``decay_steps`` <= 0: always 1).

    A function of the step alone, so a resumed run follows the same schedule.
    """
    if decay_steps <= 0 or total <= 0:
        return 1.0
    if not 0.0 < final <= 1.0:
        raise ValueError(f"learning-rate decay: the final factor must be in (0, 1], got {final}")
    start = total - decay_steps
    if step < start:
        return 1.0
    t = min(1.0, (step - start + 1) / decay_steps)
    return final + (1.0 - final) * 0.5 * (1.0 + math.cos(math.pi * t))


class Trainer:
    """Runs optimisation steps of a model.

    Args:
        model: see the module docstring.
        optimizers: optimisers over the model's parameter groups.
        weights: loss weights.
        history: history to continue (resume).
        lr_factor: optional ``step -> factor`` on every group's starting learning rate
            (e.g. :func:`lr_decay_factor`); the starting rate is kept in the group as ``base_lr``.
    """

    def __init__(self, model: Any, optimizers: list[torch.optim.Optimizer], weights: LossWeights,
                 history: History | None = None, lr_factor: Callable[[int], float] | None = None) -> None:
        self.model = model
        self.optimizers = optimizers
        self.weights = weights
        self.history = history or History()
        self.lr_factor = lr_factor

    def step(self, step: int) -> dict[str, float]:
        """One optimisation step -> the unweighted terms (floats)."""
        for opt in self.optimizers:
            opt.zero_grad(set_to_none=True)
            if self.lr_factor is not None:
                f = float(self.lr_factor(step))
                for g in opt.param_groups:
                    g["lr"] = g.setdefault("base_lr", g["lr"]) * f
        losses = self.model.get_loss_dict(step)
        total = weighted_total(losses, self.weights)
        if not torch.isfinite(total):
            raise FloatingPointError(f"step {step}: non-finite loss {({k: float(v) for k, v in losses.items()})}")
        total.backward()
        hook = getattr(self.model, "after_backward", None)
        if hook is not None:
            hook(step)
        for opt in self.optimizers:
            opt.step()
        terms = {k: float(v.detach()) for k, v in losses.items()}
        self.history.add(step, terms, float(total.detach()))
        return terms

    def run(self, start: int, stop: int, desc: str = "fit", progress: bool = True,
            on_step: Callable[[int], None] | None = None) -> History:
        """Steps ``start .. stop-1``; ``on_step(step)`` after each (e.g. checkpoints). Shows a tqdm bar."""
        from tqdm import tqdm

        bar = tqdm(range(start, stop), desc=desc, disable=not progress, leave=False, dynamic_ncols=True,
                   initial=0, total=max(0, stop - start))
        for step in bar:
            t0 = time.perf_counter()
            self.step(step)
            self.history.seconds += time.perf_counter() - t0
            bar.set_postfix(loss=f"{self.history.total[-1]:.4g}", refresh=False)
            if on_step is not None:
                on_step(step)
        bar.close()
        return self.history
