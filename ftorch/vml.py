"""MKL's vector math (VML) resolved before any parallel use, so unary float ops are exact every time.

On CPU, torch routes contiguous float unary ops (``sqrt``, ``exp``, ``log``, ``sin``, ...) to
oneMKL's VML, each intra-op thread on its own chunk. oneMKL picks each function's kernel lazily
on its first call; when that first call runs on several threads at once, one thread may run a
low-accuracy kernel over its whole chunk (pytorch/pytorch#188792, oneMKL 2024.2 as bundled in
the torch wheels). Here that made ``torch.sqrt`` in s_edge (eq. 3.11) wrong over the first
record batch in some fresh processes (how often and by how much: docs/decisions.md, "Exact float
ops in every process"), so the salient points, and with them a whole run, changed from one
process to the next with the same seed. Calling every VML function once on one element, in one thread, when ftorch is imported
settles the choice before any parallel call; later calls are unchanged, and where torch has no
MKL the calls are merely cheap.
"""
from __future__ import annotations

import torch

# the unary ops aten/src/ATen/cpu/vml.h may hand to MKL, and a few neighbours (any extra is harmless)
FUNCTIONS = ("acos", "asin", "atan", "cos", "cosh", "erf", "erfc", "erfinv", "exp", "expm1", "lgamma", "log",
             "log10", "log1p", "log2", "reciprocal", "rsqrt", "sin", "sinh", "sqrt", "tan", "tanh", "trunc")


def resolve_vml() -> None:
    """One call of each function in :data:`FUNCTIONS` on a single float32 and float64 element."""
    for dtype in (torch.float32, torch.float64):
        one = torch.full((1,), 0.5, dtype=dtype)
        for name in FUNCTIONS:
            getattr(torch, name)(one)
