"""Stage 2 (joint multi-keyframe refinement) on the toy problem: loss decreases, determinism,
resume, file-level run through the command line, and the optional loss terms."""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from vid2haircut.fit.losses import pca_consistency_loss, smoothness_losses
from vid2haircut.fit.scene import render_frames
from vid2haircut.fit.settings import apply_overrides
from vid2haircut.fit.stage2 import checkpoint_state, fit_stage2, Stage2Model
from vid2haircut.fit.toy import write_toy_files
from vid2haircut.fit.visibility import gate_visibility
from vid2haircut.render.numba_backend import numba_available

sys.path.insert(0, str(Path(__file__).parent))
from stage2_common import FAST, cfg as _cfg, make_toy, start as _start  # noqa: E402


@pytest.fixture(scope="module")
def toy():
    return make_toy()


def test_loss_decreases(toy):
    z0, m0 = _start(toy)
    res = fit_stage2(toy.data, toy.codec, _cfg(iterations=12), z0, m0, progress=False)
    t = res.history.terms
    image = [sum(t[k][i] for k in ("silhouette", "direction")) for i in (0, -1)]
    assert image[1] < 0.8 * image[0]
    assert not np.isnan(t["motion"][-1]) and np.isnan(t["motion"][0])    # the MLP joins after the canonical steps
    assert res.render.silhouette.shape == (3, 40, 40)


def test_same_seed_same_output_and_resume(toy):
    z0, m0 = _start(toy)
    states = {}

    def keep(step, model, trainer):
        if step == 3:
            states["ck"] = copy.deepcopy(checkpoint_state(step, model, trainer))

    a = fit_stage2(toy.data, toy.codec, _cfg(), z0, m0, progress=False, on_step=keep)
    b = fit_stage2(toy.data, toy.codec, _cfg(), z0, m0, progress=False)
    assert torch.equal(a.z, b.z) and torch.equal(a.guides, b.guides)
    for pa, pb in zip(a.extra["deform"].parameters(), b.extra["deform"].parameters()):
        assert torch.equal(pa, pb)
    c = fit_stage2(toy.data, toy.codec, _cfg(), z0, m0, progress=False, resume=states["ck"])
    assert len(c.history.total) == FAST["iterations"]
    assert torch.allclose(a.z, c.z, atol=1e-6)
    other = fit_stage2(toy.data, toy.codec, _cfg(seed=5), z0, m0, progress=False)
    assert not torch.equal(other.extra["deform"].frame_codes.weight, a.extra["deform"].frame_codes.weight)


def test_lr_decay_follows_the_step_and_survives_resume(toy):
    z0, m0 = _start(toy)
    cfg = _cfg(lr_decay_steps=6, lr_final=0.2)
    states, lrs = {}, []

    def keep(step, model, trainer):
        lrs.append([g["lr"] for opt in trainer.optimizers for g in opt.param_groups])
        if step == 4:
            states["ck"] = copy.deepcopy(checkpoint_state(step, model, trainer))

    a = fit_stage2(toy.data, toy.codec, cfg, z0, m0, progress=False, on_step=keep)
    assert lrs[0][0] == pytest.approx(cfg.lr_z) and lrs[-1][0] == pytest.approx(0.2 * cfg.lr_z)
    assert lrs[-1][1] == pytest.approx(0.2 * cfg.lr_mlp)                  # every group decays
    c = fit_stage2(toy.data, toy.codec, cfg, z0, m0, progress=False, resume=states["ck"])
    assert torch.allclose(a.z, c.z, atol=1e-6)
    plain = fit_stage2(toy.data, toy.codec, _cfg(), z0, m0, progress=False)
    assert not torch.allclose(a.z, plain.z, atol=1e-5)


def _stage2_parser() -> argparse.ArgumentParser:
    from vid2haircut.cli import stage2

    parser = argparse.ArgumentParser()
    stage2.register(parser.add_subparsers())
    return parser


