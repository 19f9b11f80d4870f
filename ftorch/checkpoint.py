"""Checkpoint files: plain JSON, written atomically, read without executing anything (no pickle).

A checkpoint is one JSON object {"format": "ftorch", "kind": ..., "version": 4, ...}. Floats
are written as Python's shortest exact repr; arrays as zlib-compressed little-endian float32
where that holds every value exactly (feature values are computed in float32), else float64,
in base64 blocks of ``ROWS`` rows (a block unchanged since the last checkpoint is not compressed
again); long texts (feature tables) as xz-compressed UTF-8 in base64: xz at its fastest preset
shrinks the repeated structure of compound features' JSON far more than zlib in about zlib's time,
while float arrays gain little from it at several times the cost (docs/benchmark.md, "Design
choices measured once"). An array that mostly repeats another
one the reader holds too (the instance list's values are those of the value cache) is written
relative to it: the XOR of the two arrays' bits, zero where they agree, which compresses to almost
nothing and restores exactly (version 4). Versions 2 (texts in zlib) and 3 still read: a block's
codec is told by its magic bytes, and their arrays are absolute. So a state
survives a round trip bit for bit. Compressed data are inflated only up to the size their
declared shape allows (``MAX_BYTES`` at most), and readers give the shape the rest of the file
implies (a value cache's features x images, a CPT's parents), so a declared shape that differs is
refused before anything is inflated: a small damaged or hostile file cannot blow up. Writing goes to a temporary
file in the same folder, flushed and fsynced, then renamed over the target: a crash leaves
either the old checkpoint or the new one, never half of one; only a regular file is renamed
over (:func:`write_target`). Reading refuses, with one line
naming the file, a missing, truncated, foreign, other-kind or newer checkpoint.
What a checkpoint holds has its own schema version (``"schema"``: the learners' states, the
runs' checkpoint.json and report.json), apart from this format's; :func:`schema_of` checks it the
same way for all.
"""
from __future__ import annotations

import base64
import hashlib
import json
import lzma
import os
import stat
import sys
import tempfile
import zlib
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from enum import Enum
from pathlib import Path

import numpy as np

from .errors import InputError, NewerSchema

FORMAT = "ftorch"
VERSION = 4
READS = (2, 3, 4)  # versions this ftorch reads: 2 compresses texts with zlib, 3 has no relative arrays
XZ_MAGIC = b"\xfd7zXZ\x00"
MAX_BYTES = 1 << 30  # no array or text in a checkpoint inflates to more


ROWS = 1024  # rows per compressed block of an array
SLICE = 1 << 20  # values per slice of the float32 exactness check
MEMO_SIZE = 256  # blocks a memo remembers of each sort (arrays' and feature tables')


class Memo:
    """Compressed blocks a writer made before, reused where the same data come again: the value
    cache's table and its feature table grow between the checkpoints of a run, and all but their
    last blocks are unchanged. Owned by what grows (:class:`~ftorch.recognition.value_cache.ValueCache`),
    it lives as long as that; each sort holds the most recent :data:`MEMO_SIZE` blocks.

    Array blocks are keyed by the BLAKE2b digest of their raw bytes (and the compressor), not the
    bytes, so remembering the block of a large array holds no copy of it; feature blocks by the ids
    of their features, each entry keeping its features alive, so that their ids cannot be reused
    while it is remembered."""

    def __init__(self) -> None:
        self.arrays: OrderedDict = OrderedDict()  # (digest, xz) -> block
        self.features: OrderedDict = OrderedDict()  # ids of a chunk's features -> (the features, the block)

    @staticmethod
    def _keep(memo: OrderedDict, key, value) -> None:
        memo[key] = value
        if len(memo) > MEMO_SIZE:
            memo.popitem(last=False)

    def feature_block(self, chunk: tuple) -> dict | None:
        """The packed block of the features ``chunk`` (these very objects), where remembered."""
        known = self.features.get(tuple(map(id, chunk)))
        return None if known is None else known[1]

    def remember_features(self, chunk: tuple, block: dict) -> None:
        """Remember ``block`` as the packed form of ``chunk``."""
        self._keep(self.features, tuple(map(id, chunk)), (chunk, block))

    def compress(self, raw: bytes, xz: bool = False) -> str:
        """:func:`_compress`, once per distinct block."""
        key = (hashlib.blake2b(raw, digest_size=32).digest(), xz)
        block = self.arrays.get(key)
        if block is None:
            block = _compress(raw, xz)
            self._keep(self.arrays, key, block)
        return block


