"""The accelerator check scripts (benchmarks/device_check.sh) run on the CPU too, so they cannot rot
between the sessions that are lent a GPU."""

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from bench_loader import load_benchmark  # noqa: E402


def test_fit_device_check_small_problem_on_cpu():
    fit_device_check = load_benchmark("fit_device_check")
    res = fit_device_check.run_small("cpu")
    assert res["invisible_points"] > 0
    assert res["invisible_grad_max"] == 0.0
    assert res["visible_grad_max"] > 0.0
    assert math.isfinite(res["stage1_final_total"]) and math.isfinite(res["stage2_final_total"])
    assert res["stage2_first"]["silhouette"] > 0.0


def test_render_kernels_benchmark_times_every_kernel(capsys):
    """benchmarks/render_kernels.py (the README's renderer breakdown) runs on a small scene, times
    every kernel it names and puts the kernels back afterwards."""
    render_kernels = load_benchmark("render_kernels")
    from vid2haircut.render import numba_backend, numba_kernels

    if not numba_backend.numba_available():
        pytest.skip("needs numba")
    before = numba_kernels.composite_forward
    out = ""
    for compositing in ("bins", "exact"):  # the exact model's kernels run only with it
        assert render_kernels.main(["--strands", "100", "--size", "64", "--calls", "2",
                                    "--compositing", compositing]) == 0
        out += capsys.readouterr().out
    for names in render_kernels.KERNELS.values():
        for name in names:
            assert (f"| {name} |" in out) != (name in render_kernels.OTHER_PATH), name
    assert numba_kernels.composite_forward is before


def test_render_floor_walk_lists_the_renderers_elements(capsys):
    """benchmarks/render_floor.py's walk-only kernel does the real forward kernel's window walk (the
    same elements, powers turned into the same d l / d power and l), so its time is the walk's; the
    benchmark runs on a small scene and puts the kernels back."""
    render_floor = load_benchmark("render_floor")
    setup = load_benchmark("render_bench").setup
    import numpy as np

    from vid2haircut.render import numba_backend, numba_kernels, render_strands

    if not numba_backend.numba_available():
        pytest.skip("needs numba")
    real = numba_kernels.composite_forward
    seen = []

    def both(*args):
        real(*args)
        elems, e_range = args[17], args[18]
        copies = tuple(np.zeros_like(a) for a in elems), np.zeros_like(e_range)
        render_floor.walk_only(*args[:17], *copies, *args[19:])
        seen.append((elems, e_range) + copies)

    numba_kernels.composite_forward = both
    try:
        pts, K, E, hd = setup(200, 64, 1, "cpu")
        render_strands(pts, K, E, 64, 64, head_depth=hd, backend="numba", compositing="bins")
    finally:
        numba_kernels.composite_forward = real
    (elems, e_range, elems_w, e_range_w), = seen
    assert np.array_equal(e_range, e_range_w) and int((e_range[:, 1] - e_range[:, 0]).sum()) > 1000
    for k0, k1 in e_range:
        for col in (0, 2, 3):  # pixel, d l / d power, l
            assert np.array_equal(elems[col][k0:k1], elems_w[col][k0:k1])
    assert render_floor.main(["--strands", "100", "--size", "64", "--repeat", "1", "--rounds", "1"]) == 0
    out = capsys.readouterr().out
    assert "| full | walk | none |" in out and out.strip().splitlines()[-1].startswith("| 1 |")
    assert numba_kernels.composite_forward is real


def test_render_bench_rounds_take_each_columns_best():
    """render_bench.py --rounds: each column's best over the rounds, the ratio of those bests, and
    the rounds' ranges (a slow scatter-add in one round cannot make the ratio look better)."""
    table_row = load_benchmark("render_bench").table_row
    quiet = dict(segments=124000, T=7.56e6, fwd=35.0, fwd_bwd=60.0, scatter=6.0)
    slow = dict(quiet, fwd=50.0, fwd_bwd=62.5, scatter=11.3)
    row = table_row(4000, 256, [slow, quiet])
    assert row == "| 4000 | 256x256 | 124000 | 7.56 M | 35.0 | 60.0 (60.0-62.5) | 6.0 (6.0-11.3) | 10.0x |"
    assert table_row(4000, 256, [slow]) == "| 4000 | 256x256 | 124000 | 7.56 M | 50.0 | 62.5 | 11.3 | 5.5x |"
