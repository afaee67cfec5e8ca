"""Metrics on hand-computable strand configurations and against a brute-force reference."""

import json

import numpy as np
import pytest

from vid2haircut.evaluate import THRESHOLDS, evaluate_files, evaluate_strands
from scipy.spatial import cKDTree
from vid2haircut.evaluate.metrics import oriented_points, tip_heights
from vid2haircut.io.strand_formats import save_strands
from vid2haircut.strands import StrandSet

TAGS = ["2mm_20deg", "3mm_30deg", "4mm_40deg"]


def _curved(n=5, p=30):
    """(n,p,3) arcs of radius 0.1 m in the xy plane (z = 0), 0.5 m apart along x."""
    th = np.linspace(0, 1.5, p)
    arc = np.stack([0.1 * np.sin(th), -0.1 * (1 - np.cos(th)), np.zeros(p)], -1)
    return np.stack([arc + [0.5 * k, 0, 0] for k in range(n)]).astype(np.float32)


def _straight(angle_deg, n=3, p=5, spacing=0.01):
    """n straight strands of p points ``spacing`` apart, centred at (k m, 0, 0), direction
    (cos a, 0, sin a) in the xz plane."""
    s = (np.arange(p) - (p - 1) / 2) * spacing
    a = np.deg2rad(angle_deg)
    d = np.array([np.cos(a), 0.0, np.sin(a)])
    return np.stack([s[:, None] * d + [k, 0, 0] for k in range(n)])


def test_identical_sets():
    s = StrandSet(_curved())
    m = evaluate_strands(s, s, n_points=30)
    assert m["chamfer_pts"] == 0.0 and m["chamfer_angle"] < 1e-7
    for t in TAGS:
        assert m[f"precision_{t}"] == m[f"recall_{t}"] == m[f"f1_{t}"] == 1.0
    assert m["n_points_pred"] == m["n_points_gt"] == 150


@pytest.mark.parametrize("shift_mm,f1", [(1.0, [1, 1, 1]), (2.5, [0, 1, 1]), (3.5, [0, 0, 1])])
def test_shifted_set(shift_mm, f1):
    # arcs in the xy plane shifted along z: every point's nearest neighbour is its twin
    gt = StrandSet(_curved())
    pred = StrandSet(gt.points + np.float32([0, 0, shift_mm * 1e-3]))
    m = evaluate_strands(pred, gt, n_points=30)
    assert m["chamfer_pts"] == pytest.approx(2 * (shift_mm * 1e-3) ** 2, rel=1e-4)
    assert m["chamfer_pts_pred_to_gt"] == pytest.approx(m["chamfer_pts_gt_to_pred"], rel=1e-4)
    assert m["chamfer_angle"] < 1e-6
    assert [m[f"f1_{t}"] for t in TAGS] == f1


def test_perpendicular_strands():
    # along x turned to along z about each strand's midpoint: all tangents are perpendicular.
    # Points at s in {-2,-1,0,1,2} cm: nearest distance^2 of (0,0,s) to the x-axis samples is s^2,
    # so chamfer_pts = 2 * mean(s^2) = 2 * (4+1+0+1+4)/5 cm^2 = 4e-4 m^2.
    gt, pred = StrandSet(_straight(0.0)), StrandSet(_straight(90.0))
    m = evaluate_strands(pred, gt, n_points=5)
    assert m["chamfer_pts"] == pytest.approx(4e-4, rel=1e-5)
    assert m["chamfer_angle"] == pytest.approx(np.pi / 2, abs=1e-6)
    assert all(m[f"f1_{t}"] == 0.0 for t in TAGS)        # the midpoints coincide but cross at 90 deg


def test_rotated_35_degrees():
    # turned by 35 deg: every pair of tangents is 35 deg apart. Only the coincident midpoints are
    # within 4 mm (the next pred point is 6.0 mm from the nearest x-axis sample), and 35 deg
    # passes only the 40 deg threshold: P = R = 1/5 at (4 mm, 40 deg), 0 elsewhere.
    gt, pred = StrandSet(_straight(0.0)), StrandSet(_straight(35.0))
    m = evaluate_strands(pred, gt, n_points=5)
    assert m["chamfer_angle"] == pytest.approx(np.deg2rad(35.0), abs=1e-6)
    assert m["precision_4mm_40deg"] == pytest.approx(0.2) and m["recall_4mm_40deg"] == pytest.approx(0.2)
    assert m["f1_4mm_40deg"] == pytest.approx(0.2)
    assert m["f1_2mm_20deg"] == m["f1_3mm_30deg"] == 0.0
    s = (np.arange(5) - 2) * 0.01
    a = np.deg2rad(35.0)
    one_way = np.mean([min((si * np.cos(a) - x) ** 2 + (si * np.sin(a)) ** 2 for x in s) for si in s])
    assert m["chamfer_pts"] == pytest.approx(2 * one_way, rel=1e-5)