def _compress(raw: bytes, xz: bool = False) -> str:
    """Compressed bytes (zlib, or xz at preset 1) in base64."""
    packed = lzma.compress(raw, preset=1) if xz else zlib.compress(raw, 6)
    return base64.b64encode(packed).decode("ascii")


def _inflate(text, size: int) -> bytes:
    """Decompress at most ``size`` bytes; ValueError where the data hold more or less."""
    if size > MAX_BYTES:
        raise ValueError(f"declares {size} bytes, more than the {MAX_BYTES} a checkpoint may hold")
    packed = base64.b64decode(text, validate=True)
    if packed.startswith(XZ_MAGIC):
        xz = lzma.LZMADecompressor(format=lzma.FORMAT_XZ)
        raw = xz.decompress(packed, size + 1)
        rest, eof = xz.unused_data, xz.eof
    else:
        deflate = zlib.decompressobj()
        raw = deflate.decompress(packed, size + 1)
        rest, eof = deflate.unconsumed_tail, deflate.eof
    if len(raw) != size or rest or not eof:
        raise ValueError(f"holds other than the {size} bytes it declares")
    return raw


def encode_array(array: np.ndarray, reference: np.ndarray | None = None, memo: Memo | None = None) -> dict:
    """A float array as JSON-ready data: shape, dtype (f4 where exact, else f8) and compressed bytes;
    with a ``reference`` of the same shape, the bits of the array XOR those of the reference in that
    dtype ("relative"): :func:`decode_array` restores it given the same reference. ``memo``: blocks
    compressed before, reused (:class:`Memo`)."""
    if np.asarray(array).dtype == np.float32:
        data = np.require(array, dtype="<f4", requirements="C")
    else:
        data = np.require(array, dtype="<f8", requirements="C")  # keeps 0-d arrays 0-d
        narrow = data.astype("<f4")
        wide, small = data.reshape(-1).view("<i8"), narrow.reshape(-1)
        # bit for bit, NaN included; in slices, so that a large array is not widened again whole
        if all(np.array_equal(small[s : s + SLICE].astype("<f8").view("<i8"), wide[s : s + SLICE])
               for s in range(0, wide.size, SLICE)):
            data = narrow
    state: dict[str, object] = {"shape": list(data.shape), "dtype": data.dtype.str}
    if reference is not None:
        data = data.view(_BITS[data.dtype.str]) ^ _reference(reference, data.shape, data.dtype)
        state["relative"] = True
    rows = data.reshape(len(data), int(np.prod(data.shape[1:]))) if data.ndim else data.reshape(1, 1)
    compress = _compress if memo is None else memo.compress
    state["blocks"] = [compress(rows[s : s + ROWS].tobytes()) for s in range(0, max(len(rows), 1), ROWS)]
    return state


_BITS: dict[str, np.dtype] = {"<f4": np.dtype("<u4"), "<f8": np.dtype("<u8")}  # the unsigned integers holding each float's bits


def _reference(reference: np.ndarray, shape: tuple, dtype: np.dtype) -> np.ndarray:
    """The bits of ``reference`` in ``dtype`` (rounded the same way when written and read; a view
    where it is in that dtype already, in any memory order: a checkpoint's instance values are large)."""
    reference = np.asarray(reference)
    if reference.shape != tuple(shape):
        raise ValueError(f"a reference of shape {reference.shape} for an array of shape {tuple(shape)}")
    return reference.astype(dtype, copy=False).view(_BITS[dtype.str])


