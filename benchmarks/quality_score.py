"""Scoring of ``benchmarks/quality.py`` runs against the ground truth: the points no keyframe can
show, and the exact metrics of a strand file, cached next to it. Kept apart from the runs so that
the other benchmarks that score (``stage2_sweep.py``) use the same rule.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def unseen_test(seq: dict):
    """The points (head frame, metres) that the sequence's keyframes cannot show: those lying in the
    back region (azimuth from the face >= 120 degrees, :data:`REGIONS`) or outside the image
    of every keyframe (camera and head poses of the front stages; long hair runs off the bottom of
    the frame). A function (M,3) -> (M,) bool for ``evaluate_strands(unseen=...)``."""
    from vid2haircut.evaluate.metrics import REGIONS, region_of
    from vid2haircut.fit.data import load_fit_camera
    from vid2haircut.front.headfile import load_head_fit
    from vid2haircut.front.keyframes import load_keyframes

    fit, extra = load_head_fit(seq["head"])
    cam = load_fit_camera(seq["root"], seq["subject"], extra.get("serial") or load_keyframes(seq["keyframes"]).serial)
    poses = np.asarray(fit.world_from_head, np.float64)
    back = [name for name, _, _ in REGIONS].index("back")

    def test(points: np.ndarray) -> np.ndarray:
        inside = np.zeros(len(points), bool)
        for pose in poses:
            uv, z = cam.project(points @ pose[:3, :3].T + pose[:3, 3])
            inside |= ((z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] < cam.width - 0.5)
                       & (uv[:, 1] >= -0.5) & (uv[:, 1] < cam.height - 0.5))
        return ~inside | (region_of(points) == back)

    return test


def score(pred: Path, gt: Path, cache: Path, unseen=None) -> dict:
    """Metrics of a strand file against the ground truth (every point, exact; ``max_points`` 0 in the
    cache), with Chamfer_pts split by head region
    (front / side / back) and the median tip height above the ground truth's per root region
    (``tip_dy_<region>``, metres; positive = too short), cached next to the prediction."""
    from vid2haircut.evaluate.metrics import evaluate_strands, tip_heights
    from vid2haircut.io.atomic import write_json
    from vid2haircut.io.strand_formats import load_strands

    if cache.is_file() and cache.stat().st_mtime >= pred.stat().st_mtime:
        m = json.loads(cache.read_text())
        # a score through a random subset (biased upwards, ``max_points`` != 0) or without a part asked for is redone
        if m.get("max_points") == 0 and "tip_dy_back" in m and (unseen is None or "chamfer_pts_unseen" in m):
            return m
    p, g = load_strands(pred), load_strands(gt)
    m = evaluate_strands(p, g, max_points=None, by_region=True, unseen=unseen)
    m["max_points"] = 0
    hp, hg = tip_heights(p), tip_heights(g)
    m.update({f"tip_dy_{r}": hp[r] - hg[r] for r in hp})
    write_json(cache, m)
    return m
