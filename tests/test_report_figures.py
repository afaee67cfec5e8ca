"""Report figures: turntable strips, scalp coverage maps and metrics tables on tiny inputs."""

import argparse
import json

import cv2
import numpy as np
import pytest

from vid2haircut.camera import save_cameras
from vid2haircut.cli import figures as cli_figures
from vid2haircut.head import get_head, texel_uv
from vid2haircut.io.atomic import write_json, write_npz
from vid2haircut.io.strand_formats import save_strands
from vid2haircut.report import TurntableStyle, render_views, scalp_coverage, turntable_strip
from vid2haircut.report.metrics_table import metrics_table_rst
from vid2haircut.report.turntable import framing_camera, view_pose
from vid2haircut.strands import StrandSet
from vid2haircut.synth.sequence import make_camera

SIZE = 64


@pytest.fixture(scope="module")
def head():
    return get_head("proxy-v1")


def _hair(head, res=24, p=8, length=0.08, droop=0.5):
    """Strands on every scalp texel of a res x res UV grid: out along the normal, bending down."""
    uv = texel_uv(res)[head.scalp_mask(res)]
    roots, normals = head.scalp_uv_to_root(uv)
    s = np.linspace(0.0, 1.0, p)[None, :, None]
    down = np.array([0.0, -1.0, 0.0])
    pts = roots[:, None] + length * (s * (1 - droop) * normals[:, None] + droop * s * s * down)
    return StrandSet(pts.astype(np.float32), head_model="proxy-v1")


def _parse(argv):
    parser = argparse.ArgumentParser()
    cli_figures.register(parser.add_subparsers(dest="command"))
    return parser.parse_args(argv)


def test_turntable_has_hair_in_every_view(head):
    style = TurntableStyle(size=SIZE)
    hair = _hair(head)
    cam = framing_camera(head, [hair.points], style)
    frames = render_views(hair, head, style, cam)
    bald = render_views(None, head, style, cam)
    assert len(frames) == 4
    for (view, _), f, b in zip(style.views, frames, bald):
        assert f.image.shape[0] == SIZE and SIZE // 3 < f.image.shape[1] <= SIZE
        assert f.hair.sum() > 0.02 * SIZE * SIZE, view                      # hair pixels in every view
        assert b.hair.sum() == 0
        assert np.abs(f.image.astype(int) - b.image).sum() > 0, view         # the hair changes the picture
    # the back view sees more hair than the front view (the face is bare)
    assert frames[3].hair.sum() > frames[0].hair.sum()

    strip = turntable_strip(hair, head, gt=hair.subset(np.arange(0, hair.n_strands, 2)), style=style)
    width = frames[0].image.shape[1]
    assert strip.shape == (2 * SIZE, 4 * width, 3) and strip.dtype == np.uint8
    again = turntable_strip(hair, head, style=style)
    assert again.shape == (SIZE, 4 * width, 3)
    assert np.array_equal(again[4:SIZE], strip[4:SIZE])                     # same first row, deterministic


def test_turntable_thins_large_sets(head):
    hair = _hair(head)
    style = TurntableStyle(size=SIZE, max_strands=40)
    cam = framing_camera(head, [hair.points], style)
    full = render_views(hair, head, style=TurntableStyle(size=SIZE), camera=cam)[0].hair.sum()
    thin = render_views(hair, head, style, cam)[0].hair.sum()
    assert 0 < thin < full


def test_turntable_cli(head, tmp_path):
    hair = _hair(head, res=12)
    save_strands(tmp_path / "pred.npz", hair)
    save_strands(tmp_path / "gt.npz", hair)
    out = tmp_path / "fig" / "turntable.png"
    args = _parse(["figures", "turntable", "--strands", str(tmp_path / "pred.npz"), "--gt",
                   str(tmp_path / "gt.npz"), "--size", str(SIZE), "--out", str(out)])
    assert args.func(args) == 0
    img = cv2.imread(str(out))
    assert img.shape[0] == 2 * SIZE and 4 * SIZE // 3 < img.shape[1] <= 4 * SIZE
    bad = _parse(["figures", "turntable", "--strands", str(tmp_path / "nope.npz"), "--out", str(out)])
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        bad.func(bad)
    assert cv2.imread(str(out)).shape == img.shape                          # the old figure is untouched


