"""Whether bf16 autocast pays on a device: decided at run time, never per preset.

bf16 autocast made the 3D-conv update 1.35-1.47x faster on a CPU with native bf16
(AVX-512-bf16 / AMX) and 30-600x *slower* on an AVX2-only CPU of the same machine kind, where
oneDNN emulates it (BENCHMARKS.md). CUDA GPUs from Ampere on have it natively.
"""

from __future__ import annotations

import functools
from pathlib import Path

import torch

#: /proc/cpuinfo flags that mean bf16 matrix/vector instructions in hardware.
NATIVE_BF16_CPU_FLAGS = frozenset({"avx512_bf16", "amx_bf16"})


@functools.cache
def cpu_flags() -> frozenset[str]:
    """The CPU feature flags the kernel reports (empty where /proc/cpuinfo is absent)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return frozenset()
    for line in text.splitlines():
        if line.startswith("flags"):
            return frozenset(line.partition(":")[2].split())
    return frozenset()


def native_bf16(device: torch.device) -> bool:
    """True when ``device`` computes bf16 in hardware."""
    if device.type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported(including_emulation=False)
    if device.type == "cpu":
        return bool(NATIVE_BF16_CPU_FLAGS & cpu_flags())
    return False


def use_bf16(setting: bool | str, device: torch.device) -> bool:
    """Resolve the ``bf16`` config value (True, False or "auto") for ``device``."""
    if setting == "auto":
        return native_bf16(device)
    return bool(setting)