def test_files_cli_outputs_and_resume(toy, tmp_path):
    from vid2haircut.fit.pipeline import run_stage1
    from vid2haircut.io.strand_formats import load_strands

    files = write_toy_files(toy, tmp_path / "data")
    s1 = tmp_path / "s1"
    run_stage1(files["dataset_root"], "toy", files["keyframes"], files["head"], files["targets"], s1,
               codec_path=files["codec"], progress=False,
               settings={"iterations": 2, "map_res": 12, "render": {"n_points": 16, "size": 40}, "n_dense": 200})
    out = tmp_path / "s2"
    argv = ["stage2", "--root", str(files["dataset_root"]), "--subject", "toy", "--seq", "HAIR",
            "--keyframes", str(files["keyframes"]), "--head", str(files["head"]), "--targets", str(files["targets"]),
            "--stage1-dir", str(s1), "--out", str(out), "--no-progress",
            "--settings", json.dumps({**FAST, "render": {"n_points": 16, "size": 40}})]
    args = _stage2_parser().parse_args(argv)
    assert args.func(args) == 0
    for rel in ("strands.npz", "guides.npz", "hairmap.npz", "deform.pt", "checkpoint.pt", "loss_curve.png",
                "stage2.json", *(f"renders/frame_{t:05d}.png" for t in range(3))):
        assert (out / rel).is_file(), rel
    dense = load_strands(out / "strands.npz")
    assert dense.n_strands == 300 and dense.head_model == "proxy-v1"
    first = json.loads((out / "stage2.json").read_text())
    assert first["resumed_from_step"] is None and first["keyframes"] == [0, 1, 2]
    assert 0.0 <= first["carved_fraction"] < 1.0 and first["config"]["carve_tolerance"] == 1.0
    assert first["machine"]["render_compaction"] and first["machine"]["cpu"]
    assert first["compositing"] == "bins"  # (the model drawn with; "auto" would name it)
    assert args.func(args) == 0                                             # again: resumes at the end
    again = json.loads((out / "stage2.json").read_text())
    assert again["resumed_from_step"] == FAST["iterations"] - 1
    assert np.array_equal(load_strands(out / "strands.npz").points, dense.points)
    # a decoding-only setting resumes the finished fit and decodes it again
    args = _stage2_parser().parse_args(argv[:-1] + [json.dumps({**FAST, "render": {"n_points": 16, "size": 40},
                                                                "carve_tolerance": 0.0})])
    assert args.func(args) == 0
    plain = json.loads((out / "stage2.json").read_text())
    assert plain["resumed_from_step"] == FAST["iterations"] - 1 and plain["carved_fraction"] == 0.0
    assert plain["config"]["carve_tolerance"] == 0.0 and plain["signature"] == first["signature"]
    # fewer keyframes is one setting
    args = _stage2_parser().parse_args(argv[:-1] + [json.dumps({**FAST, "iterations": 2, "n_keyframes": 1,
                                                                "render": {"n_points": 16, "size": 40}})])
    assert args.func(args) == 0
    assert json.loads((out / "stage2.json").read_text())["keyframes"] == [0]


def test_silhouette_opacity_thins_only_the_silhouette(toy):
    """The silhouette term sees translucent guides (a second render); direction, depth and visibility
    stay those of the opaque render, and the silhouette still passes a gradient to the points."""
    model = Stage2Model(toy.data, toy.codec, _cfg(), *_start(toy))
    pts = model.canonical()[:, model.layout.render_index].detach()[None].requires_grad_(True)
    frames = torch.tensor([0])
    opaque = render_frames(pts, toy.data, frames, apply_overrides(model.cfg.render, {"silhouette_opacity": 1.0}))
    thin = render_frames(pts, toy.data, frames, apply_overrides(model.cfg.render, {"silhouette_opacity": 0.3}))
    s_thin, s_opaque = thin.silhouette.detach(), opaque.silhouette.detach()
    assert float(s_opaque.max()) > 0.9
    assert bool((s_thin <= s_opaque + 1e-6).all())
    # translucent guides cover less: only overlaps of several reach full coverage
    assert float(s_thin.mean()) < 0.8 * float(s_opaque.mean())
    for name in ("direction", "depth", "mask", "visibility"):
        assert torch.equal(getattr(thin, name), getattr(opaque, name)), name
    (g,) = torch.autograd.grad(thin.silhouette.sum(), pts)
    assert float(g.abs().sum()) > 0.0
    with pytest.raises(ValueError, match="silhouette_opacity"):
        render_frames(pts, toy.data, frames, apply_overrides(model.cfg.render, {"silhouette_opacity": 0.0}))


