"""The accelerator check scripts (benchmarks/device_check.sh) run on the CPU too, so they cannot rot
between the sessions that are lent a GPU."""

import math
import sys
from pathlib import Path

import pytest

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


def test_render_kernels_benchmark_times_every_kernel(capsys):
    """benchmarks/render_kernels.py (the README's renderer breakdown) runs on a small scene, times
    every kernel it names and puts the kernels back afterwards."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import render_kernels
    finally:
        sys.path.pop(0)
    from vid2haircut.render import numba_backend, numba_kernels

    if not numba_backend.numba_available():
        pytest.skip("needs numba")
    before = numba_kernels.composite_forward
    assert render_kernels.main(["--strands", "100", "--size", "64", "--calls", "2"]) == 0
    out = capsys.readouterr().out
    for names in render_kernels.KERNELS.values():
        for name in names:
            assert f"| {name} |" in out
    assert numba_kernels.composite_forward is before
