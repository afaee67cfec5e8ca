"""Vectorisable exp and log for the numba kernels (float64 and float32, branch-free, a few ulp).

numba lowers ``math.exp`` / ``math.log1p`` to scalar libm calls (4-10 ns each), which cost more
than the rest of a compositing element together; these versions are plain arithmetic plus bit
casts, so LLVM vectorises the loops that use them (AVX2 / AVX-512; ~1 ns per element for both).
Measured against libm on 4 M random arguments: exp relative error <= 2.3e-16 on [-4.6, 0],
log(1 - a) relative error <= 6e-15 against log1p(-a) for a in [0.011, 0.99].
:func:`lane_exp` and :func:`lane_log1m` dispatch on the argument's type (float32 or float64), so
that one kernel source serves both dtypes; the float32 versions use shorter series (exp
relative error <= 1.2e-7 on [-87, 0], log1p(-a) <= 2.5e-7 on [0, 0.99]; tests/test_render_math.py).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from numba import njit, types
from numba.core.errors import NumbaIRAssumptionWarning
from numba.extending import intrinsic, overload

# When the kernels compile (once per machine), the overloads below, inlined into the compositing
# loops, trip numba's pedantic check of variable scopes: an internal warning without consequence for
# the compiled code, which would otherwise fill a fresh machine's first logs with requests to report
# a numba bug.
warnings.filterwarnings("ignore", category=NumbaIRAssumptionWarning)

_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_LOG2E = 1.4426950408889634
_LN2 = 0.6931471805599453
_SQRT2 = 1.4142135623730951


def _bitcast(src, dst):
    """A numba intrinsic reinterpreting the bits of a ``src`` value as ``dst`` (same width)."""

    @intrinsic
    def cast(typingctx, x):
        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(dst))

        return dst(src), codegen

    return cast


_f64_from_bits = _bitcast(types.int64, types.float64)
_bits_from_f64 = _bitcast(types.float64, types.int64)
_f32_from_bits = _bitcast(types.int32, types.float32)
_bits_from_f32 = _bitcast(types.float32, types.int32)


# Taylor series of exp(r) to degree 13 (truncation < 1e-17 for |r| <= ln(2) / 2), highest first
_EXP_COEFFS = tuple(1.0 / math.factorial(n) for n in range(13, -1, -1))
# 2 atanh(s) / (2 s) = sum s^(2n) / (2n + 1), n = 10 .. 0, as a polynomial in s^2
_LOG_COEFFS = tuple(1.0 / (2 * n + 1) for n in range(10, -1, -1))


@njit(cache=True, inline="always")
def _horner(x, coeffs):
    """sum c_i x^(n-i) for coefficients ``coeffs`` (highest power first), by Horner's rule."""
    p = coeffs[0]
    for c in coeffs[1:]:
        p = p * x + c
    return p


@njit(cache=True, inline="always")
def vexp(x):
    """exp(x) for x <= 0 (arguments below -700 are treated as -700)."""
    x = max(x, -700.0)
    # k as a float (np.floor; numba's math.floor returns an int64) and through int32 for the exponent
    # bits (exact: |k| <= 1010 here; NaN / inf give p NaN either way): conversions between float64
    # and int64 have no vector form before AVX-512DQ, and would leave the loops scalar on AVX2 CPUs
    k = np.floor(x * _LOG2E + 0.5)
    r = (x - k * _LN2_HI) - k * _LN2_LO  # |r| <= ln(2) / 2
    p = _horner(r, _EXP_COEFFS)
    return p * _f64_from_bits((np.int64(np.int32(k)) + 1023) << 52)