def _brute(pred_pts, pred_tan, gt_pts, gt_tan):
    d2 = ((pred_pts[:, None] - gt_pts[None]) ** 2).sum(-1)
    cos = np.abs(pred_tan @ gt_tan.T)
    out = {"chamfer_pts": d2.min(1).mean() + d2.min(0).mean()}
    ang_pg = np.arccos(np.clip(cos[np.arange(len(pred_pts)), d2.argmin(1)], 0, 1)).mean()
    ang_gp = np.arccos(np.clip(cos[d2.argmin(0), np.arange(len(gt_pts))], 0, 1)).mean()
    out["chamfer_angle"] = 0.5 * (ang_pg + ang_gp)
    for (r, a), t in zip(THRESHOLDS, TAGS):
        ok = (np.sqrt(d2) <= r) & (cos >= np.cos(np.deg2rad(a)))
        out[f"precision_{t}"], out[f"recall_{t}"] = ok.any(1).mean(), ok.any(0).mean()
    return out


def test_matches_brute_force_on_dense_random_hair():
    # dense random strands in a 1 cm box: most points have far more than 16 neighbours within
    # 4 mm, which exercises the exact ball-query fallback
    rng = np.random.default_rng(3)
    gt = StrandSet((rng.random((40, 1, 3)) * 0.01 + rng.normal(scale=0.001, size=(40, 8, 3)).cumsum(1)))
    pred = StrandSet(gt.points + rng.normal(scale=0.002, size=gt.points.shape))
    m = evaluate_strands(pred, gt, n_points=8)
    ref = _brute(pred.points.reshape(-1, 3).astype(float), pred.tangents().reshape(-1, 3).astype(float),
                 gt.points.reshape(-1, 3).astype(float), gt.tangents().reshape(-1, 3).astype(float))
    for k, v in ref.items():
        assert m[k] == pytest.approx(v, rel=1e-5, abs=1e-9), k
    assert 0.0 < m["precision_2mm_20deg"] < m["precision_4mm_40deg"] < 1.0


def test_subsampling_is_deterministic_and_capped():
    rng = np.random.default_rng(0)
    gt = StrandSet(rng.normal(scale=0.01, size=(50, 20, 3)).cumsum(1))
    pred = StrandSet(gt.points + rng.normal(scale=1e-3, size=gt.points.shape))
    a = evaluate_strands(pred, gt, n_points=20, max_points=300, seed=1)
    b = evaluate_strands(pred, gt, n_points=20, max_points=300, seed=1)
    c = evaluate_strands(pred, gt, n_points=20, max_points=300, seed=2)
    assert a == b and a != c
    assert a["n_points_pred"] == a["n_points_gt"] == 300


def test_whole_sets_are_exact_and_subsets_biased_upwards():
    rng = np.random.default_rng(3)
    gt = StrandSet(rng.normal(scale=0.01, size=(200, 30, 3)).cumsum(1))
    whole = evaluate_strands(gt, gt, n_points=30)                   # default: every point
    assert whole["chamfer_pts"] == 0.0 and whole["n_points_pred"] == 200 * 30
    assert evaluate_strands(gt, gt, n_points=30, max_points=0) == whole
    # two different random subsets of the same set: a positive score that says nothing of the strands
    a = oriented_points(gt, 30, 1200, seed=0)
    b = oriented_points(gt, 30, 1200, seed=1)
    d_ab = cKDTree(b.points).query(a.points)[0]
    assert np.mean(d_ab ** 2) > 0.0
    pred = StrandSet(gt.points + rng.normal(scale=1e-3, size=gt.points.shape))
    exact = evaluate_strands(pred, gt, n_points=30)["chamfer_pts"]
    subset = evaluate_strands(pred, gt, n_points=30, max_points=1200)["chamfer_pts"]
    assert subset > exact


