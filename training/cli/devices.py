"""Choosing the torch device from a --device argument, and naming the machine a report was computed on."""
from __future__ import annotations

import platform

import numpy as np
import torch

from ftorch.settings import as_device


def resolve_device(name: str) -> torch.device:
    """'auto' -> CUDA when present else CPU; 'cpu'; 'cuda' or 'cuda:N' (refused clearly without CUDA)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return as_device(name, "--device", "cpu, cuda, cuda:N or auto")


def machine(device: torch.device) -> dict:
    """What fixes a run's last bits besides its seed and settings: the processor, the CPU kernels
    torch dispatches to (e.g. AVX2 or AVX512), torch's and numpy's versions, and the GPU where one
    computed. Runs agree report for report where these agree; elsewhere float rounding may differ in
    the last bit and a learner take another path (docs/usage.md, "Reproducibility")."""
    out = {"cpu": _cpu_name(), "cpu_kernels": torch.backends.cpu.get_cpu_capability(),
           "torch": torch.__version__, "numpy": np.__version__}
    if device.type == "cuda":
        out["gpu"] = torch.cuda.get_device_name(device)
    return out


def start_memory(device: torch.device) -> None:
    """Count a task's peak GPU memory from now on (:func:`peak_memory`); nothing on a CPU."""
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)


def peak_memory(device: torch.device) -> float | None:
    """The GPU memory (MiB) this process's tensors held at most since :func:`start_memory` (torch's
    allocator; the CUDA context, some hundred MiB per process, comes on top), so that runs sharing one
    GPU (``--workers N --device cuda``) can be sized; None on a CPU."""
    if device.type != "cuda":
        return None
    return round(torch.cuda.max_memory_allocated(device) / 2**20, 1)


def described(machine: dict) -> str:
    """:func:`machine`'s entry in one line, as reports print it."""
    gpu = f"{machine['gpu']}; " if "gpu" in machine else ""
    return f"{gpu}{machine['cpu']}, {machine['cpu_kernels']} kernels; torch {machine['torch']}, numpy {machine['numpy']}"


def _cpu_name() -> str:
    """The processor's model name (Linux's /proc/cpuinfo; elsewhere what ``platform`` knows)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()
