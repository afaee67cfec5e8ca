"""The numba backend's pixel windows and screen-tile binning against slow Python references."""

from __future__ import annotations

import numpy as np
import pytest

from vid2haircut.render.numba_backend import numba_available


def _windows_reference(means, covs, valid, height, width, power_min, cols):
    """Slow float32 reference of the numba window tables (one Gaussian at a time, numpy scalars, the
    formulas of footprint.gaussian_windows): (hz, u_lo, ncols, need, slope, v0) per Gaussian; u_lo,
    need, slope and v0 are only meaningful where ncols > 0."""
    f32 = np.float32
    c2 = f32(-2.0 * power_min)
    out = []
    for (mx, my), (sxx, sxy, syy), ok in zip(means.astype(f32), covs.astype(f32), valid):
        hz = sxx >= syy
        mu, mv, suu, svv = (mx, my, sxx, syy) if hz else (my, mx, syy, sxx)
        size_u, size_v = (f32(width), f32(height)) if hz else (f32(height), f32(width))
        with np.errstate(all="ignore"):
            eu, ev = np.sqrt(c2 * suu), np.sqrt(c2 * svv)
            u_lo = max(np.ceil(mu - eu), f32(0.0))
            u_hi = min(np.floor(mu + eu), size_u - f32(1.0))
            slope = sxy / suu
            det = max(suu * svv - sxy * sxy, f32(1e-12))
            half = np.sqrt(c2 * det / suu)
            good = ok and mv + ev >= 0 and mv - ev <= size_v - 1 and all(np.isfinite([mu, eu, ev, half]))
            ncol = max(u_hi - u_lo + f32(1.0), f32(0.0)) if good else f32(0.0)
            nt = int(np.ceil(ncol / f32(cols)))
            need = int(np.floor(f32(2.0) * half) + f32(1.0)) if nt > 0 else 1
            out.append((int(hz), int(u_lo) if good else 0, nt * cols, need, slope, mv - slope * mu - half))
    return out


@pytest.mark.skipif(not numba_available(), reason="needs numba")
def test_numba_windows_match_a_float32_reference():
    """numba_windows.gaussian_windows gives, window for window, the
    float32 formulas evaluated one Gaussian at a time: random Gaussians on and off a 61 x 47 image,
    thin and round, some degenerate, NaN, infinite or invalid."""
    from vid2haircut.render import numba_windows as nt

    rng = np.random.default_rng(5)
    G = 3 * 256 + 17
    means = rng.uniform(-20, 80, (G, 2))
    a, b = rng.uniform(0.05, 30, G), rng.uniform(0.05, 3, G)
    ang = rng.uniform(0, np.pi, G)
    c, s = np.cos(ang), np.sin(ang)
    covs = np.stack([a * c * c + b * s * s, (a - b) * c * s, a * s * s + b * c * c], 1)
    covs[::37, 1] = np.sqrt(covs[::37, 0] * covs[::37, 2])  # degenerate (determinant 0)
    means[::41, 0] = np.nan
    covs[::43, 2] = np.inf
    covs[::47, 0] = -1.0
    valid = rng.random(G) > 0.1
    height, width, power_min, cols = 47, 61, -4.5, 4
    wint, wflt = np.empty((G, 4), np.int64), np.empty((G, 2), np.float32)
    rows = nt.gaussian_windows(means, covs, valid, height, width, power_min, cols, 8, wint, wflt)
    ref = _windows_reference(means, covs, valid, height, width, power_min, cols)
    drawn = 0
    for g, (hz, u_lo, ncols, need, slope, v0) in enumerate(ref):
        assert wint[g, nt.W_NCOL] == ncols, g
        if ncols > 0:
            drawn += 1
            assert (wint[g, nt.W_HZ], wint[g, nt.W_ULO]) == (hz, u_lo), g
            assert wint[g, nt.W_HGT] == (need + rows - 1) // rows * rows, g
            assert wflt[g, nt.W_SLOPE].tobytes() == slope.tobytes() and wflt[g, nt.W_V0].tobytes() == v0.tobytes(), g
    assert G // 4 < drawn < G - G // 10  # both kinds are tested