def test_gravity_term_is_in_the_loss_only_when_weighted(toy):
    z0, m0 = _start(toy)
    assert "gravity" not in Stage2Model(toy.data, toy.codec, _cfg(), z0, m0).get_loss_dict(0)
    model = Stage2Model(toy.data, toy.codec, _cfg(weights={"gravity": 0.1}), z0, m0)
    losses = model.get_loss_dict(0)
    from vid2haircut.fit.losses import gravity_loss
    expect = gravity_loss(model.canonical()[:, model.layout.render_index])
    assert float(losses["gravity"].detach()) == pytest.approx(float(expect.detach()), rel=1e-12)


def test_depth_alignment_reaches_the_depth_term_and_is_checked(toy):
    z0, m0 = _start(toy)
    terms = {a: float(Stage2Model(toy.data, toy.codec, _cfg(depth_align=a), z0, m0).get_loss_dict(0)["depth"].detach())
             for a in ("quantile", "affine")}
    assert terms["quantile"] != terms["affine"]
    with pytest.raises(ValueError, match="depth_align"):
        Stage2Model(toy.data, toy.codec, _cfg(depth_align="median"), z0, m0)


def test_outside_term_pulls_stray_strands_and_respects_the_gate(toy):
    z0, m0 = _start(toy)
    assert "outside" not in Stage2Model(toy.data, toy.codec, _cfg(), z0, m0).get_loss_dict(0)
    model = Stage2Model(toy.data, toy.codec, _cfg(weights={"outside": 1.0}, visibility_unit="strand"), z0, m0)
    assert toy.data.outside is not None and float(toy.data.outside.max()) > 1.0
    canon = model.canonical()[:, model.layout.render_index].detach().requires_grad_(True)
    frames = torch.arange(3)
    moved, _, _ = model.deformed(canon, frames, 0.0)
    out = render_frames(moved, toy.data, frames, model.cfg.render)
    model.gate.set_visibility(gate_visibility(out.visibility, model.cfg.visibility_unit))
    from vid2haircut.fit.scene import outside_term
    term = outside_term(moved, toy.data, frames, model.cfg.outside_tolerance)
    assert float(term.detach()) > 0.0                         # the mean strand sticks out of the toy's hair
    term.backward()
    seen = out.visibility.any(-1).any(0)                      # (N,) strands some frame shows
    g = canon.grad.norm(dim=-1).amax(-1)
    assert float(g[~seen].max()) == 0.0 and float(g[seen].max()) > 0.0
    left = {}
    for w in (0.0, 100.0):                                    # after the same steps, with and without the term
        cfg = _cfg(iterations=12, weights={"outside": w}, switches={"use_deformation": False})
        res = fit_stage2(toy.data, toy.codec, cfg, z0, m0, progress=False)
        pts = res.guides[:, model.layout.render_index][None].expand(3, -1, -1, -1)
        left[w] = float(outside_term(pts, toy.data, frames, model.cfg.outside_tolerance))
    assert left[100.0] < 0.7 * left[0.0]


