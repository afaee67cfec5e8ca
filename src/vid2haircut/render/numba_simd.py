"""Explicit 16-lane vector code for the window walk (numba intrinsics emitting LLVM vector IR).

numba has no vector types; its loops are vectorised by LLVM or not at all. The walk's per-line
loop over the 16 lanes of a tile line (:mod:`.numba_lines`) is short, runs ~1 M times per 4k-strand
frame, and sits in one large inlined kernel, where LLVM vectorises it behind run-time alias
checks, register spills and a scalar tail: ~60-80 cycles per line measured, for ~20 vector
instructions of work. :func:`line16` emits that work directly as ``<16 x float>`` (or
``<16 x double>``) operations, in the same order and with the same rounding as the scalar numba
code (no fast-math flags: no fused multiply-adds, the same comparisons and selects as numba's
``min`` / ``max``), so the elements it appends are bit for bit those of the loop
(tests/test_render_math.py, tests/test_render_backends.py). :func:`line8` does the same for 8 of
the 16 lanes, for the lines whose window lanes all lie in one half of the tile (about half the
lines of a frame; on AVX2 a 16-lane line is two registers of 8, so it halves their work).

The kept lanes are packed to the front and stored with plain vector stores: 16 slots from the
cursor hold the kept lanes, then zeros (that the next line overwrites). How they are packed
depends on the CPU (:data:`COMPACTION`, chosen once per machine, when the kernels compile):

- ``"compress"`` (AVX-512F): LLVM's ``experimental.vector.compress``, one ``vcompress`` into a
  register. A compress straight to memory (``masked.compressstore``) would spare the zeros, but
  AMD Zen 4 runs that form as a microcoded sequence of ~100+ cycles (measured on this project's
  2-core AMD EPYC: 30 ms more per 4k-strand forward than a scalar loop), while the register form
  is fast on Intel and AMD alike.
- ``"permute"`` (AVX2, float32): per half of 8 lanes, one ``vpermps`` / ``vpermd`` with the lane
  order looked up in a 256-entry table of the 8-bit mask (float64 lanes go lane by lane). LLVM's
  compress cannot serve here: numba's LLVM (llvmlite 0.50) aborts the whole process with an
  assertion ("Cannot create FP integer constant") when it expands the compress of a float vector
  for an AVX2 target (found on an AMD EPYC Zen 3).
- ``"lanes"`` (anything else): each lane stored at the cursor, which only the kept lanes advance;
  the walk then takes its numba loop instead (:data:`USE_LINE16`).
"""

from __future__ import annotations

import llvmlite.binding as _llvm
from llvmlite import ir as _ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

LANES = 16
_I64 = _ir.IntType(64)
_I32 = _ir.IntType(32)
HAS_VECTOR_COMPRESS = tuple(_llvm.llvm_version_info) >= (19,)
"""Whether numba's LLVM has ``experimental.vector.compress`` (LLVM 19 on)."""


COMPACTIONS = ("compress", "permute", "lanes")
"""The ways :func:`line16` can pack the kept lanes (module docstring), fastest first."""


def parse_features(flat: str) -> dict[str, bool]:
    """LLVM's feature string ("+avx2,-avx512f,...") as {feature: enabled}."""
    return {f[1:]: f[0] == "+" for f in flat.split(",") if len(f) > 1 and f[0] in "+-"}


def _host_features() -> dict[str, bool]:
    """The CPU features numba compiles for: ``NUMBA_CPU_FEATURES`` when set, else the host's (with
    ``NUMBA_ENABLE_AVX=0`` honoured), as numba's code generator takes them."""
    try:
        from numba.core import codegen, config

        flat = config.CPU_FEATURES if config.CPU_FEATURES is not None else codegen.get_host_cpu_features()
        return parse_features(flat)
    except Exception:  # noqa: BLE001 (any failure of the feature query: take the portable stores)
        return {}


def available_compactions(features: dict | None = None) -> tuple[str, ...]:
    """The compactions :func:`make_line16` can compile for this CPU (``features``: the CPU features
    numba compiles for, queried when None), fastest first; ``"lanes"`` always."""
    f = _host_features() if features is None else features
    runs = {"compress": HAS_VECTOR_COMPRESS and f.get("avx512f", False), "permute": f.get("avx2", False),
            "lanes": True}
    return tuple(c for c in COMPACTIONS if runs[c])