@pytest.mark.skipif(not numba_available(), reason="needs numba")
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_gathered_windows_are_the_window_tables_gathered(dtype):
    """numba_records.gather_windows (the exact model's windows, computed while the Gaussians are
    gathered in depth order) writes byte for byte the records of gaussian_windows then
    gather_gaussians, degenerate, NaN and invalid Gaussians included, and the same frames, but
    for the heights: the rows each window needs, not rounded up to the common tile height."""
    from vid2haircut.render import numba_records as nr
    from vid2haircut.render import numba_windows as nw

    rng = np.random.default_rng(11)
    G = 2 * 256 + 29
    table = rng.uniform(-20, 80, (G, 8)).astype(dtype)  # (mean x, mean y, ..., depth, ...)
    table[:, 5] = rng.uniform(0.4, 0.8, G)
    a, b = rng.uniform(0.05, 30, G), rng.uniform(0.05, 3, G)
    ang = rng.uniform(0, np.pi, G)
    c, s = np.cos(ang), np.sin(ang)
    covs = np.stack([a * c * c + b * s * s, (a - b) * c * s, a * s * s + b * c * c], 1).astype(dtype)
    covs[::37, 1] = np.sqrt(covs[::37, 0] * covs[::37, 2])
    table[::41, 0] = np.nan
    covs[::43, 2] = np.inf
    valid = rng.random(G) > 0.1
    frame = rng.integers(0, 3, G).astype(np.int64)
    order = nr.depth_order(table[:, 5])
    wint, wflt = np.empty((G, 4), np.int64), np.empty((G, 2), np.float32)
    rows = nw.gaussian_windows(table[:, 0:2], covs, valid, 47, 61, -4.5, 4, 8, wint, wflt)
    want = nr.gaussian_records(G, dtype)
    fr_want = nr.gather_gaussians(order, table, wint, wflt, frame, *want)
    got = nr.gaussian_records(G, dtype)
    fr_got = nr.gather_windows(order, table, covs, valid, frame, 47, 61, -4.5, 4, *got)
    assert np.array_equal(fr_got, fr_want) and np.array_equal(fr_got, frame[order])
    for u, v in zip(got, want):
        if u.dtype == np.int32:  # the window integers: heights apart, the same
            assert u[:, :nw.W_HGT].tobytes() == v[:, :nw.W_HGT].tobytes()
        else:
            assert u.tobytes() == v.tobytes()
    ref = _windows_reference(table[:, 0:2], covs, valid, 47, 61, -4.5, 4)
    need = np.array([r[3] for r in ref])[order]
    drawn = want[1][:, nw.W_NCOL] > 0
    assert np.array_equal(got[1][drawn, nw.W_HGT], need[drawn])  # unrounded
    assert np.array_equal(want[1][drawn, nw.W_HGT], (need[drawn] + rows - 1) // rows * rows)
    assert rows > 1 and (got[1][drawn, nw.W_HGT] < want[1][drawn, nw.W_HGT]).any()  # (the rounding is tested)
    assert 0 < drawn.sum() < G  # drawn and undrawn windows both


@pytest.mark.skipif(not numba_available(), reason="needs numba")
@pytest.mark.parametrize("tile", [16, 12])
def test_bin_windows_matches_a_python_reference(tile):
    """numba_tiles.bin_windows (branch-free tile boxes, an unrolled count for boxes of up to 2 x 2
    tiles, pixel -> tile by shifts for a power-of-two tile, by division otherwise) lists the same
    instances as a plain Python loop over every Gaussian's tiles: windows of every size (1 tile to
    many), off the image, undrawn or with a NaN line, over two
    frames, with a head that hides some tiles (and a NaN depth, which nothing hides)."""
    from vid2haircut.render import numba_tiles as nt, numba_windows as nw

    assert (nt.tile_shift(16), nt.tile_shift(1), nt.tile_shift(12), nt.tile_shift(0)) == (4, 0, -1, -1)
    assert all(nt._tile_of(i, 16, 4) == i // 16 and nt._tile_of(i, 12, -1) == i // 12 for i in range(-40, 41))
    rng = np.random.default_rng(11)
    G, H, W, frames = 1500, 70, 90, 2
    means = rng.uniform(-30, 110, (G, 2))
    a, b = rng.uniform(0.05, 400, G) ** rng.uniform(0.3, 1.0, G), rng.uniform(0.05, 3, G)
    ang = rng.uniform(0, np.pi, G)
    c, s = np.cos(ang), np.sin(ang)
    covs = np.stack([a * c * c + b * s * s, (a - b) * c * s, a * s * s + b * c * c], 1)
    valid = rng.random(G) > 0.05
    wint, wflt = np.empty((G, 4), np.int64), np.empty((G, 2), np.float32)
    nw.gaussian_windows(means, covs, valid, H, W, -4.5, 4, 8, wint, wflt)
    wflt[::97, 1] = np.nan
    frame = rng.integers(0, frames, G).astype(np.int64)
    z = rng.uniform(0.4, 0.8, G)
    z[::89] = np.nan
    ntx, nty = -(-W // tile), -(-H // tile)
    hmax = np.where(rng.random(frames * nty * ntx) < 0.3, rng.uniform(0.4, 0.8, frames * nty * ntx), np.inf)
    gstart, inst_pos, tile_start, sorted_g, no_codes, no_csr = nt.bin_windows(wint, wflt, frame, frames, W, H, tile,
                                                                             z, hmax, False)
    exact = nt.bin_windows(wint, wflt, frame, frames, W, H, tile, z, hmax, True)  # the same lists, codes, inst_csr
    assert all(np.array_equal(u, v) for u, v in zip((exact[0], exact[2], exact[3]), (gstart, tile_start, sorted_g)))
    assert no_codes.shape == (0,) and no_csr.shape == (0,) and exact[1].shape == (0,)
    boxes, inst_csr = exact[4], exact[5]
    assert inst_csr.dtype == np.int32 and np.array_equal(inst_pos[inst_csr], np.arange(inst_pos.shape[0]))  # inverted

    inst = []  # (tile, g) in Gaussian order
    for g in range(G):
        hz, ua, ncol, hgt = (int(v) for v in wint[g])
        sl, v0 = wflt[g]
        if ncol <= 0 or not (np.isfinite(sl) and np.isfinite(v0)):
            continue
        su, sv = (W, H) if hz else (H, W)
        ub = min(ua + ncol - 1, su - 1)
        if ub < ua:
            continue
        va, vb = nw.vstart(sl, ua, v0), nw.vstart(sl, ub, v0)
        vlo, vhi = max(min(va, vb), 0), min(max(va, vb) + hgt - 1, sv - 1)
        if vhi < vlo:
            continue
        (x0, x1), (y0, y1) = ((ua, ub), (vlo, vhi)) if hz else ((vlo, vhi), (ua, ub))
        for ty in range(y0 // tile, y1 // tile + 1):
            for tx in range(x0 // tile, x1 // tile + 1):
                t = (frame[g] * nty + ty) * ntx + tx
                if not z[g] >= hmax[t]:
                    inst.append((t, g))
    counts = np.bincount([g for _, g in inst], minlength=G)
    assert np.array_equal(gstart, np.concatenate([[0], np.cumsum(counts)]))
    order = sorted(range(len(inst)), key=lambda i: inst[i][0])  # stable: Gaussian order inside a tile
    assert np.array_equal(sorted_g, [inst[i][1] for i in order])
    assert np.array_equal(tile_start, np.concatenate([[0], np.cumsum(np.bincount([t for t, _ in inst],
                                                                                  minlength=frames * nty * ntx))]))
    pos = np.empty(len(inst), np.int64)
    pos[order] = np.arange(len(inst))
    assert np.array_equal(inst_pos, pos)
    # boxes beyond 2 x 2 tiles, boxes of up to 2 x 2, and Gaussians with no instance are all there
    assert (counts > 4).sum() > 50 and ((counts >= 1) & (counts <= 4)).sum() > 200 and (counts == 0).sum() > 200
    # each instance's box code: its window's lanes (columns along u) and lines (rows along v) in its tile
    fields = {"miss": 0, "hit": 0}
    for i, (t, g) in enumerate(inst):
        hz, ula, ncol, hgt = (int(v) for v in wint[g])
        sl, v0 = wflt[g]
        ty, tx = divmod(t % (nty * ntx), ntx)
        x0, y0 = tx * tile, ty * tile
        x1, y1 = min(x0 + tile, W) - 1, min(y0 + tile, H) - 1
        tu0, tu1, tv0, tv1 = (x0, x1, y0, y1) if hz else (y0, y1, x0, x1)
        ua, ub = max(ula, tu0), min(ula + ncol - 1, tu1)
        code = boxes[pos[i]]
        lo = hi = None
        if ub >= ua:
            va, vb = nw.vstart(sl, ua, v0), nw.vstart(sl, ub, v0)
            lo, hi = max(min(va, vb), tv0) - tv0, min(max(va, vb) + hgt - 1, tv1) - tv0
        if lo is None or hi < lo:
            assert code == nw.B_MISS, (t, g)
            fields["miss"] += 1
            continue
        assert nw.box_fields(code) == (0 if hz else 1, lo, hi, ua - tu0, ub - tu0, min(hgt, tv1 - tv0 + 1)), (t, g)
        assert nw.row_box(g, wint, wflt, x0, x1, y0, y1) == code, (t, g)  # the walk's own, from the rows
        fields["hit"] += 1
    assert fields["miss"] > 10 and fields["hit"] > 1000, fields
