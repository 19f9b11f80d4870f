"""Checkpoint files: plain JSON, written atomically, read without executing anything (no pickle).

A checkpoint is one JSON object {"format": "ftorch", "kind": ..., "version": 1, ...}. Floats
are written as Python's shortest exact repr and arrays as zlib-compressed little-endian
float64 in base64, so a state survives a round trip bit for bit. Writing goes to a temporary
file in the same folder, flushed and fsynced, then renamed over the target: a crash leaves
either the old checkpoint or the new one, never half of one. Reading refuses, with one line
naming the file, a missing, truncated, foreign, other-kind or newer checkpoint.
"""
from __future__ import annotations

import base64
import json
import os
import tempfile
import zlib
from pathlib import Path

import numpy as np

from .errors import InputError

FORMAT = "ftorch"
VERSION = 1


def encode_array(array: np.ndarray) -> dict:
    """A float64 array as JSON-ready data: shape and compressed bytes."""
    data = np.ascontiguousarray(array, dtype="<f8")
    return {"shape": list(data.shape), "data": base64.b64encode(zlib.compress(data.tobytes(), 6)).decode("ascii")}


def decode_array(data: dict) -> np.ndarray:
    """Inverse of :func:`encode_array`; ValueError where the data are damaged."""
    try:
        shape = tuple(int(v) for v in data["shape"])
        flat = np.frombuffer(zlib.decompress(base64.b64decode(data["data"], validate=True)), dtype="<f8")
    except (KeyError, TypeError, ValueError, zlib.error) as err:
        raise ValueError(f"damaged array ({err})") from None
    if flat.size != int(np.prod(shape)):
        raise ValueError(f"array holds {flat.size} numbers, its shape {shape} asks for {int(np.prod(shape))}")
    return flat.reshape(shape).copy()


def save_checkpoint(path, kind: str, payload: dict) -> Path:
    """Write ``payload`` as a checkpoint of ``kind`` to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps({"format": FORMAT, "kind": kind, "version": VERSION, **payload}, separators=(",", ":"))
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as out:
            out.write(text)
            out.flush()
            os.fsync(out.fileno())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return path


def load_checkpoint(path, kind: str) -> dict:
    """Read a checkpoint of ``kind``; InputError naming ``path`` for anything else."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(f"{path}: not a readable checkpoint (truncated or not JSON: {err})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f"{path}: not an ftorch checkpoint")
    if data.get("kind") != kind:
        raise InputError(f"{path}: an ftorch checkpoint of kind {data.get('kind')!r}, expected {kind!r}")
    if data.get("version") != VERSION:
        raise InputError(f"{path}: checkpoint version {data.get('version')!r}, this ftorch reads version {VERSION}")
    return data
