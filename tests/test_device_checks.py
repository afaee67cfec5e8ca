"""The accelerator check scripts (benchmarks/device_check.sh) run on the CPU too, so they cannot rot
between the sessions that are lent a GPU."""

import math
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_fit_device_check_small_problem_on_cpu():
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import fit_device_check
    finally:
        sys.path.pop(0)
    res = fit_device_check.run_small("cpu")
    assert res["invisible_points"] > 0
    assert res["invisible_grad_max"] == 0.0
    assert res["visible_grad_max"] > 0.0
    assert math.isfinite(res["stage1_final_total"]) and math.isfinite(res["stage2_final_total"])
    assert res["stage2_first"]["silhouette"] > 0.0