def decode_array(data: dict, reference: np.ndarray | None = None, shape: tuple | None = None) -> np.ndarray:
    """Inverse of :func:`encode_array` (as float64; a relative array needs the ``reference`` it was
    written with); ValueError where the data are damaged. ``shape``: the shape the caller knows the
    array has (from the rest of the file): any other declared shape is refused before anything is
    inflated, so a file cannot make the reader allocate more than its own structure implies. Blocks
    are inflated one at a time into the result."""
    try:
        declared = tuple(int(v) for v in data["shape"])
        dtype = np.dtype({"<f4": "<f4", "<f8": "<f8"}[data["dtype"]])
        if any(v < 0 for v in declared):
            raise ValueError(f"negative shape {declared}")
        if shape is not None and declared != tuple(shape):
            raise ValueError(f"declares shape {declared} where the file's structure needs {tuple(shape)}")
        n_rows = declared[0] if declared else 1
        row_values = int(np.prod(declared[1:])) if declared else 1
        blocks = data["blocks"]
        if not isinstance(blocks, list) or len(blocks) != max(1, -(-n_rows // ROWS)):
            raise ValueError(f"{len(blocks) if isinstance(blocks, list) else 'no'} blocks for {n_rows} rows")
        if n_rows * row_values * dtype.itemsize > MAX_BYTES:
            raise ValueError(f"declares {n_rows * row_values * dtype.itemsize} bytes, more than the {MAX_BYTES} a checkpoint may hold")
        relative, bits = data.get("relative", False), None
        if relative is not False:
            if relative is not True or reference is None:
                raise ValueError("written relative to values that are not given")
            bits = _reference(reference, declared, dtype).reshape(n_rows, row_values)
        out = np.empty((n_rows, row_values), np.float64)
        for k, block in enumerate(blocks):
            rows = slice(k * ROWS, min((k + 1) * ROWS, n_rows))
            raw = _inflate(block, (rows.stop - rows.start) * row_values * dtype.itemsize)
            part = np.frombuffer(raw, dtype=dtype).reshape(rows.stop - rows.start, row_values)
            out[rows] = part if bits is None else (part.view(_BITS[dtype.str]) ^ bits[rows]).view(dtype)
    except (KeyError, TypeError, ValueError, OverflowError, zlib.error, lzma.LZMAError) as err:
        raise ValueError(f"damaged array ({err})") from None
    return out.reshape(declared)


def stored_position(index, size: int) -> int:
    """A stored reference into a table of ``size`` entries; ValueError unless a valid position (an
    int, not a bool, and no negative index that Python would wrap around)."""
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < size:
        raise ValueError(f"reference {index!r} into a table of {size} entries")
    return index


def encode_text(text: str) -> dict:
    """A long text as JSON-ready data: its length in bytes and its xz-compressed UTF-8."""
    raw = text.encode("utf-8")
    return {"bytes": len(raw), "data": _compress(raw, xz=True)}


def decode_text(data: dict, limit: int = MAX_BYTES) -> str:
    """Inverse of :func:`encode_text`; ValueError where the data are damaged or declare more than
    ``limit`` bytes (refused before anything is inflated)."""
    try:
        size = int(data["bytes"])
        if size > limit:
            raise ValueError(f"declares {size} bytes, more than the {limit} such a text may hold")
        return _inflate(data["data"], size).decode("utf-8")
    except (KeyError, TypeError, ValueError, UnicodeDecodeError, zlib.error, lzma.LZMAError) as err:
        raise ValueError(f"damaged text ({err})") from None


class Target(Enum):
    """How a write reaches a path (:func:`write_target`)."""

    REPLACE = "replace"  # a regular file, or nothing yet: written beside it, then renamed over it
    IN_PLACE = "in place"  # a pipe, the null device, or this process's own output: written to, appended


_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISFIFO, "a pipe"))


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def write_target(path) -> Target:
    """How ftorch may write ``path``; InputError, naming it, where it must not.

    Only a regular file (or a missing path, or a link, which is replaced and its target left alone)
    is replaced atomically: a rename over a device node, a folder or a socket would destroy it (as
    root, ``--json /dev/null`` would replace the system's null device). Written to in place, where
    that is what a user means: a pipe (``>(jq .)``), the null device, and the process's own
    standard streams (``/dev/stdout``, whatever they are). Anything else is refused."""
    path = Path(path)
    try:
        st = os.stat(path)
    except OSError:  # nothing there or a link to nothing (the write makes the file), or a file where a
        return Target.REPLACE  # folder should be (the write itself says why, naming path)
    if _standard_stream(st) is not None:
        return Target.IN_PLACE
    if stat.S_ISREG(st.st_mode):
        return Target.REPLACE
    if stat.S_ISFIFO(st.st_mode) or (stat.S_ISCHR(st.st_mode) and st.st_rdev == _null_device()):
        return Target.IN_PLACE
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{path}: a folder is there, not a file")
    raise InputError(f"{path}: {_kind(st.st_mode)} is there, not a regular file; ftorch writes regular files "
                     "(and into a pipe, /dev/null or its own standard output), and does not replace anything else")


def _standard_stream(st: os.stat_result) -> int | None:
    """The descriptor of this process's stdout or stderr where it is the file ``st`` describes (a
    terminal, a pipe, a redirected file), else None."""
    for fd in (1, 2):
        try:
            other = os.fstat(fd)
        except OSError:
            continue
        if (other.st_dev, other.st_ino) == (st.st_dev, st.st_ino):
            return fd
    return None