def test_pca_change_form_compares_the_change_from_the_start_map(toy):
    """``pca_change``: the PCA consistency sees z - z_start, so at the start it is zero even for a
    rough start map, and it pulls an unseen texel's change towards its neighbours' change."""
    _, m0 = _start(toy)
    gen = torch.Generator().manual_seed(0)
    z0 = 0.5 * torch.randn(toy.z_gt.shape, generator=gen, dtype=toy.z_gt.dtype)
    plain = Stage2Model(toy.data, toy.codec, _cfg(), z0, m0)
    change = Stage2Model(toy.data, toy.codec, _cfg(pca_change=True), z0, m0)
    assert float(plain.get_loss_dict(0)["pca"]) > 0.0
    assert float(change.get_loss_dict(0)["pca"]) == 0.0
    hair = plain.layout.hair                              # observed() only after a render has set what is seen
    assert bool(plain.observed().any()) and bool((hair & ~plain.observed()).any())
    with torch.no_grad():
        change.zmap.delta.add_(torch.randn(change.zmap.delta.shape, generator=gen, dtype=z0.dtype))
    got = change.get_loss_dict(0)["pca"]                  # (this render updates what counts as observed)
    expect = pca_consistency_loss((change.z - z0)[change.cfg.pca_from:], hair, change.observed())
    assert float(got) > 0.0 and float(got) == pytest.approx(float(expect), rel=1e-12)


def test_pca_from_leaves_the_coarse_components_to_the_other_terms(toy):
    """``pca_from``: the PCA consistency covers only components pca_from.. (its gradient on the coarser
    ones is exactly zero); with pca_from >= K it is zero, and a negative value is refused."""
    _, m0 = _start(toy)
    gen = torch.Generator().manual_seed(1)
    z0 = 0.5 * torch.randn(toy.z_gt.shape, generator=gen, dtype=toy.z_gt.dtype)
    k = 2
    model = Stage2Model(toy.data, toy.codec, _cfg(pca_from=k), z0, m0)
    model.get_loss_dict(0)                                # a render sets what is observed
    hair, observed = model.layout.hair, model.observed()
    assert bool((hair & ~observed).any())
    pca = model.get_loss_dict(0)["pca"]
    assert float(pca) == pytest.approx(float(pca_consistency_loss(model.z[k:], hair, model.observed())), rel=1e-12)
    grad = torch.autograd.grad(pca, model.zmap.delta)[0]
    assert bool((grad[k:] != 0).any()) and bool((grad[:k] == 0).all())
    none = Stage2Model(toy.data, toy.codec, _cfg(pca_from=z0.shape[0]), z0, m0)
    assert float(none.get_loss_dict(0)["pca"]) == 0.0
    with pytest.raises(ValueError, match="pca_from"):
        Stage2Model(toy.data, toy.codec, _cfg(pca_from=-1), z0, m0)
    with pytest.raises(ValueError, match="pca_from"):
        apply_overrides(model.cfg, {"pca_from": -1})


@pytest.mark.parametrize("key,term", [("smooth_direction_from", "smooth_direction"),
                                      ("smooth_length_from", "smooth_length")])
def test_smoothness_from_moves_only_the_fine_components(toy, key, term):
    """``smooth_direction_from`` / ``smooth_length_from``: the smoothness term keeps its value (it
    sees the whole map) but its gradient on the coarser components is exactly zero; the other
    smoothness term is untouched; a negative value is refused."""
    _, m0 = _start(toy)
    gen = torch.Generator().manual_seed(2)
    z0 = 0.5 * torch.randn(toy.z_gt.shape, generator=gen, dtype=toy.z_gt.dtype)
    k = 2
    # the absolute direction form: the relative one is zero, without gradient, at the start
    every = {"smooth_direction_from": 0, "smooth_length_from": 0, "smooth_direction_form": "absolute"}
    full = Stage2Model(toy.data, toy.codec, _cfg(**every), z0, m0).get_loss_dict(0)
    model = Stage2Model(toy.data, toy.codec, _cfg(**{**every, key: k}), z0, m0)
    split = model.get_loss_dict(0)
    other = "smooth_length" if term == "smooth_direction" else "smooth_direction"
    for name in (term, other):
        assert float(split[name]) == pytest.approx(float(full[name]), rel=1e-12)
    grad = torch.autograd.grad(split[term], model.zmap.delta, retain_graph=True)[0]
    assert bool((grad[k:] != 0).any()) and bool((grad[:k] == 0).all())
    grad_other = torch.autograd.grad(split[other], model.zmap.delta)[0]
    assert bool((grad_other[:k] != 0).any())
    with pytest.raises(ValueError, match=key):
        Stage2Model(toy.data, toy.codec, _cfg(**{key: -1}), z0, m0)
    with pytest.raises(ValueError, match=key):
        apply_overrides(model.cfg, {key: -1})


