"""The anchor term of Stage 2 (:func:`vid2haircut.fit.losses.anchor_loss`) and the head directions
that its outward-free form uses (:func:`vid2haircut.fit.hidden.head_normals`)."""

from __future__ import annotations

import pytest
import torch

from vid2haircut.fit.losses import anchor_loss
from vid2haircut.fit.hidden import head_normals


def test_anchor_holds_only_hidden_points():
    pts = torch.zeros(2, 3, 3, requires_grad=True)
    start = torch.zeros(2, 3, 3)
    start[0, 2, 0] = 0.01
    hidden = torch.tensor([[False, False, True], [False, False, False]])
    loss = anchor_loss(pts, start, hidden)
    loss.backward()
    assert float(loss.detach()) == pytest.approx(1e-4)                               # (1 cm)^2 over the one hidden point
    assert torch.count_nonzero(pts.grad.norm(dim=-1)) == 1 and pts.grad[0, 2, 0] < 0
    assert float(anchor_loss(pts, start, torch.zeros_like(hidden)).detach()) == 0.0


def test_outward_anchor_frees_only_the_move_away_from_the_head():
    start = torch.zeros(1, 4, 3)
    hidden = torch.ones(1, 4, dtype=torch.bool)
    out = torch.tensor([0.0, 1.0, 0.0]).expand(1, 4, 3)
    moves = torch.tensor([[[0.0, 0.01, 0.0],          # away from the head: free
                           [0.0, -0.01, 0.0],         # into the head: pays
                           [0.01, 0.0, 0.0],          # sideways: pays
                           [0.01, 0.01, 0.0]]])       # away and sideways: the sideways part pays
    per_point = [float(anchor_loss(start[:, :1] + moves[:, i:i + 1], start[:, :1], hidden[:, :1], out[:, :1]))
                 for i in range(4)]
    assert per_point == pytest.approx([0.0, 1e-4, 1e-4, 1e-4], abs=1e-10)
    assert float(anchor_loss(start + moves, start, hidden)) == pytest.approx(5e-4 / 4)   # without: all pay


def test_head_normals_point_away_from_a_sphere():
    centre = torch.tensor([0.0, 0.02, -0.01])

    def sdf(p):
        return (p - centre).norm(dim=-1) - 0.09

    pts = centre + torch.randn(50, 3, generator=torch.Generator().manual_seed(0)) * 0.1
    n = head_normals(pts, sdf)
    radial = (pts - centre) / (pts - centre).norm(dim=-1, keepdim=True)
    assert torch.allclose(n, radial, atol=1e-4)
