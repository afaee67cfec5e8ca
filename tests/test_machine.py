"""The machine record stored with fits (vid2haircut.machine)."""

import json

import numba
import torch

from vid2haircut.machine import cpu_model, machine_info, machine_summary
from vid2haircut.render import numba_simd


def test_cpu_model_reads_the_first_processor(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 17\n"
                    "model name\t: AMD EPYC 9R14\nflags\t\t: fpu avx2\n\n"
                    "processor\t: 1\ncpu family\t: 6\nmodel\t\t: 85\nmodel name\t: Other\n")
    assert cpu_model(info) == "AMD EPYC 9R14 (family 25 model 17)"
    bare = tmp_path / "bare"
    bare.write_text("processor : 0\nmodel name : Some CPU\n")
    assert cpu_model(bare) == "Some CPU"
    assert isinstance(cpu_model(tmp_path / "missing"), str)   # no /proc: platform's name or "unknown"


def test_machine_info_names_what_decides_the_last_bits():
    info = machine_info("cpu")
    assert json.loads(json.dumps(info)) == info
    assert info["torch"] == torch.__version__ and info["torch_threads"] == torch.get_num_threads()
    assert info["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert info["render_compaction"] == numba_simd.COMPACTION in numba_simd.COMPACTIONS
    assert info["numba_cpu"] and info["cpu"] and info["logical_cpus"] >= 1
    assert info["device"] == "cpu" and info["cuda_device"] is None
    assert info["numba_threading"] == numba.config.THREADING_LAYER


def test_machine_summary_names_cpu_and_kernel_sets():
    line = machine_summary()
    assert line.startswith(cpu_model() + "; torch " + torch.__version__)
    assert f"{torch.backends.cpu.get_cpu_capability()} kernels, {torch.get_num_threads()} threads" in line
    assert line.endswith(f"walk compaction {numba_simd.COMPACTION}") and "GPU" not in line
    gpu = machine_summary({**machine_info(), "cuda_device": "NVIDIA H100"})
    assert gpu.endswith("; GPU NVIDIA H100")