def _write_in_place(path: Path, data: bytes) -> None:
    """Append ``data`` to ``path``; where it is this process's stdout or stderr, through that very
    descriptor after what Python holds for it, so that the output keeps its order."""
    fd = _standard_stream(os.stat(path))
    if fd is None:
        with open(path, "ab") as out:
            out.write(data)
        return
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _null_device() -> int | None:
    try:
        return os.stat(os.devnull).st_rdev
    except OSError:
        return None


def write_atomic(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder: readers see the old
    file or the whole new one, and no temporary file is left behind on failure. Where ``path`` is
    not a regular file, :func:`write_target` decides: written in place, or refused. An OSError
    names ``path``, never the temporary file."""
    path = Path(path)
    try:
        if write_target(path) is Target.IN_PLACE:
            _write_in_place(path, data)
            return path
        path.parent.mkdir(parents=True, exist_ok=True)
        # a short name of its own: the target's name plus a prefix could pass the file system's limit where the target's does not
        handle, temporary = tempfile.mkstemp(prefix=".ftorch-", suffix=".tmp", dir=path.parent)
    except OSError as err:
        raise OSError(err.errno, err.strerror or str(err), str(path)) from None
    try:
        os.chmod(temporary, 0o666 & ~_umask())  # mkstemp makes 0600 files; a written file follows the umask
        with os.fdopen(handle, "wb") as out:
            out.write(data)
            out.flush()
            os.fsync(out.fileno())
        os.replace(temporary, path)
    except BaseException as err:
        Path(temporary).unlink(missing_ok=True)
        if isinstance(err, OSError):
            raise OSError(err.errno, err.strerror or str(err), str(path)) from None
        raise
    return path


def _umask() -> int:
    mask = os.umask(0o022)  # reading the umask means setting it: put it straight back
    os.umask(mask)
    return mask


def write_text(path, text: str) -> Path:
    """:func:`write_atomic` for text (UTF-8)."""
    return write_atomic(path, text.encode("utf-8"))


def save_checkpoint(path, kind: str, payload: dict) -> Path:
    """Write ``payload`` as a checkpoint of ``kind`` to ``path`` atomically."""
    text = json.dumps({"format": FORMAT, "kind": kind, "version": VERSION, **payload}, separators=(",", ":"))
    return write_atomic(path, text.encode("utf-8"))


# what reading a damaged state (missing keys, wrong types, out-of-range numbers or positions) raises
DAMAGED = (KeyError, TypeError, ValueError, IndexError, RuntimeError, OverflowError, AttributeError)


def load_checkpoint(path, kind: str | tuple[str, ...]) -> dict:
    """Read a checkpoint of ``kind`` (or of one of several kinds); InputError naming ``path`` for anything else."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except ValueError as err:  # not UTF-8, not JSON, or an integer of more digits than Python converts
        raise InputError(f"{path}: not a readable checkpoint (truncated or not JSON: {err})") from None
    except RecursionError:
        raise InputError(f"{path}: not a readable checkpoint (JSON nested too deeply)") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f"{path}: not an ftorch checkpoint")
    kinds = (kind,) if isinstance(kind, str) else kind
    if data.get("kind") not in kinds:
        raise InputError(f"{path}: an ftorch checkpoint of kind {data.get('kind')!r}, expected "
                         f"{' or '.join(map(repr, kinds))}")
    if data.get("version") not in READS:
        raise InputError(f"{path}: checkpoint version {data.get('version')!r}, this ftorch reads versions "
                         f"{READS[0]} to {READS[-1]}")
    return data


@contextmanager
def reading(path, what: str) -> Iterator[None]:
    """Reading the checkpoint at ``path``: a file of a newer schema is refused as :class:`NewerSchema`
    naming it, and anything else found damaged (:data:`DAMAGED`, InputError included) is one InputError
    naming ``path`` and ``what`` the file is."""
    try:
        yield
    except NewerSchema as err:  # a refusal rather than damage
        raise NewerSchema(f"{path}: {err}") from None
    except DAMAGED as err:
        raise InputError(f"{path}: damaged {what} ({type(err).__name__}: {err})") from None


def schema_of(version, what: str, newest: int) -> int:
    """A file's schema ``version`` (None: written before schemas were numbered, 0), checked: ValueError for
    no version number, NewerSchema (one line) for one newer than ``newest``, which this ftorch reads."""
    version = 0 if version is None else version
    if isinstance(version, bool) or not isinstance(version, int) or version < 0:
        raise ValueError(f"schema {version!r} is not a version number")
    if version > newest:
        raise NewerSchema(f"{what} of schema {version}, newer than this ftorch reads ({newest}): update ftorch to read it")
    return version