COMPACTION = available_compactions()[0]
"""How :func:`line16` packs the kept lanes on this machine: ``"compress"``, ``"permute"`` or
``"lanes"`` (module docstring)."""
USE_LINE16 = COMPACTION != "lanes"
"""Whether the walk should append through :func:`line16` rather than its numba loop (the lane by
lane stores are slower than that loop); the backend passes it to the kernels as a run-time flag
(tests set it both ways, which changes only the path taken, never the code compiled)."""

# for each 8-bit mask: the lanes whose bits are set, in lane order, then 0s (vpermps indices)
_PERM_LUT = tuple(tuple([i for i in range(8) if m >> i & 1] + [0] * (8 - bin(m).count("1"))) for m in range(256))


def _kind(elt) -> tuple[str, int]:
    """LLVM type suffix and bit width of a scalar element type (float, double or iN)."""
    if isinstance(elt, _ir.IntType):
        return f"i{elt.width}", elt.width
    return ("f32", 32) if isinstance(elt, _ir.FloatType) else ("f64", 64)


def _splat(builder, value, n: int = LANES):
    """<n x T> with every lane ``value``."""
    vt = _ir.VectorType(value.type, n)
    one = builder.insert_element(_ir.Constant(vt, _ir.Undefined), value, _ir.Constant(_I32, 0))
    return builder.shuffle_vector(one, _ir.Constant(vt, _ir.Undefined), _ir.Constant(_ir.VectorType(_I32, n), None))


def _lane_store(builder, vec, bits, ptr, off):
    """The ``"lanes"`` compaction: as many zeros as ``vec`` has lanes, then each lane at the cursor
    (its value if kept, else 0), which only the kept lanes advance."""
    zero = _ir.Constant(vec.type, None)
    builder.store(zero, builder.bitcast(builder.gep(ptr, [off], inbounds=True), vec.type.as_pointer()), align=4)
    pos = off
    for i in range(vec.type.count):
        lane = _ir.Constant(_I32, i)
        bit = builder.extract_element(bits, lane)
        value = builder.select(bit, builder.extract_element(vec, lane), _ir.Constant(vec.type.element, None))
        builder.store(value, builder.gep(ptr, [pos], inbounds=True), align=4)
        pos = builder.add(pos, builder.zext(bit, _I64))
    return pos


