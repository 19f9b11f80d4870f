"""``salient``: salient edgels and texels drawn as in figure 3.9."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch

from ftorch import FeatureSpace, load_image
from ftorch.checkpoint import write_text
from ftorch.errors import InputError
from ftorch.space.draw import draw_salient, save_rgb, titled
from training.cli.arguments import number
from training.cli.devices import resolve_device
from training.cli.jobs import device_options
from training.cli.outputs import Command, RunFolder
from training.data.builtin import builtin_scene
from training.records import Record


def salient_command(args) -> int:
    device = resolve_device(args.device)
    if not 0 < args.truncate <= 10:
        raise InputError(f"--truncate {args.truncate}: expected a kernel radius in (0, 10] sigmas")
    out = Path(args.out)
    names = [Path(p) for p in args.images] or [Path("builtin-scene.png")]
    beside = sorted({str(name.parent) for name in map(Path, args.images) if name.parent.resolve() == out.resolve()})
    if beside:
        raise InputError(f"--out {out} holds the images ({beside[0]}): the figures would be read as images by the next "
                         "run on that folder; choose another --out")
    with RunFolder(out, out, False, True, Command.SALIENT, can_resume=False) as folder:
        images = [load_image(p) for p in names] if args.images else [torch.from_numpy(builtin_scene())]
        space = FeatureSpace(truncate=args.truncate).to(device)
        with torch.no_grad():
            records = space.records(images, progress=len(images) > 4, names=[str(p) for p in names])
        _draw(records, names, images, folder)
    return 0


def _draw(records, names: list[Path], images: list, folder: RunFolder) -> None:
    """One figure per image and ``salient.json``, each recorded in the folder's ledger before it is written."""
    out = folder.out
    counts = records.counts()
    summary = []
    stems = [name.stem for name in names]
    clash = len(set(stems)) < len(stems)  # a/x.png and b/x.png: number every figure, so none is lost
    for n, (name, image, edgels, blobs, corners) in enumerate(zip(names, images, *(counts[k] for k in SALIENT))):
        stem = f"{n + 1}-{stems[n]}" if clash else stems[n]
        target = out / f"{stem}_salient.png"
        row = SalientCounts(str(name), edgels, blobs, corners, str(target), blobs + corners)
        folder.ledger.files(target)
        save_rgb(target, titled(draw_salient(records, n, image),
                                f"{name.name}: {row.edgels} edgels (left: segments of 2 sigma); {row.blobs} blobs "
                                f"(circles) and {row.corners} corners (squares) of radius sigma"))
        summary.append(row.to_json())
        print(f"{name}: {row.edgels} edgels, {row.texels} texels ({row.blobs} blobs, {row.corners} corners) -> {target}")
    folder.ledger.files(out / "salient.json")
    write_text(out / "salient.json", json.dumps(summary, indent=2) + "\n")


SALIENT = ("edgels", "blobs", "corners")  # the kinds ImageRecords.counts counts


@dataclass
class SalientCounts(Record):
    """One image's row of salient.json: its salient edgels, blobs and corners (figure 3.9), its figure,
    and its texels (blobs and corners)."""

    image: str
    edgels: int
    blobs: int
    corners: int
    figure: str
    texels: int


def add_parser(commands) -> None:
    """The ``salient`` sub-command and its options."""
    p = commands.add_parser("salient", help="draw salient edgels and texels (figure 3.9)")
    p.add_argument("images", nargs="*", help="image files (default: the built-in scene)")
    p.add_argument("--out", default="runs/salient", help="output folder (default: runs/salient)")
    device_options(p, quiet=False)
    p.add_argument("--truncate", type=number, default=3.0, help="kernel radius in sigmas (default 3)")
    p.set_defaults(run=salient_command)
