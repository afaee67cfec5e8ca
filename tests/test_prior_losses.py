"""Tests of the hair prior's training losses: the point term and the standoff term."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from vid2haircut.prior.codec import StrandCodec
from vid2haircut.prior.losses import LossWeights, prior_losses

RES, P = 4, 20


def _strands(n: int, seed: int = 0) -> np.ndarray:
    """(n,P,3) strands hanging down (-y) from roots on the plane z = 0, bending out along +z."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, P)[None, :, None]
    roots = np.concatenate([rng.uniform(-0.05, 0.05, (n, 2)), np.zeros((n, 1))], 1)[:, None]
    length = rng.uniform(0.05, 0.2, (n, 1, 1))
    out = rng.uniform(0.005, 0.02, (n, 1, 1))
    return (roots + t * length * np.array([0.0, -1.0, 0.0]) + np.sin(np.pi * t / 2) * out * np.array([0.0, 0.0, 1.0])
            ).astype(np.float32)


@pytest.fixture(scope="module")
def setup():
    pts = _strands(RES * RES)
    codec = StrandCodec.fit(_strands(400, seed=1), k=3 * (P - 1))            # full rank: exact round trip
    roots = torch.as_tensor(pts[:, 0])
    return codec, roots, torch.as_tensor(pts)


def _maps(codec: StrandCodec, strands: torch.Tensor) -> torch.Tensor:
    """(1,K,R,R) map of ``strands`` laid out row-major over the texels."""
    return codec.encode(strands).T.reshape(1, -1, RES, RES)


def _losses(codec, roots, pred, target, weight=1.0, with_sdf=True):
    valid = torch.arange(RES * RES)
    mask = torch.ones(1, RES, RES)
    g = torch.Generator().manual_seed(0)
    sdf = (lambda x: x[..., 2]) if with_sdf else None                        # the "head" is the plane z = 0
    return prior_losses(_maps(codec, pred), torch.full((1, RES, RES), 10.0), _maps(codec, target), mask, valid,
                        codec, LossWeights(n_texels=RES * RES, standoff=weight), g, roots, sdf)


def test_standoff_counts_distance_from_the_head_not_direction(setup):
    codec, roots, target = setup
    same = _losses(codec, roots, target, target)
    assert float(same.points_cm) < 1e-3 and float(same.standoff_cm) < 1e-3
    t = torch.linspace(0.0, 1.0, P)[None, :, None]
    sideways = _losses(codec, roots, target + t * torch.tensor([0.01, 0.0, 0.0]), target)
    outward = _losses(codec, roots, target + t * torch.tensor([0.0, 0.0, 0.01]), target)
    # 1 cm at the tip, 0.5 cm on average along the strand, in both cases ...
    assert float(sideways.points_cm) == pytest.approx(float(outward.points_cm), rel=1e-3)
    assert float(outward.points_cm) == pytest.approx(0.5 * P / (P - 1), rel=1e-3)
    # ... but only moving away from the head changes the standoff
    assert float(sideways.standoff_cm) < 1e-3
    assert float(outward.standoff_cm) == pytest.approx(float(outward.points_cm), rel=1e-3)
    assert float(outward.total) == pytest.approx(float(outward.points_cm + 0.1 * outward.coef + outward.mask_bce
                                                       + outward.standoff_cm), rel=1e-5)


def test_standoff_gradient_moves_a_flat_prediction_out(setup):
    """A prediction flatter than the target: the standoff term's gradient lifts it off the head."""
    codec, roots, target = setup
    flat = target.clone()
    flat[..., 2] *= 0.5
    z = _maps(codec, flat).requires_grad_(True)
    valid = torch.arange(RES * RES)
    terms = prior_losses(z, torch.full((1, RES, RES), 10.0), _maps(codec, target), torch.ones(1, RES, RES), valid,
                         codec, LossWeights(points=0.0, coef=0.0, mask=0.0, n_texels=RES * RES, standoff=1.0),
                         torch.Generator().manual_seed(0), roots, lambda x: x[..., 2])
    terms.total.backward()
    with torch.no_grad():
        stepped = codec.decode_offsets((z - 1e-2 * z.grad).reshape(z.shape[1], -1).T)
    assert float(stepped[..., 2].mean()) > float((flat - flat[:, :1])[:, 1:, 2].mean())


def test_standoff_off_without_head_or_weight(setup):
    codec, roots, target = setup
    pred = target + torch.linspace(0.0, 1.0, P)[None, :, None] * torch.tensor([0.0, 0.0, 0.01])
    no_head = _losses(codec, roots, pred, target, with_sdf=False)
    assert float(no_head.standoff_cm) == 0.0
    off = _losses(codec, roots, pred, target, weight=0.0)
    assert float(off.standoff_cm) > 0.1                                      # reported, not counted
    assert float(off.total) == pytest.approx(float(no_head.total), rel=1e-6)


def test_standoff_setting_is_the_default_with_the_term():
    from vid2haircut.prior.train import SETTINGS, config_fingerprint

    default, standoff = SETTINGS["default"], SETTINGS["standoff"]
    assert standoff.w_standoff > 0 and replace(standoff, w_standoff=0.0) == default
    assert "w_standoff" not in default.to_dict() and standoff.to_dict()["w_standoff"] == standoff.w_standoff
    assert config_fingerprint(standoff, 0) != config_fingerprint(default, 0)
    assert default.loss_weights().standoff == 0.0 and standoff.loss_weights().standoff == standoff.w_standoff
