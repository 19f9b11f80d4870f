"""Choosing the torch device from a --device argument."""
from __future__ import annotations

import torch

from ftorch.errors import InputError


def resolve_device(name: str) -> torch.device:
    """'auto' -> CUDA when present else CPU; 'cpu'; 'cuda' or 'cuda:N' (refused clearly without CUDA)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(f"--device {name}: CUDA is not available on this machine")
    try:
        return torch.device(name)
    except RuntimeError:
        raise InputError(f"--device {name!r}: expected cpu, cuda, cuda:N or auto") from None