@pytest.mark.parametrize("seen_w,unseen_w", [(0.0, 1.0), (1.0, 0.0), (0.3, 0.5)])
def test_smooth_seen_weights_scale_observed_and_unobserved_guides(toy, seen_w, unseen_w):
    """``smooth_seen_weight`` / ``smooth_unseen_weight``: the smoothness terms equal
    :func:`smoothness_losses` with those factors on the guides some keyframe observed and on the
    others; 1 and 1 are the plain terms; a negative factor is refused."""
    z0, m0 = _start(toy)
    absolute = {"smooth_direction_form": "absolute"}      # the relative form is zero at the start
    plain = Stage2Model(toy.data, toy.codec, _cfg(**absolute), z0, m0).get_loss_dict(0)
    model = Stage2Model(toy.data, toy.codec, _cfg(smooth_seen_weight=seen_w, smooth_unseen_weight=unseen_w,
                                                  **absolute), z0, m0)
    out = model.get_loss_dict(0)
    seen = model._seen_guides()
    assert bool(seen.any()) and bool((~seen).any())
    canon = model.canonical()[:, model.layout.render_index]
    factor = torch.where(seen, seen_w, unseen_w).to(canon.dtype)
    ref = smoothness_losses(canon, model.layout.graph, model.cfg.weights.smooth_length_back
                            / model.cfg.weights.smooth_length, length_scale=model.cfg.smooth_length_scale,
                            direction_scale=model.cfg.smooth_direction_scale, strand_weight=factor,
                            reference_directions=model.start_directions,
                            direction_form=model.cfg.smooth_direction_form)
    for name in ("smooth_length", "smooth_direction"):
        assert float(out[name]) == pytest.approx(float(ref[name]), rel=1e-9)
        assert float(out[name]) < float(plain[name])
    for key in ("smooth_seen_weight", "smooth_unseen_weight"):
        with pytest.raises(ValueError, match=key):
            apply_overrides(model.cfg, {key: -0.5})


@pytest.mark.parametrize("form", ["relative", "change"])
def test_smooth_direction_forms_measure_against_the_start(toy, form):
    """``smooth_direction_form`` "relative" / "change": the direction smoothness compares with the
    Stage 2 start, so it is zero at the start however rough the start map, and grows once the map
    moves; the length term is the plain one."""
    _, m0 = _start(toy)
    gen = torch.Generator().manual_seed(0)
    z0 = 0.5 * torch.randn(toy.z_gt.shape, generator=gen, dtype=toy.z_gt.dtype)
    plain = Stage2Model(toy.data, toy.codec, _cfg(smooth_direction_form="absolute"), z0, m0).get_loss_dict(0)
    model = Stage2Model(toy.data, toy.codec, _cfg(smooth_direction_form=form), z0, m0)
    out = model.get_loss_dict(0)
    assert float(plain["smooth_direction"]) > 0.0
    assert float(out["smooth_direction"]) == pytest.approx(0.0, abs=1e-12)
    assert float(out["smooth_length"]) == float(plain["smooth_length"])
    with torch.no_grad():
        model.zmap.delta.add_(torch.randn(model.zmap.delta.shape, generator=gen, dtype=z0.dtype))
    assert float(model.get_loss_dict(0)["smooth_direction"]) > 0.0