def _permute_store(builder, vec, bits, ptr, off):
    """The ``"permute"`` compaction (AVX2, 32-bit lanes): per group of 8 lanes, the kept ones moved
    to the front by one vpermps / vpermd (the order from :data:`_PERM_LUT` at the 8-bit mask), the
    rest zeroed, one store of 8 slots."""
    module = builder.module
    elt = vec.type.element
    v8, i8x = _ir.VectorType(elt, 8), _ir.VectorType(_I32, 8)
    lut = module.globals.get("vid2haircut_perm_lut")
    if lut is None:
        lut_ty = _ir.ArrayType(i8x, 256)
        lut = _ir.GlobalVariable(module, lut_ty, "vid2haircut_perm_lut")
        lut.linkage = "internal"
        lut.global_constant = True
        lut.align = 32
        lut.initializer = _ir.Constant(lut_ty, [_ir.Constant(i8x, list(row)) for row in _PERM_LUT])
    fname = "llvm.x86.avx2.permd" if isinstance(elt, _ir.IntType) else "llvm.x86.avx2.permps"
    perm = cgutils.get_or_insert_function(module, _ir.FunctionType(v8, [v8, i8x]), fname)
    ctpop = cgutils.get_or_insert_function(module, _ir.FunctionType(_I64, [_I64]), "llvm.ctpop.i64")
    iota = _ir.Constant(i8x, list(range(8)))
    pos = off
    for part in range(vec.type.count // 8):
        idx = _ir.Constant(i8x, [part * 8 + i for i in range(8)])
        v = builder.shuffle_vector(vec, _ir.Constant(vec.type, _ir.Undefined), idx)
        b = builder.shuffle_vector(bits, _ir.Constant(bits.type, _ir.Undefined), idx)
        mask = builder.zext(builder.bitcast(b, _ir.IntType(8)), _I64)
        order = builder.load(builder.gep(lut, [_ir.Constant(_I64, 0), mask], inbounds=True), align=32)
        kept = builder.call(ctpop, [mask])
        front = builder.icmp_unsigned("<", iota, _splat(builder, builder.trunc(kept, _I32), 8))
        packed = builder.select(front, builder.call(perm, [v, order]), _ir.Constant(v8, None))
        builder.store(packed, builder.bitcast(builder.gep(ptr, [pos], inbounds=True), v8.as_pointer()), align=4)
        pos = builder.add(pos, kept)
    return pos


def _vector_compress_store(builder, vec, bits, ptr, off):
    """The ``"compress"`` compaction (AVX-512): LLVM's vector compress into a register, one plain
    store (64-bit lanes as two halves of 8, one 512-bit register each)."""
    elt = vec.type.element
    kind, width = _kind(elt)
    lanes = min(vec.type.count, 16 if width <= 32 else 8)
    vt, bt = _ir.VectorType(elt, lanes), _ir.VectorType(_ir.IntType(1), lanes)
    pack = cgutils.get_or_insert_function(builder.module, _ir.FunctionType(vt, [vt, bt, vt]),
                                          f"llvm.experimental.vector.compress.v{lanes}{kind}")
    ctpop = cgutils.get_or_insert_function(builder.module, _ir.FunctionType(_I64, [_I64]), "llvm.ctpop.i64")
    pos = off
    for part in range(vec.type.count // lanes):
        if lanes == vec.type.count:
            v, b = vec, bits
        else:
            idx = _ir.Constant(_ir.VectorType(_I32, lanes), [part * lanes + i for i in range(lanes)])
            v = builder.shuffle_vector(vec, _ir.Constant(vec.type, _ir.Undefined), idx)
            b = builder.shuffle_vector(bits, _ir.Constant(bits.type, _ir.Undefined), idx)
        packed = builder.call(pack, [v, b, _ir.Constant(vt, None)])
        builder.store(packed, builder.bitcast(builder.gep(ptr, [pos], inbounds=True), vt.as_pointer()), align=4)
        kept = builder.call(ctpop, [builder.zext(builder.bitcast(b, _ir.IntType(lanes)), _I64)])
        pos = builder.add(pos, kept)
    return pos


def _compress_store(builder, vec, bits, ptr, off, compaction):
    """Store the lanes of ``vec`` (<n x T>, n = 16 or 8) whose ``bits`` (<n x i1>) are set, in lane
    order, at ptr[off], by ``compaction`` (module docstring); writes at most n slots from off on (the
    kept lanes, then zeros; groups of 8 reach off + (kept before the last group) + 8 only). Returns
    off + the kept count (i64)."""
    if compaction == "compress":
        return _vector_compress_store(builder, vec, bits, ptr, off)
    if compaction == "permute" and _kind(vec.type.element)[1] == 32:
        return _permute_store(builder, vec, bits, ptr, off)
    return _lane_store(builder, vec, bits, ptr, off)


def _data(context, builder, aryty, ary):
    return context.make_array(aryty)(context, builder, ary).data


def _load(builder, ptr, off, n):
    """<n x T> from ptr[off:off + n] (unaligned)."""
    p = builder.gep(ptr, [off], inbounds=True)
    return builder.load(builder.bitcast(p, _ir.VectorType(ptr.type.pointee, n).as_pointer()), align=4)


def make_line16(compaction: str = COMPACTION, lanes: int = LANES):
    """The :func:`line16` intrinsic compiled with ``compaction`` (one of
    :func:`available_compactions`; tests build each); ``lanes=8``: the :func:`line8` intrinsic."""
    if compaction not in COMPACTIONS:
        raise ValueError(f"unknown compaction {compaction!r}")
    if lanes == LANES:
        @intrinsic
        def line16(typingctx, qa, qb, vlo, vhi, hl, zref, with_zref, zg, base, rr, dv, qv, logop, half, cut, z, big,
                   keep_any, pr, si, e_al, e_la, e_p, n, lanes_on):
            return _line16_typing(compaction, LANES, qa, qb, vlo, vhi, hl, zref, e_al, e_la, e_p)

        return line16
    if lanes != 8:
        raise ValueError(f"lanes must be 16 or 8, got {lanes}")

    @intrinsic
    def line8(typingctx, qa, qb, vlo, vhi, hl, zref, with_zref, zg, base, rr, dv, qv, logop, half, cut, z, big,
              keep_any, pr, si, e_al, e_la, e_p, n, lanes_on, lane0):
        return _line16_typing(compaction, 8, qa, qb, vlo, vhi, hl, zref, e_al, e_la, e_p)

    return line8


def _line16_typing(compaction, nl, qa, qb, vlo, vhi, hl, zref, e_al, e_la, e_p):
    """One line of the window walk (:func:`vid2haircut.render.numba_lines.walk_lines`) in 16 lanes:
    update z_ref, append the line's kept elements at e_*[n:] and return how many (int64).
    ``nl`` = 8: lanes lane0 .. lane0 + 7 of the line only (``lane0``, uint64, a last argument after
    ``lanes_on``: 0 or 8), the others left as they are (for lines whose window lanes all lie in one half:
    the same elements and z_ref as line16 gives, since it keeps no lane and changes no z_ref
    outside the window).

    Lane i (u = tile u0 + i) of line ``rr`` (tile relative, int32) is in the window when
    vlo[i] <= rr <= vhi[i]; there, with ``with_zref``, zref[base + i] := zg if zg < zref[base + i]
    (``zg`` must be finite and > 0, as a drawn Gaussian's depth is, and zref never NaN).
    Its power p = logop - half (qa[i] + dv (qb[i] + qv dv)), head factor
    f = min(max((hl[base + i] - z) big, 0), 1); kept when in the window, p > cut, f > 0,
    ``keep_any`` and bit i of ``lanes_on`` (uint32: the exact model's live pixels of the line, all
    ones for the binned model); its element is (pixel pr + i si (int32), p, f) into (e_p, e_al, e_la).
    qa / qb / hl / zref / e_al / e_la and the float scalars share one float dtype (float32 or
    float64); vlo / vhi / e_p are int32; base and n uint64. Writes at most ``nl`` slots of each
    output from n on (the kept lanes, then zeros), packed by ``compaction``.
    """
    ft = qa.dtype
    extra = (types.uint64,) if nl != LANES else ()
    sig = types.int64(qa, qb, vlo, vhi, hl, zref, types.boolean, ft, types.uint64, types.int32, ft, ft, ft, ft, ft, ft,
                      ft, types.boolean, types.int32, types.int32, e_al, e_la, e_p, types.uint64, types.uint32, *extra)

    def codegen(context, builder, signature, args):
        (qa_v, qb_v, lo_v, hi_v, hl_v, zr_v, wz_v, zg_v, base_v, rr_v, dv_v, qv_v, logop_v, half_v, cut_v, z_v, big_v,
         keep_v, pr_v, si_v, al_v, la_v, p_v, n_v) = args[:24]
        on_v = args[24]
        lane0 = args[25] if nl != LANES else _ir.Constant(_I64, 0)
        aty = signature.args
        qa_ = _load(builder, _data(context, builder, aty[0], qa_v), lane0, nl)
        qb_ = _load(builder, _data(context, builder, aty[1], qb_v), lane0, nl)
        lo_ = _load(builder, _data(context, builder, aty[2], lo_v), lane0, nl)
        hi_ = _load(builder, _data(context, builder, aty[3], hi_v), lane0, nl)
        row = builder.add(base_v, lane0)  # the lanes' first slot in hl and zref
        hl_ = _load(builder, _data(context, builder, aty[4], hl_v), row, nl)
        zero = _ir.Constant(qa_.type, None)
        one = _splat(builder, _ir.Constant(qa_.type.element, 1.0), nl)
        # p = logop - half * (qa + dv * (qb + qv * dv)), operation by operation as the scalar code
        dvs = _splat(builder, dv_v, nl)
        t = builder.fadd(qb_, builder.fmul(_splat(builder, qv_v, nl), dvs))
        t = builder.fadd(qa_, builder.fmul(dvs, t))
        p = builder.fsub(_splat(builder, logop_v, nl), builder.fmul(_splat(builder, half_v, nl), t))
        # f = min(max((hl - z) * big, 0), 1) with numba's max(a, b) = b if b > a else a (min: b < a)
        x = builder.fmul(builder.fsub(hl_, _splat(builder, z_v, nl)), _splat(builder, big_v, nl))
        x = builder.select(builder.fcmp_ordered(">", zero, x), zero, x)
        f = builder.select(builder.fcmp_ordered("<", one, x), one, x)
        rrs = _splat(builder, rr_v, nl)
        inside = builder.and_(builder.icmp_signed(">=", rrs, lo_), builder.icmp_signed("<=", rrs, hi_))
        with builder.if_then(wz_v):
            zptr = builder.bitcast(builder.gep(_data(context, builder, aty[5], zr_v), [row], inbounds=True),
                                   qa_.type.as_pointer())
            zr = builder.load(zptr, align=4)
            # zg where inside and zg < zr, else zr, as minnum(zg + (inside ? 0 : +inf), zr): the same value,
            # as neither operand is ever NaN (zg is a drawn Gaussian's depth, finite and > 0; zr is +inf,
            # then only smaller zg's), so minnum may be a plain vminps ("nnan"). The row is stored whole:
            # a select of the loaded zr would become a masked store (vmaskmovps on AVX2), from which the
            # next line's load of the same z_ref row cannot take its value (measured: the walk 5 ms
            # slower single-thread on an AMD Zen 3)
            inf = _splat(builder, _ir.Constant(qa_.type.element, float("inf")), nl)
            t = builder.fadd(_splat(builder, zg_v, nl), builder.select(inside, zero, inf))
            fmin = cgutils.get_or_insert_function(builder.module, _ir.FunctionType(qa_.type, [qa_.type, qa_.type]),
                                                  f"llvm.minnum.v{nl}{_kind(qa_.type.element)[0]}")
            builder.store(builder.call(fmin, [t, zr], fastmath=("nnan",)), zptr, align=4)
        kept = builder.and_(inside, builder.fcmp_ordered(">", p, _splat(builder, cut_v, nl)))
        kept = builder.and_(kept, builder.fcmp_ordered(">", f, zero))
        kept = builder.select(keep_v, kept, _ir.Constant(kept.type, None))
        on = builder.trunc(builder.lshr(builder.zext(on_v, _I64), lane0), _ir.IntType(nl))  # bits lane0 ..
        kept = builder.and_(kept, builder.bitcast(on, kept.type))
        # pixel pr + i si of lane i = lane0 + j (int32, wrapping: the same value in any order)
        iota = builder.add(_ir.Constant(_ir.VectorType(_I32, nl), list(range(nl))),
                           _splat(builder, builder.trunc(lane0, _I32), nl))
        pix = builder.add(_splat(builder, pr_v, nl), builder.mul(iota, _splat(builder, si_v, nl)))
        _compress_store(builder, p, kept, _data(context, builder, aty[20], al_v), n_v, compaction)
        _compress_store(builder, f, kept, _data(context, builder, aty[21], la_v), n_v, compaction)
        end = _compress_store(builder, pix, kept, _data(context, builder, aty[22], p_v), n_v, compaction)
        return builder.sub(end, n_v)

    return sig, codegen


line16 = make_line16()
"""One line of the window walk in 16 lanes, compiled with this machine's :data:`COMPACTION`
(:func:`_line16_typing` describes its arguments)."""
line8 = make_line16(lanes=8)
"""Lanes lane0 .. lane0 + 7 of a line (an argument after ``n``): :func:`line16`'s work halved, for
the lines of windows whose columns in the tile all lie in one half (about half the lines of the
benchmark scene; on AVX2 a 16-lane line is two registers of 8)."""


@intrinsic
def prefetch_row(typingctx, ary, i):
    """Ask the CPU to bring row ``i`` of the C-contiguous array ``ary`` (its first cache line) into
    the cache (``llvm.prefetch``, read, high locality): a hint with no effect on any value."""
    if not isinstance(ary, types.Array) or not isinstance(i, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        a = context.make_array(sig.args[0])(context, builder, args[0])
        stride0 = builder.extract_value(a.strides, 0)
        idx = context.cast(builder, args[1], sig.args[1], types.int64)
        i8p = _ir.IntType(8).as_pointer()
        p = builder.gep(builder.bitcast(a.data, i8p), [builder.mul(idx, stride0)])
        fn = cgutils.get_or_insert_function(builder.module, _ir.FunctionType(_ir.VoidType(), [i8p, _I32, _I32, _I32]),
                                            "llvm.prefetch.p0")
        builder.call(fn, [p, _I32(0), _I32(3), _I32(1)])
        return context.get_dummy_value()

    return types.void(ary, i), codegen
