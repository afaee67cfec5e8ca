"""The machine a result was computed on, as recorded next to fits and benchmark figures.

Fits are bit-reproducible on one kind of machine, not across instruction sets: torch picks its CPU
kernels per CPU (``torch.backends.cpu.get_cpu_capability()``: ``AVX2``, ``AVX512``, ...) and
those round differently in the last bits (vectorised sums in another order, other exp and matrix
product kernels); numba compiles the renderer for the CPU it runs on (fused multiply-adds where
the CPU has them, the walk's compaction, :data:`vid2haircut.render.numba_simd.COMPACTION`); and
a Stage 2 fit of hundreds of steps carries such last-bit differences into its metrics (README,
"Fitting speed"). :func:`machine_info` names all of these, so a figure can be traced to the
machine kind that made it (``stage1.json``, ``stage2.json``, the renderer benchmark's header).
"""

from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_model(cpuinfo: str | Path = "/proc/cpuinfo") -> str:
    """The CPU's model name with its family and model numbers ("AMD EPYC (family 25 model 1)"),
    read from ``cpuinfo`` (Linux); ``platform.processor()`` (or "unknown") where that is missing."""
    fields: dict[str, str] = {}
    try:
        for line in Path(cpuinfo).read_text(errors="replace").splitlines():
            key, sep, value = line.partition(":")
            if not sep:
                if fields:
                    break  # the first processor's block is enough
                continue
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    name = fields.get("model name") or platform.processor() or "unknown"
    if "cpu family" in fields and "model" in fields:
        return f"{name} (family {fields['cpu family']} model {fields['model']})"
    return name


def machine_info(device: str = "cpu") -> dict:
    """What decides a result's speed and its last bits on this machine.

    Args:
        device: the torch device the computation ran on ("cpu", "cuda", "cuda:1").

    Returns:
        A JSON-able dict: ``cpu`` (:func:`cpu_model`), ``logical_cpus``, ``torch`` (version),
        ``torch_cpu_capability``, ``torch_threads``, ``numba`` (version), ``numba_cpu`` (the CPU
        name numba compiles for), ``numba_threading`` (the threading layer the renderer's kernels
        run on, :func:`vid2haircut.render.numba_backend.numba_available`: "tbb" or "workqueue"; it
        sets their speed, not their results), ``render_compaction`` (the walk's compaction), ``device``, and
        ``cuda_device`` (the GPU's name on a CUDA device, else None).
    """
    import numba
    import torch
    import llvmlite.binding as llvm
    from numba.core import config

    from vid2haircut.render.numba_backend import numba_available
    from vid2haircut.render.numba_simd import COMPACTION

    cuda = None
    if str(device).startswith("cuda") and torch.cuda.is_available():
        cuda = torch.cuda.get_device_name(torch.device(device))
    return {
        "cpu": cpu_model(),
        "logical_cpus": os.cpu_count(),
        "torch": torch.__version__,
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "torch_threads": torch.get_num_threads(),
        "numba": numba.__version__,
        "numba_cpu": config.CPU_NAME or llvm.get_host_cpu_name(),
        "numba_threading": config.THREADING_LAYER if numba_available() else None,
        "render_compaction": COMPACTION,
        "device": str(device),
        "cuda_device": cuda,
    }


def machine_summary(info: dict | None = None) -> str:
    """One line naming the machine of :func:`machine_info` (``info``; this machine's when None), for
    the headers of benchmark reports: "AMD EPYC (family 25 model 1); torch 2.13.0+cpu, AVX2 kernels,
    2 threads; numba target znver3, tbb threads, walk compaction permute"."""
    m = machine_info() if info is None else info
    gpu = f"; GPU {m['cuda_device']}" if m["cuda_device"] else ""
    return (f"{m['cpu']}; torch {m['torch']}, {m['torch_cpu_capability']} kernels, {m['torch_threads']} threads; "
            f"numba target {m['numba_cpu']}, {m.get('numba_threading')} threads, "
            f"walk compaction {m['render_compaction']}{gpu}")
