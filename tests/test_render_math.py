"""The numba kernels' vectorisable math (render/numba_math.py: exp, log(1 - a)) and explicit vector
code (render/numba_simd.py: one line of the window walk, its compaction included)."""

from __future__ import annotations

import functools

import numpy as np
import pytest

numba = pytest.importorskip("numba")

from vid2haircut.render import numba_simd  # noqa: E402
from vid2haircut.render.numba_math import lane_exp, lane_log1m  # noqa: E402


@numba.njit(cache=True)
def _exp_all(x, out):
    for i in range(x.shape[0]):
        out[i] = lane_exp(x[i])


@numba.njit(cache=True)
def _log1m_all(a, out):
    for i in range(a.shape[0]):
        out[i] = lane_log1m(a[i])


@pytest.mark.parametrize("dtype,tol", [(np.float32, 1.2e-7), (np.float64, 3e-16)])
def test_exp_relative_error(dtype, tol):
    x = np.concatenate([np.linspace(-87, 0, 400_001), -np.geomspace(1e-12, 1, 10_001)]).astype(dtype)
    out = np.empty_like(x)
    _exp_all(x, out)
    ref = np.exp(x.astype(np.float64))
    assert out.dtype == dtype and np.max(np.abs(out - ref) / ref) < tol


@pytest.mark.parametrize("dtype,tol", [(np.float32, 2.5e-7), (np.float64, 1e-15)])
def test_log1m_relative_error(dtype, tol):
    """log(1 - a) over the renderer's alpha range, small alphas included (the rounding of 1 - a is
    corrected: log(fl(1 - a)) alone is off by up to 5e-6 relative at a = 0.011 in float32)."""
    a = np.concatenate([np.linspace(0, 0.99, 400_001), np.geomspace(1e-9, 0.05, 20_001)]).astype(dtype)
    out = np.empty_like(a)
    _log1m_all(a, out)
    ref = np.log1p(-a.astype(np.float64))
    nz = ref != 0
    assert out.dtype == dtype and np.all(out[~nz] == 0)
    assert np.max(np.abs(out[nz] - ref[nz]) / np.abs(ref[nz])) < tol


@functools.cache
def _lines_for(compaction, lanes=16):
    """A numba loop calling line16 (``lanes`` 16) or line8 (8: at lane0s[j] on row j) compiled with
    ``compaction`` once per row, with the row's lanes_on bits ons[j] (built once each)."""
    line = numba_simd.make_line16(compaction, lanes)
    if lanes == 16:
        call = numba.njit(lambda *a: line(*a[:-1]))  # line16 has no lane0 argument
    else:
        call = numba.njit(lambda *a: line(*a))

    @numba.njit
    def lines(qa, qb, vlo, vhi, hl, zref, with_zref, zgs, bases, rows, dvs, qv, logop, half, cut, z, big,
              keep_any, prs, si, e_al, e_la, e_p, ons, lane0s):
        n = 0
        for j in range(rows.shape[0]):
            n += call(qa[j], qb[j], vlo[j], vhi[j], hl, zref, with_zref, zgs[j],
                      np.uint64(bases[j]), np.int32(rows[j]), dvs[j], qv, logop, half, cut, z, big, keep_any,
                      np.int32(prs[j]), np.int32(si), e_al, e_la, e_p, np.uint64(n), np.uint32(ons[j]),
                      np.uint64(lane0s[j]))
        return n

    return lines


def test_compaction_choice():
    """The compaction follows the features numba compiles for (NUMBA_CPU_FEATURES or the host's):
    AVX-512F compress (where numba's LLVM has it), else AVX2 permutes, else lane by lane; the walk
    uses line16 unless only the lanes remain."""
    assert numba_simd.available_compactions({"avx512f": True, "avx2": True})[0] == \
        ("compress" if numba_simd.HAS_VECTOR_COMPRESS else "permute")
    assert numba_simd.available_compactions({"avx512f": False, "avx2": True}) == ("permute", "lanes")
    assert numba_simd.available_compactions({}) == ("lanes",)
    assert numba_simd.parse_features("+avx2,-avx512f,+fma") == {"avx2": True, "avx512f": False, "fma": True}
    assert numba_simd.available_compactions(numba_simd.parse_features("+avx2,-avx512f"))[0] == "permute"
    assert numba_simd.parse_features("") == {}
    assert numba_simd.COMPACTION == numba_simd.available_compactions()[0]
    assert numba_simd.USE_LINE16 == (numba_simd.COMPACTION != "lanes")
    with pytest.raises(ValueError, match="compaction"):
        numba_simd.make_line16("gather")
    with pytest.raises(ValueError, match="lanes"):
        numba_simd.make_line16("lanes", 4)


