"""``python -m training.data.coil ARCHIVE --out DIR [--size N]``: the COIL-20 folder from the official archive.

COIL-20 (Nene, Nayar and Murase, Technical Report CUCS-005-96, 1996) is distributed by Columbia
University's CAVE lab for research use: download ``coil-20-proc.zip`` (the processed images: 20
objects x 72 views, 128x128 grey, ``coil-20-proc/obj{k}__{view}.png``) from
https://www.cs.columbia.edu/CAVE/software/softlib/coil-20.php and give its path. The command
checks that the archive holds exactly those 1440 images, each a readable 128x128 grey PNG, and
writes them to ``DIR`` under their original names (``--size N``: area-averaged to N pixels, as
``--size`` does on load). Only members with COIL names are read and nothing is extracted by the
archive's own paths, so a foreign or hostile archive writes nothing. ``--data DIR`` then serves
every COIL command.
"""
from __future__ import annotations

import sys
import zipfile
from pathlib import Path

import cv2
import numpy as np

from ftorch.checkpoint import write_atomic
from ftorch.errors import InputError
from training.cli.arguments import Parser, at_least
from training.cli.outputs import writable_folder
from training.data.datasets import COIL_NAME

OBJECTS, VIEWS, SIDE = 20, 72, 128


def coil_images(archive) -> dict[tuple[int, int], np.ndarray]:
    """The 1440 grey 128x128 images of ``coil-20-proc.zip`` by (object, view); InputError unless complete."""
    archive = Path(archive)
    try:
        with zipfile.ZipFile(archive) as zipped:
            members = [m for m in zipped.infolist() if not m.is_dir() and COIL_NAME.match(Path(m.filename).name)]
            images = {}
            for member in members:
                match = COIL_NAME.match(Path(member.filename).name)
                key = (int(match[1]), int(match[2]))
                if key in images:
                    raise InputError(f"{archive}: obj{key[0]}__{key[1]}.png is in the archive twice")
                if member.file_size > 1 << 20:
                    raise InputError(f"{archive}: {member.filename} declares {member.file_size} bytes, not a COIL image")
                pixels = cv2.imdecode(np.frombuffer(zipped.read(member), np.uint8), cv2.IMREAD_UNCHANGED)
                if pixels is None or pixels.shape != (SIDE, SIDE) or pixels.dtype != np.uint8:
                    raise InputError(f"{archive}: {member.filename} is not a {SIDE}x{SIDE} 8-bit grey image")
                images[key] = pixels
    except (zipfile.BadZipFile, OSError) as err:
        raise InputError(f"{archive}: not a readable zip archive ({err})") from None
    expected = {(k, v) for k in range(1, OBJECTS + 1) for v in range(VIEWS)}
    missing, extra = sorted(expected - set(images)), sorted(set(images) - expected)
    if missing or extra:
        name = lambda key: f"obj{key[0]}__{key[1]}.png"  # noqa: E731
        raise InputError(f"{archive}: not coil-20-proc.zip: {len(images)} COIL images, {len(missing)} of the "
                         f"{len(expected)} missing{' (e.g. ' + name(missing[0]) + ')' if missing else ''}"
                         f"{', unexpected ' + name(extra[0]) if extra else ''}")
    return images


def prepare(archive, out, size: int = SIDE) -> list[Path]:
    """Write the archive's images to ``out`` (reduced to ``size`` pixels); returns the files written."""
    if not 9 <= size <= SIDE:
        raise InputError(f"--size {size}: expected 9 to {SIDE} pixels")
    images = coil_images(archive)
    out = writable_folder(out)
    written = []
    for (k, view), pixels in sorted(images.items()):
        if size != SIDE:
            pixels = cv2.resize(pixels.astype(np.float32) / 255, (size, size), interpolation=cv2.INTER_AREA)
            pixels = (pixels * 255).round().astype(np.uint8)
        written.append(write_atomic(out / f"obj{k}__{view}.png", cv2.imencode(".png", pixels)[1].tobytes()))
    return written


def main(argv: list[str] | None = None) -> int:
    p = Parser(prog="python -m training.data.coil", description=__doc__.split("\n\n")[0])
    p.add_argument("archive", help="coil-20-proc.zip as downloaded from Columbia's CAVE lab")
    p.add_argument("--out", required=True, help="folder for obj{k}__{view}.png (created; then --data OUT)")
    p.add_argument("--size", type=at_least(9, "an image side in pixels"), default=SIDE,
                   help=f"image side (default {SIDE}, as distributed; e.g. 32 for fast runs)")
    args = p.parse_args(argv)
    try:
        written = prepare(args.archive, args.out, args.size)
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{len(written)} COIL-20 images ({OBJECTS} objects x {VIEWS} views, {args.size}x{args.size}) in {args.out}; "
          f"use --task coil --data {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
