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
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_MAX = -4

_state: dict[str, bool] = {}


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