def test_unseen_part_of_chamfer():
    rng = np.random.default_rng(4)
    gt = StrandSet(rng.normal(scale=0.01, size=(60, 20, 3)).cumsum(1))
    pred = StrandSet(gt.points + rng.normal(scale=1e-3, size=gt.points.shape))
    m = evaluate_strands(pred, gt, n_points=20, unseen=lambda x: x[:, 1] < 0.0)
    p_pts, g_pts = pred.resample(20).points.reshape(-1, 3), gt.resample(20).points.reshape(-1, 3)
    d_pg = cKDTree(g_pts).query(p_pts)[0] ** 2
    d_gp = cKDTree(p_pts).query(g_pts)[0] ** 2
    want = d_pg[p_pts[:, 1] < 0].sum() / len(d_pg) + d_gp[g_pts[:, 1] < 0].sum() / len(d_gp)
    assert m["chamfer_pts_unseen"] == pytest.approx(want, rel=1e-9)
    assert 0.0 < m["chamfer_pts_unseen"] < m["chamfer_pts"]
    assert evaluate_strands(pred, gt, n_points=20, unseen=lambda x: np.ones(len(x), bool))[
        "chamfer_pts_unseen"] == pytest.approx(m["chamfer_pts"])


def test_errors_and_evaluate_files(tmp_path):
    gt = StrandSet(_curved(), head_model="proxy-v1")
    with pytest.raises(ValueError, match="empty"):
        evaluate_strands(gt.subset([]), gt)
    with pytest.raises(ValueError, match="head model"):
        evaluate_strands(StrandSet(gt.points, head_model="flame"), gt)
    save_strands(tmp_path / "gt.npz", gt)
    save_strands(tmp_path / "pred.data", StrandSet(gt.points + np.float32([0, 0, 1e-3])))
    rec = evaluate_files(tmp_path / "pred.data", tmp_path / "gt.npz", tmp_path / "out" / "metrics.json",
                         n_points=30)
    on_disk = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert on_disk == rec and on_disk["pred_file"] == "pred.data" and on_disk["points_per_strand"] == 30
    assert on_disk["chamfer_pts"] == pytest.approx(2e-6, rel=1e-4) and on_disk["f1_2mm_20deg"] == 1.0


def test_chamfer_by_region_credits_each_region_and_sums_to_the_total():
    # one vertical strand in front (+z), one at the side (+x), one at the back (-z), 0.1 m out
    t = np.linspace(0.0, -0.1, 20)
    strand = lambda x, z: np.stack([np.full(20, x), t, np.full(20, z)], -1)  # noqa: E731
    gt = StrandSet(np.stack([strand(0, 0.1), strand(0.1, 0), strand(0, -0.1)]).astype(np.float32))
    moved = gt.points.copy()
    moved[2] += np.float32([0.003, 0, 0])              # only the back strand is off, by 3 mm
    pred = StrandSet(moved)
    m = evaluate_strands(pred, gt, n_points=20, by_region=True)
    parts = {k: m[k] for k in ("chamfer_pts_front", "chamfer_pts_side", "chamfer_pts_back")}
    total = evaluate_strands(pred, gt, n_points=20)["chamfer_pts"]
    assert parts["chamfer_pts_front"] == 0.0 and parts["chamfer_pts_side"] == 0.0
    assert parts["chamfer_pts_back"] == pytest.approx(2 * (0.003 ** 2) / 3, rel=1e-4)
    assert sum(parts.values()) == pytest.approx(total, rel=1e-9)


def test_tip_heights_by_root_region():
    # hanging strands rooted in front (+z), at the side (+x) and at the back (-z), of different lengths;
    # the back strand's tip swings forward (its tip point lies in front) but counts as back by its root
    def hang(x, z, drop, tip_dz=0.0):
        p = np.zeros((10, 3), np.float32)
        p[:, 0], p[:, 1], p[:, 2] = x, np.linspace(0.0, -drop, 10), z + np.linspace(0.0, tip_dz, 10)
        return p
    s = StrandSet(np.stack([hang(0, 0.1, 0.1), hang(0, 0.1, 0.2), hang(0.1, 0, 0.15), hang(0, -0.1, 0.3, 0.25)]))
    h = tip_heights(s)
    assert h["front"] == pytest.approx(-0.15) and h["side"] == pytest.approx(-0.15)
    assert h["back"] == pytest.approx(-0.3)
    only_front = tip_heights(StrandSet(s.points[:1]))
    assert only_front["front"] == pytest.approx(-0.1) and np.isnan(only_front["back"])