def _front_back(cov, res):
    v = ((np.arange(res) + 0.5) / res)[:, None]
    front = cov.mask & (v > 0.7)        # v grows towards the face
    back = cov.mask & (v < 0.3)
    return cov.counts[front].mean(), cov.counts[back].mean()


def test_coverage_front_only_keyframes(head):
    cam = make_camera(head, 96, 96)
    poses = np.stack([view_pose(a) for a in (-25.0, 0.0, 25.0)])
    cov = scalp_coverage(head, cam, poses, res=32)
    assert cov.counts.shape == (32, 32) and cov.seen.shape == (3, 32, 32)
    assert not cov.counts[~cov.mask].any() and cov.counts.max() <= 3
    front, back = _front_back(cov, 32)
    assert front > 1.5 and back == 0.0
    # keyframes all around the head see (nearly) all of it, the back included
    ring = scalp_coverage(head, cam, np.stack([view_pose(a) for a in range(0, 360, 60)]), res=32)
    assert ring.seen_fraction > 0.9 > cov.seen_fraction
    assert _front_back(ring, 32)[1] > 1.0


def test_coverage_cli(head, tmp_path):
    root = tmp_path / "data"
    cam = make_camera(head, 96, 96)
    save_cameras(root / "subj" / "calibration" / "camera_params.json", {"cam0": cam})
    frames = np.array([0, 5, 9])
    write_json(tmp_path / "keyframes.json", {"frames": [0, 5, 9, 12], "reference": 5, "serial": "cam0"})
    write_npz(tmp_path / "head.npz", head_model=np.array("proxy-v1"), shape=np.ones(3), frames=frames,
              world_from_head=np.stack([view_pose(a) for a in (-20.0, 0.0, 20.0)]),
              reprojection_error_px=np.zeros(3), serial=np.array("cam0"))
    out = tmp_path / "coverage.png"
    args = _parse(["figures", "coverage", "--root", str(root), "--subject", "subj", "--seq", "HAIR",
                   "--keyframes", str(tmp_path / "keyframes.json"), "--head", str(tmp_path / "head.npz"),
                   "--res", "24", "--out", str(out)])
    assert args.func(args) == 0                          # keyframe 12 has no pose: left out with a warning
    img = cv2.imread(str(out))
    assert img is not None and img.shape[0] > 200 and img.shape[1] > 200
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 10      # a heat map, not a blank image


def test_metrics_table(tmp_path):
    paths = []
    for stage, f1 in (("stage1", 0.25), ("stage2", 0.5)):
        p = tmp_path / "ev" / "s" / "HAIR" / stage / "default" / "metrics.json"
        p.parent.mkdir(parents=True)
        p.write_text(json.dumps({"chamfer_pts": 3.3e-5, "chamfer_angle": 0.25, "f1_2mm_20deg": f1,
                                 "f1_3mm_30deg": f1, "f1_4mm_40deg": f1}))
        paths.append(str(p))
    out_png, out_rst = tmp_path / "t.png", tmp_path / "t.rst"
    for out in (out_png, out_rst):
        args = _parse(["figures", "metrics-table", "--inputs", *paths, "--title", "s/HAIR", "--out", str(out)])
        assert args.func(args) == 0
    img = cv2.imread(str(out_png))
    assert img is not None and img.shape[1] > img.shape[0] > 50
    rst = out_rst.read_text()
    assert "0.000033" in rst and "0.250" in rst and "0.500" in rst and "stage2" in rst
    from docutils.core import publish_parts

    html = publish_parts(rst, writer="html")["body"]
    assert html.count("<tr") == 3 and "0.000033" in html
    with pytest.raises(ValueError, match=r"\.png, \.rst or \.md"):
        args = _parse(["figures", "metrics-table", "--inputs", *paths, "--out", str(tmp_path / "t.txt")])
        args.func(args)


def test_metrics_table_without_ground_truth():
    import pandas as pd

    df = pd.DataFrame({"subject": ["r"], "seq": ["Q"], "stage": ["stage2"], "variant": ["default"],
                       "has_ground_truth": [False]})
    assert "n/a" in metrics_table_rst(df)
