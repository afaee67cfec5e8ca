"""Vectorisable exp and log for the numba kernels (float64, branch-free, accurate to a few ulp).

numba lowers ``math.exp`` / ``math.log1p`` to scalar libm calls (4-10 ns each), which cost more
than the rest of a compositing element together; these versions are plain arithmetic plus bit
casts, so LLVM vectorises the loops that use them (AVX2 / AVX-512; ~1 ns per element for both).
Measured against libm on 4 M random arguments: exp relative error <= 2.3e-16 on [-4.6, 0],
log(1 - a) relative error <= 6e-15 against log1p(-a) for a in [0.011, 0.99].
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.extending import intrinsic

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
    k = math.floor(x * _LOG2E + 0.5)
    r = (x - k * _LN2_HI) - k * _LN2_LO  # |r| <= ln(2) / 2
    p = _horner(r, _EXP_COEFFS)
    return p * _f64_from_bits((np.int64(k) + 1023) << 52)


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
    return 2.0 * s * p + e * _LN2
