"""What holds the hair that no keyframe shows in Stage 2 (:mod:`vid2haircut.fit.stage2`): the
directions away from the head that the anchor leaves free, and the harmonic extension of the seen
texels' change to the unseen ones.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor

__all__ = ["head_normals", "harmonic_extension"]


@torch.no_grad()
def head_normals(points: Tensor, sdf: Callable[[Tensor], Tensor], eps: float = 1e-3) -> Tensor:
    """(...,3) unit gradients of the head's signed distance at ``points`` (central differences of
    ``eps`` metres): the direction away from the head."""
    grads = []
    for axis in range(3):
        step = torch.zeros(3, dtype=points.dtype, device=points.device)
        step[axis] = eps
        grads.append(sdf(points + step) - sdf(points - step))
    g = torch.stack(grads, -1)
    return g / g.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def harmonic_extension(pairs: Tensor, n: int, known: Tensor, eps: float = 1e-3) -> Tensor:
    """The matrix that extends values given on ``known`` nodes harmonically to the other nodes.

    On the graph with edges ``pairs``, the unknown values u minimise sum over edges (u_i - u_j)^2
    with the known values fixed: every unknown node takes the mean of its neighbours (a discrete
    Laplace equation with Dirichlet values on the known nodes). ``eps`` (times each node's degree)
    ties unknown nodes weakly to 0, so a region with no known node gets 0 rather than a singular
    system.

    Args:
        pairs: (E,2) long node pairs. n: number of nodes. known: (n,) bool.

    Returns:
        (n_unknown, n_known) float64 matrix E: ``u[~known] = E @ v[known]``.
    """
    lap = torch.zeros(n, n, dtype=torch.float64)
    i, j = pairs[:, 0].cpu(), pairs[:, 1].cpu()
    lap.index_put_((i, j), torch.full((len(i),), -1.0, dtype=torch.float64), accumulate=True)
    lap.index_put_((j, i), torch.full((len(i),), -1.0, dtype=torch.float64), accumulate=True)
    deg = -lap.sum(1)
    lap += torch.diag(deg)
    k = known.cpu().bool()
    u = ~k
    a = lap[u][:, u] + torch.diag(eps * deg[u].clamp_min(1.0))
    return torch.linalg.solve(a, -lap[u][:, k])
