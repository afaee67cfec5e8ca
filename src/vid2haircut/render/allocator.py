"""CPU allocator tuning for the renderer (glibc only).

The renderer allocates many short-lived tensors of tens of megabytes per call. glibc serves blocks
above its mmap threshold (at most 32 MB) with fresh ``mmap`` pages and returns them on ``free``,
so every such temporary pays one page fault per 4 KiB page when first written; measured on the
project's 2-core CPU this makes an elementwise op on 7.5 M int64 values 5x slower (50 ms instead
of 10 ms) and the whole render several times slower. Keeping freed memory in the process heap
(``M_MMAP_MAX = 0``, a large ``M_TRIM_THRESHOLD``) removes that cost after the first call.
The price: the process keeps its peak heap size instead of returning memory to the OS.

``render_strands`` calls :func:`tune_cpu_allocator` once when it first renders on the CPU, unless
the environment variable ``VID2HAIRCUT_MALLOC_TUNING`` is ``0``.

:func:`aligned_empty` gives arrays whose rows start on cache lines: glibc and numpy align blocks
to 16 bytes only, so a 64-byte row of a plain ``np.empty`` array spans two cache lines 3 times in 4.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

import numpy as np

_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_MAX = -4

_state: dict[str, bool] = {}


CACHE_LINE = 64


def aligned_empty(shape, dtype, align: int = CACHE_LINE) -> np.ndarray:
    """An uninitialised C-contiguous array of ``shape`` and ``dtype`` whose data starts on an
    ``align``-byte boundary (a view of a slightly larger byte buffer that it keeps alive). With
    rows of 64 bytes (or 32, 16) each row then lies in one cache line: the exact model's rows of
    per-instance sums, read in a scattered order by the gradient reduction, take 3.0 -> 2.3 ms
    there aligned (4k strands at 256 x 256, AMD Zen 4, 2 threads; the same values)."""
    shape = (shape,) if isinstance(shape, (int, np.integer)) else tuple(shape)
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    raw = np.empty(nbytes + align, np.uint8)
    off = -raw.ctypes.data % align
    return raw[off:off + nbytes].view(dtype).reshape(shape)


def tune_cpu_allocator() -> bool:
    """Keep freed memory in the heap (glibc ``mallopt``). Returns True when applied (once per process)."""
    if "done" in _state:
        return _state["done"]
    ok = False
    if os.environ.get("VID2HAIRCUT_MALLOC_TUNING", "1") != "0":
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            mallopt = libc.mallopt
            mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
            ok = bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))
            mallopt(_M_TOP_PAD, 256 * 2**20)
        except (OSError, AttributeError):  # not glibc (macOS, Windows, musl): nothing to do
            ok = False
    _state["done"] = ok
    return ok
