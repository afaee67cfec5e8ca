"""Neighbour-strand smoothness of Stage 2 (vid2haircut.fit.losses): the texel graph, length,
direction (its absolute, relative and change forms) and tip height, and the robust penalty."""

from __future__ import annotations

import math

import pytest
import torch

from vid2haircut.fit.config import Stage2Config
from vid2haircut.fit.losses import robust, smoothness_losses, texel_graph, tip_height_loss, unit_directions
from vid2haircut.fit.settings import apply_overrides


def test_texel_graph_and_smoothness():
    # guides on a full 3x3 block of a 4x4 map: 6 horizontal + 6 vertical pairs
    idx = torch.tensor([r * 4 + c for r in range(3) for c in range(3)])
    g = texel_graph(idx, 4, back_v=0.3)
    assert g.pairs.shape == (12, 2)
    assert int(g.back.sum()) == 5                 # pairs whose first texel is in row 0 (v = 0.125 < 0.3)
    line = torch.stack([torch.zeros(5), torch.zeros(5), torch.linspace(0, 0.1, 5)], -1)
    same = line[None].repeat(9, 1, 1) + torch.tensor([0.01, 0.0, 0.0]) * torch.arange(9.0)[:, None, None]
    out = smoothness_losses(same, g, back_weight=100.0)
    assert float(out["smooth_length"]) == pytest.approx(0.0, abs=1e-7)
    assert float(out["smooth_direction"]) == pytest.approx(0.0, abs=1e-6)
    # lengths varying linearly over the map are smooth too (a Laplacian, not a difference)
    big = torch.tensor([r * 8 + c for r in range(6) for c in range(6)])
    ramp = line[None].repeat(36, 1, 1)
    ramp[:, :, 2] *= (1.0 + 0.1 * (big % 8))[:, None]             # +1 cm per column: |dL| = 0.005 per pair
    lap = float(smoothness_losses(ramp, texel_graph(big, 8), back_weight=1.0)["smooth_length"])
    assert lap == pytest.approx((2 * (4 * 0.01 / 3 + 2 * 0.01 / 2)) / 36, rel=1e-3)  # only the border columns
    longer = same.clone()
    longer[4, :, 2] *= 1.5                         # the centre texel is 5 cm longer
    out = smoothness_losses(longer, g, back_weight=1.0)
    # centre: |0.15 - 0.1|; its 4 edge neighbours (3 neighbours each, one of them the centre): 0.05 / 3
    assert float(out["smooth_length"]) == pytest.approx((0.05 + 4 * 0.05 / 3) / 9, rel=1e-4)
    heavy = smoothness_losses(longer, g, back_weight=100.0)["smooth_length"]   # row 0 is the back
    assert float(heavy) == pytest.approx((0.05 + 3 * 0.05 / 3 + 100 * 0.05 / 3) / 9, rel=1e-4)
    # direction: a crossing neighbour costs 1 - cos; a parallel one far away costs nothing
    two = texel_graph(torch.tensor([0, 1]), 4)
    cross = torch.stack([line, line[:, [2, 1, 0]] - torch.tensor([0.05, 0.0, -0.05])])
    assert float(smoothness_losses(cross, two)["smooth_direction"]) == pytest.approx(1.0, abs=1e-5)
    far = torch.stack([line, line + torch.tensor([0.05, 0.0, 0.0])])
    assert float(smoothness_losses(far, two)["smooth_direction"]) == pytest.approx(0.0, abs=1e-6)
    # per-guide factors: ones change nothing; a zero drops the guide's own length residual, and a
    # pair takes the mean of its two guides' factors
    base = smoothness_losses(longer, g, back_weight=1.0)
    ones = smoothness_losses(longer, g, back_weight=1.0, strand_weight=torch.ones(9))
    assert all(float(ones[k]) == float(base[k]) for k in base)
    centre = torch.ones(9)
    centre[4] = 0.0
    out = smoothness_losses(longer, g, back_weight=1.0, strand_weight=centre)
    assert float(out["smooth_length"]) == pytest.approx((4 * 0.05 / 3) / 9, rel=1e-4)
    half = smoothness_losses(cross, two, strand_weight=torch.tensor([1.0, 0.0]))
    assert float(half["smooth_direction"]) == pytest.approx(0.5, abs=1e-5)


def test_robust_smoothness_keeps_small_residuals_and_releases_edges():
    x = torch.tensor([0.0, 1e-4, 0.01, 1.0], requires_grad=True)
    r = robust(x, 0.01)
    assert torch.equal(robust(x, 0.0), x)
    v = r.detach()
    assert float(v[1]) == pytest.approx(1e-4, rel=0.011) and float(v[2]) == pytest.approx(0.005)
    assert float(v[3]) < 0.01                                   # saturates at the scale
    r.sum().backward()
    assert float(x.grad[0]) == pytest.approx(1.0) and float(x.grad[3]) < 1e-3  # no pull across an edge
    # a fringe: the centre guide 20 cm shorter than its neighbours; the plain Laplacian pulls it
    # with a gradient independent of the jump, the robust one barely
    idx = torch.tensor([r * 4 + c for r in range(3) for c in range(3)])
    g = texel_graph(idx, 4, back_v=0.0)
    line = torch.stack([torch.zeros(9), torch.zeros(9), torch.linspace(0, 0.3, 9)], -1)
    pts = (line[None].repeat(9, 1, 1) + torch.tensor([0.01, 0.0, 0.0]) * torch.arange(9.0)[:, None, None])
    pts[4, :, 2] *= 1.0 / 3.0
    grads = []
    for scale in (0.0, 0.01):
        p = pts.clone().requires_grad_(True)
        smoothness_losses(p, g, back_weight=1.0, length_scale=scale)["smooth_length"].backward()
        grads.append(float(p.grad[4].norm()))
    assert grads[1] < 0.02 * grads[0]


