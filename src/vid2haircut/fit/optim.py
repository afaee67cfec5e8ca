"""Adam that moves weakly constrained texels of a hair map slowly.

Plain Adam divides every coordinate's step by that coordinate's own gradient RMS, so each texel
of a (K,R,R) map moves by about the learning rate per step whatever the evidence for it: a texel
that only a weak regulariser touches (hair never seen in any keyframe) moves as fast as one that
the images pin down. :class:`SharedAdam` divides instead by the larger of the coordinate's own RMS
and the RMS shared over chosen dimensions (by default the two texel dimensions: one scale per PCA
component). Texels with typical or large gradients step like Adam (never faster); texels whose
gradients are much smaller than their component's typical gradient step proportionally less.
"""

from __future__ import annotations

from typing import Iterable

import torch

__all__ = ["SharedAdam"]


class SharedAdam(torch.optim.Optimizer):
    """Adam whose step is divided by max(own gradient RMS, gradient RMS shared over ``shared_dims``).

    Args:
        params: parameters or groups (each group may carry a ``name``).
        lr: learning rate.
        betas: Adam's (beta1, beta2).
        eps: added to the root of the second moment.
        shared_dims: dimensions the second moment is averaged over (default the last two:
            the texel grid of a (K,R,R) map); dimensions a parameter does not have are ignored.
    """

    def __init__(self, params: Iterable, lr: float = 1e-2, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8, shared_dims: tuple[int, ...] = (-2, -1)) -> None:
        if lr <= 0:
            raise ValueError(f"SharedAdam: lr must be positive, got {lr}")
        super().__init__(params, {"lr": lr, "betas": betas, "eps": eps, "shared_dims": tuple(shared_dims)})

    @torch.no_grad()
    def step(self, closure=None):  # noqa: D102 - torch optimiser API
        loss = closure() if closure is not None else None
        for group in self.param_groups:
            b1, b2 = group["betas"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                g = p.grad
                dims = tuple(d for d in group["shared_dims"] if -p.ndim <= d < p.ndim)
                st = self.state[p]
                if not st:
                    st["step"] = torch.zeros((), dtype=torch.float64)
                    st["exp_avg"] = torch.zeros_like(p)
                    st["exp_avg_sq"] = torch.zeros_like(p)
                    st["shared_sq"] = torch.zeros_like(g.square().mean(dim=dims, keepdim=True) if dims else p)
                st["step"] += 1
                t = float(st["step"])
                st["exp_avg"].mul_(b1).add_(g, alpha=1 - b1)
                sq = g.square()
                st["exp_avg_sq"].mul_(b2).add_(sq, alpha=1 - b2)
                st["shared_sq"].mul_(b2).add_(sq.mean(dim=dims, keepdim=True) if dims else sq, alpha=1 - b2)
                m_hat = st["exp_avg"] / (1 - b1 ** t)
                v_hat = torch.maximum(st["exp_avg_sq"], st["shared_sq"]) / (1 - b2 ** t)
                p.add_(m_hat / (v_hat.sqrt() + group["eps"]), alpha=-group["lr"])
        return loss