@pytest.mark.parametrize("compaction", numba_simd.available_compactions())
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("keep_any", [True, False])
@pytest.mark.parametrize("lanes", [16, 8])
def test_line16_appends_the_elements_of_the_scalar_walk(dtype, keep_any, compaction, lanes):
    """line16 and line8, with each compaction this CPU can run, against the walk's scalar formulas
    evaluated operation by operation in numpy (IEEE rounding per operation, as the numba loop): the
    same z_ref update (none without it), the same kept lanes, bit for bit the same power and head
    factor, the pixel indices, then zeros in the line's remaining slots; lines with every, no and
    some lanes kept, the head in front (factor 0), level with (in between) and behind (1), and +inf
    head depth, and lanes_on masks with every, none or some of the lanes on (they change the kept
    lanes only, not z_ref). line8 evaluates lanes lane0 .. lane0 + 7 of each line (lane0 0 or 8) and
    leaves the others (their z_ref included) as they are."""
    _lines = _lines_for(compaction, lanes)
    rng = np.random.default_rng(1)
    c = lambda x: np.asarray(x, dtype)  # noqa: E731
    J = 300
    qa, qb = c(rng.uniform(0, 6, (J, 16))), c(rng.uniform(-3, 3, (J, 16)))
    vlo = rng.integers(-3, 10, (J, 16)).astype(np.int32)
    vhi = (vlo + rng.integers(-1, 6, (J, 16))).astype(np.int32)
    rows = rng.integers(0, 14, J).astype(np.int32)
    vlo[0], vhi[0], qa[0], qb[0] = -5, 20, 0, 0  # every lane kept
    vlo[1], vhi[1] = 20, -20  # none
    hl = c(np.concatenate([rng.uniform(0.5, 0.7, 16 * J), np.full(16, np.inf)]))
    z, big = c(0.6), c(1e4)  # (hl - z) * big: 0 (head in front) below 0.6, between 0 and 1 within 0.1 mm
    hl[:16 * J:7] = z  # level: factor 0
    hl[3:16 * J:11] = z + c(3e-5)
    bases = np.arange(J, dtype=np.uint64) * 16
    bases[0] = bases[5] = 16 * J  # the +inf row (line 0: every lane kept)
    dvs, qv = c(rng.uniform(-3, 3, J)), c(0.7)
    logop, half, cut = c(0.0), c(0.5), c(np.log(np.exp(-4.5)) - 1e-3)
    prs, si = rng.integers(0, 200, J).astype(np.int32), 16
    slots = 16 * J + 16
    e_al, e_la, e_p = np.full(slots, -9, dtype), np.full(slots, -9, dtype), np.full(slots, -9, np.int32)
    zgs = c(rng.uniform(0, 1, J))
    zref = c(np.full(hl.shape, np.inf))
    zref[::3] = c(0.5)
    zref0 = zref.copy()
    lane0s = rng.choice([0, 8], J).astype(np.uint64) if lanes == 8 else np.zeros(J, np.uint64)
    lane0s[0] = 0
    ons = np.where(rng.random(J) < 0.3, 0xFFFFFFFF, rng.integers(0, 1 << 16, J)).astype(np.uint32)
    ons[0], ons[2] = 0xFFFFFFFF, 0  # line 0: every lane kept; line 2: none on
    n = _lines(qa, qb, vlo, vhi, hl, zref, True, zgs, bases, rows, dvs, qv, logop, half, cut, z, big, keep_any, prs, si,
               e_al, e_la, e_p, ons, lane0s)
    unchanged = zref0.copy()
    assert _lines(qa, qb, vlo, vhi, hl, unchanged, False, zgs, bases, rows, dvs, qv, logop, half, cut, z, big, keep_any,
                  prs, si, e_al.copy(), e_la.copy(), e_p.copy(), ons, lane0s) == n
    assert np.array_equal(unchanged, zref0)  # without z_ref: not touched
    ref_p, ref_f, ref_pix = [], [], []
    ref_zref = zref0.copy()
    for j in range(J):
        b = int(bases[j])
        evaluated = (np.arange(16) >= lane0s[j]) & (np.arange(16) < lane0s[j] + lanes)
        win = (rows[j] >= vlo[j]) & (rows[j] <= vhi[j]) & evaluated
        ref_zref[b:b + 16] = np.where(win & (zgs[j] < ref_zref[b:b + 16]), zgs[j], ref_zref[b:b + 16])
        dv = dvs[j]
        p = logop - half * (qa[j] + dv * (qb[j] + qv * dv))
        x = (hl[int(bases[j]):int(bases[j]) + 16] - z) * big
        x = np.where(c(0) > x, c(0), x)
        f = np.where(c(1) < x, c(1), x)
        kept = win & (p > cut) & (f > 0) & keep_any & ((ons[j] >> np.arange(16, dtype=np.uint32)) & 1 != 0)
        ref_p.append(p[kept])
        ref_f.append(f[kept])
        ref_pix.append((prs[j] + np.arange(16) * si)[kept])
        assert kept[evaluated].all() == (j == 0 and keep_any) or j > 0
    ref_p, ref_f, ref_pix = np.concatenate(ref_p), np.concatenate(ref_f), np.concatenate(ref_pix)
    assert np.array_equal(zref, ref_zref) and not np.array_equal(zref, zref0)
    assert n == ref_p.size and (n > 200 * lanes // 16 if keep_any else n == 0)
    assert np.array_equal(e_al[:n], ref_p) and np.array_equal(e_la[:n], ref_f) and np.array_equal(e_p[:n], ref_pix)
    last = n - int(np.count_nonzero(kept))  # where the last line's slots begin
    for out in (e_al, e_la, e_p):  # they hold its kept lanes, then zeros (float64: up to there); nothing beyond
        assert np.all((out[n:last + lanes] == 0) | (out[n:last + lanes] == -9)) and np.all(out[last + lanes:] == -9)
        assert out[n] == 0
    if keep_any:
        assert 0 < np.count_nonzero((ref_f > 0) & (ref_f < 1)) and np.count_nonzero(ref_f == 1) > 50


def test_window_start_is_the_float32_ceiling():
    """numba_windows.vstart (trunc + compare, no libm call) = ceil(float32(slope * u) + v0) as
    footprint.py computes it: integers, halves, values just around integers, negatives, -0."""
    from vid2haircut.render.numba_windows import vstart

    rng = np.random.default_rng(3)
    slopes = np.concatenate([rng.uniform(-1, 1, 2000), [0.0, -0.0, 1.0, -1.0, 0.5, -0.5]]).astype(np.float32)
    us = rng.integers(0, 600, slopes.size)
    v0s = np.concatenate([rng.uniform(-700, 700, 1000), np.round(rng.uniform(-50, 50, 1006))]).astype(np.float32)
    v0s[:200] = np.nextafter(np.round(v0s[:200]), np.float32(np.inf))  # just above and below integers
    v0s[200:400] = np.nextafter(np.round(v0s[200:400]), np.float32(-np.inf))
    for sl, u, v0 in zip(slopes, us, v0s):
        t = np.float32(np.float32(sl * np.float32(u)) + v0)
        assert vstart(sl, u, v0) == int(np.ceil(t)), (sl, u, v0)


def test_window_start_in_int32_is_the_same():
    """numba_windows.vstart32 (the walk's lanes: int32, vectorisable on AVX2) = vstart for int32 u,
    over the same cases and starts far from 0 (up to 2^30); +-2^30 beyond."""
    from vid2haircut.render.numba_windows import vstart, vstart32

    @numba.njit
    def both(slopes, us, v0s, out):
        for i in range(slopes.shape[0]):
            out[i, 0] = vstart(slopes[i], us[i], v0s[i])
            out[i, 1] = vstart32(slopes[i], np.int32(us[i]), v0s[i])

    rng = np.random.default_rng(4)
    n = 4000
    slopes = rng.uniform(-1, 1, n).astype(np.float32)
    slopes[:6] = [0.0, -0.0, 1.0, -1.0, 0.5, -0.5]
    us = rng.integers(0, 600, n)
    v0s = rng.uniform(-700, 700, n).astype(np.float32)
    v0s[:400] = np.nextafter(np.round(v0s[:400]), np.float32(np.inf))
    v0s[400:800] = np.nextafter(np.round(v0s[400:800]), np.float32(-np.inf))
    v0s[800:1000] = rng.uniform(-2.0**30, 2.0**30, 200).astype(np.float32)
    out = np.empty((n, 2), np.int64)
    both(slopes, us, v0s, out)
    assert np.array_equal(out[:, 0], out[:, 1])
    big = np.array([3e9, -3e9], np.float32)
    out2 = np.empty((2, 2), np.int64)
    both(np.zeros(2, np.float32), np.zeros(2, np.int64), big, out2)
    assert list(out2[:, 1]) == [2**30, -2**30]


def test_prefetch_row_is_a_hint_on_the_row_address():
    """numba_simd.prefetch_row: a prefetch instruction in the compiled code, on rows of 1-D and 2-D
    arrays of several dtypes, and no change to what the loop computes."""
    import platform

    from vid2haircut.render.numba_simd import prefetch_row

    @numba.njit
    def gathered(table, col, order, ahead):
        s = 0.0
        for k in range(order.shape[0]):
            if k + ahead < order.shape[0]:
                prefetch_row(table, order[k + ahead])
                prefetch_row(col, order[k + ahead])
            s += table[order[k], 1] + col[order[k]]
        return s

    rng = np.random.default_rng(5)
    order = rng.permutation(5000)
    for dt in (np.float32, np.float64, np.int64):
        table = rng.integers(-100, 100, (5000, 8)).astype(dt)
        col = rng.integers(-100, 100, 5000).astype(dt)
        assert gathered(table, col, order, 4) == float(table[order, 1].sum() + col[order].sum())
    if platform.machine() in ("x86_64", "AMD64"):
        asm = gathered.inspect_asm(gathered.signatures[0])
        assert "prefetcht0" in asm