def test_tip_height_follows_the_cut_line_not_the_roots():
    # 3x3 guides hanging straight down (-y) from roots at different heights, all ending at y = -0.2
    idx = torch.tensor([r * 4 + c for r in range(3) for c in range(3)])
    g = texel_graph(idx, 4, back_v=0.0)
    roots = torch.stack([0.01 * (torch.arange(9.0) % 3), 0.05 * (torch.arange(9.0) // 3), torch.zeros(9)], -1)
    t = torch.linspace(0.0, 1.0, 6)[:, None]
    drop = torch.tensor([0.0, -0.2, 0.0])
    cut = torch.stack([r + t * (drop - r * torch.tensor([0.0, 1.0, 0.0])) for r in roots])   # (9,6,3)
    assert float(cut[:, -1, 1].std()) < 1e-6 and float(cut[:, 0, 1].std()) > 0.01
    assert float(tip_height_loss(cut, g)) == pytest.approx(0.0, abs=1e-7)
    assert float(smoothness_losses(cut, g, back_weight=1.0)["smooth_length"]) > 0.005    # lengths differ
    # a hidden guide ending 4 cm higher: the loss pulls its tip down, and only along the up axis
    short = cut.clone().requires_grad_(True)
    with torch.no_grad():
        short[4, -1, 1] += 0.04
    loss = tip_height_loss(short, g)
    assert loss.item() == pytest.approx((0.04 + 4 * 0.04 / 3) / 9, rel=1e-4)
    loss.backward()
    assert float(short.grad[4, -1, 1]) > 0.0                        # descent lowers the tip
    assert float(short.grad[4, -1, [0, 2]].abs().max()) == 0.0 and float(short.grad[4, :-1].abs().max()) == 0.0
    # edge-preserving: a fringe 20 cm above its neighbours is barely pulled
    fringe = cut.clone().requires_grad_(True)
    with torch.no_grad():
        fringe[4, -1, 1] += 0.2
    tip_height_loss(fringe, g, scale=0.01).backward()
    assert float(fringe.grad[4, -1, 1]) < 0.02 * float(short.grad[4, -1, 1])
    assert float(tip_height_loss(cut[:1], texel_graph(torch.tensor([0]), 4))) == 0.0   # no neighbours


def _tilted(angle: float, x0: float = 0.0, n: int = 5) -> torch.Tensor:
    """(n,3) a 10 cm strand from (x0, 0, 0) tilted by ``angle`` (radians) from +z towards +x."""
    s = torch.linspace(0.0, 0.1, n, dtype=torch.float64)[:, None]
    d = torch.tensor([math.sin(angle), 0.0, math.cos(angle)], dtype=torch.float64)
    return torch.tensor([x0, 0.0, 0.0], dtype=torch.float64) + s * d


def test_direction_smoothness_forms_measure_against_the_reference():
    """"relative": only a loss of alignment against the reference pair costs, so a fanned-out start
    is kept; "change": the difference of the two strands' changes of direction; "absolute" costs
    the fan itself."""
    two = texel_graph(torch.tensor([0, 1]), 4)
    fan = torch.stack([_tilted(0.0), _tilted(0.15, 0.002)])          # neighbours 8.6 degrees apart
    assert float(smoothness_losses(fan, two)["smooth_direction"]) > 1e-3
    for form in ("relative", "change"):
        at_start = smoothness_losses(fan, two, reference_directions=unit_directions(fan), direction_form=form)
        assert float(at_start["smooth_direction"]) == pytest.approx(0.0, abs=1e-12)
        moved = fan + torch.tensor([0.0, 0.01, 0.0], dtype=torch.float64)   # both shifted alike
        same = smoothness_losses(moved, two, reference_directions=unit_directions(fan), direction_form=form)
        assert float(same["smooth_direction"]) == pytest.approx(0.0, abs=1e-12)
    # the first strand turns away from its neighbour: both forms cost, and pull the neighbour along
    wider = torch.stack([_tilted(-0.15), _tilted(0.15, 0.002)]).requires_grad_(True)
    for form in ("relative", "change"):
        out = smoothness_losses(wider, two, reference_directions=unit_directions(fan), direction_form=form)["smooth_direction"]
        assert float(out.detach()) > 1e-4
        (grad,) = torch.autograd.grad(out, wider)
        assert float(grad[1, -1, 0]) > 0.0       # descent moves the neighbour's tip towards -x
    # turning towards each other costs nothing in the relative form, something in the change form
    closer = torch.stack([_tilted(0.1), _tilted(0.15, 0.002)])
    rel = smoothness_losses(closer, two, reference_directions=unit_directions(fan), direction_form="relative")["smooth_direction"]
    chg = smoothness_losses(closer, two, reference_directions=unit_directions(fan), direction_form="change")["smooth_direction"]
    assert float(rel) == 0.0 and float(chg) > 1e-4
    with pytest.raises(ValueError, match="reference directions"):
        smoothness_losses(fan, two, direction_form="relative")
    with pytest.raises(ValueError, match="direction_form"):
        smoothness_losses(fan, two, reference_directions=unit_directions(fan), direction_form="sideways")
    with pytest.raises(ValueError, match="smooth_direction_form"):
        apply_overrides(Stage2Config(), {"smooth_direction_form": "sideways"})
    assert apply_overrides(Stage2Config(), {"smooth_direction_form": "relative"}).smooth_direction_form == "relative"