@njit(cache=True, inline="always")
def vlog(y):
    """log(y) for a positive normal float64 y."""
    bits = _bits_from_f64(y)
    e = ((bits >> 52) & 0x7FF) - 1023
    m = _f64_from_bits((bits & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000)  # mantissa in [1, 2)
    big = m > _SQRT2
    m = m * 0.5 if big else m  # now in [sqrt(2) / 2, sqrt(2)]
    e = e + 1 if big else e
    s = (m - 1.0) / (m + 1.0)  # log m = 2 atanh(s), |s| <= 0.1716
    p = _horner(s * s, _LOG_COEFFS)
    return 2.0 * s * p + np.float64(np.int32(e)) * _LN2  # |e| <= 1024; int32: as in vexp


_F = np.float32
# float32: Taylor series of exp(r) to degree 7 (truncation < 6e-9 for |r| <= ln(2) / 2), highest first
_EXP32_COEFFS = tuple(_F(1.0 / math.factorial(n)) for n in range(7, -1, -1))
# log1p(x) = x - x^2 / 2 + x^3 p(x) on [sqrt(1/2) - 1, sqrt(2) - 1], p of degree 7 fitted by least
# squares in float64 (benchmarks-free: tests/test_render_math.py checks the error), highest first
_LOG32_COEFFS = tuple(_F(c) for c in (-0.07995741388534612, 0.12547464828512545, -0.12940912355514422,
                                      0.142203946465506, -0.16646029318525066, 0.20000955231279197,
                                      -0.25000224531562865, 0.3333333085931708))
_LN2_HI32 = _F(0.693145751953125)  # 16 significant bits: k * _LN2_HI32 is exact for |k| < 256
_LN2_LO32 = _F(1.428606765330187e-06)


@njit(cache=True, inline="always")
def vexp32(x):
    """exp(x) for float32 x <= 0 (arguments below -87 are treated as -87)."""
    x = max(x, _F(-87.0))
    k = np.floor(x * _F(_LOG2E) + _F(0.5))
    r = (x - k * _LN2_HI32) - k * _LN2_LO32
    p = _horner(r, _EXP32_COEFFS)
    return p * _f32_from_bits((np.int32(k) + np.int32(127)) << np.int32(23))


@njit(cache=True, inline="always")
def vlog32(y):
    """log(y) for a positive normal float32 y (no division: a polynomial in the mantissa - 1)."""
    bits = _bits_from_f32(y)
    e = ((bits >> np.int32(23)) & np.int32(0xFF)) - np.int32(127)
    m = _f32_from_bits((bits & np.int32(0x007FFFFF)) | np.int32(0x3F800000))  # mantissa in [1, 2)
    big = m > _F(_SQRT2)
    m = m * _F(0.5) if big else m  # now in [sqrt(2) / 2, sqrt(2)]
    e = e + np.int32(1) if big else e
    x = m - _F(1.0)
    x2 = x * x
    return (x - _F(0.5) * x2 + x2 * x * _horner(x, _LOG32_COEFFS)) + _F(e) * _F(_LN2)


def lane_exp(x):
    """exp(x) for x <= 0 in the precision of x (numba only; see :func:`vexp`, :func:`vexp32`)."""
    raise NotImplementedError("lane_exp is for numba-compiled code")


def lane_log1m(a):
    """log(1 - a) for 0 <= a < 1 in the precision of a, with the rounding of 1 - a corrected
    (numba only)."""
    raise NotImplementedError("lane_log1m is for numba-compiled code")


@overload(lane_exp, inline="always", jit_options={"cache": True})
def _lane_exp(x):
    if x == types.float32:
        return lambda x: vexp32(x)
    return lambda x: vexp(x)


@overload(lane_log1m, inline="always", jit_options={"cache": True})
def _lane_log1m(a):
    if a == types.float32:
        def log1m32(a):
            y = _F(1.0) - a
            # 1 - y - a: the rounding error of y, exact; 0 for a >= 1/2, else y is in (1/2, 1] and
            # 2 - y stands for 1 / y (the correction is below half an ulp of 1 anyway)
            return vlog32(y) + ((_F(1.0) - y) - a) * (_F(2.0) - y)
        return log1m32

    def log1m64(a):
        y = 1.0 - a
        return vlog(y) + ((1.0 - y) - a) / y
    return log1m64


def lane_cast(x, like):
    """x converted to the float type of ``like`` (a float32 or float64 scalar, or an array of
    one; numba only): float32 arithmetic with an int or a float64 constant would otherwise be done
    in float64."""
    raise NotImplementedError("lane_cast is for numba-compiled code")


@overload(lane_cast, inline="always", jit_options={"cache": True})
def _lane_cast(x, like):
    if isinstance(like, types.Array):
        like = like.dtype
    if like == types.float32:
        return lambda x, like: np.float32(x)
    return lambda x, like: np.float64(x)