def test_bad_stage_files_and_outputs(toy, tmp_path, caplog):
    """A folder where an output file goes stops Stage 1 before the fit (the old outputs stay whole);
    an unreadable or foreign checkpoint is set aside (a warning, a fresh fit); a truncated hair map
    is named."""
    import logging

    from vid2haircut.fit.pipeline import run_stage1, run_stage2

    files = write_toy_files(toy, tmp_path / "data")
    common = (files["dataset_root"], "toy", files["keyframes"], files["head"], files["targets"])
    s1_settings = {"iterations": 2, "map_res": 12, "render": {"n_points": 16, "size": 40}, "n_dense": 50}
    s1 = tmp_path / "s1"
    run_stage1(*common, s1, codec_path=files["codec"], progress=False, settings=s1_settings)
    old = (s1 / "strands.npz").read_bytes()
    (s1 / "loss_curve.png").unlink()
    (s1 / "loss_curve.png").mkdir()
    with pytest.raises(IsADirectoryError, match=r"loss_curve\.png: is a folder"):
        run_stage1(*common, s1, codec_path=files["codec"], progress=False, settings={**s1_settings, "seed": 5})
    assert (s1 / "strands.npz").read_bytes() == old
    (s1 / "loss_curve.png").rmdir()

    out = tmp_path / "s2"
    out.mkdir()
    s2_settings = {**FAST, "iterations": 2, "render": {"n_points": 16, "size": 40}, "n_dense": 50}
    for junk in (b"PK\x03\x04 not a whole checkpoint", None):
        if junk is None:
            torch.save([1, 2], out / "checkpoint.pt")
        else:
            (out / "checkpoint.pt").write_bytes(junk)
        with caplog.at_level(logging.WARNING, logger="vid2haircut.fit.pipeline"):
            record = run_stage2(*common, s1, out, settings=s2_settings, progress=False)
        assert record["resumed_from_step"] is None
        assert "checkpoint.pt" in caplog.text and "starting afresh" in caplog.text
        caplog.clear()

    (s1 / "hairmap.npz").write_bytes((s1 / "hairmap.npz").read_bytes()[:500])
    with pytest.raises(ValueError, match=r"hairmap\.npz: not a hair map \.npz \(BadZipFile"):
        run_stage2(*common, s1, tmp_path / "s2b", settings=s2_settings, progress=False)


def test_signature_of_the_compositing_models():
    """A checkpoint made before ``render.compositing`` existed still resumes with the binned model
    (the default): neither it, ``t_min`` nor ``gate_bins_every`` enters its signature. "auto" signs
    as the model it names on the fit's device ("exact" on the CPU with numba), and the exact model's
    ``gate_bins_every`` is part of its signature."""
    from types import SimpleNamespace

    from vid2haircut.fit.config import Stage2Config
    from vid2haircut.fit.pipeline import _signature

    data = SimpleNamespace(frames=[0, 4], mask=torch.ones(2, 4, 4), cam_from_head=torch.eye(4).expand(2, 4, 4),
                           K=torch.eye(3).expand(2, 3, 3))
    z, mask = torch.zeros(3, 2, 2), torch.ones(2, 2, dtype=torch.bool)

    def sig(over):
        return _signature(apply_overrides(Stage2Config(), over), data, z, mask)

    bins = sig({})
    assert sig({"render": {"compositing": "bins"}}) == bins
    assert sig({"render": {"compositing": "bins", "t_min": 1e-3}, "gate_bins_every": 10}) == bins
    exact = sig({"render": {"compositing": "exact"}})
    assert exact != bins and sig({"render": {"compositing": "exact"}, "gate_bins_every": 10}) not in (bins, exact)
    if numba_available():
        assert sig({"render": {"compositing": "auto"}}) == exact
        assert sig({"render": {"compositing": "auto", "t_min": 1e-3}}) != exact
