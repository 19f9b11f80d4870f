"""``salient``: salient edgels and texels drawn as in figure 3.9."""
from __future__ import annotations

import json
from pathlib import Path

import torch

from ftorch import FeatureSpace, load_image
from ftorch.checkpoint import write_text
from ftorch.errors import InputError
from ftorch.space.draw import draw_salient, save_rgb, titled
from training.cli.arguments import number
from training.cli.devices import resolve_device
from training.cli.jobs import device_options
from training.cli.outputs import writable_folder
from training.data.builtin import builtin_scene


def salient_command(args) -> int:
    device = resolve_device(args.device)
    if not 0 < args.truncate <= 10:
        raise InputError(f"--truncate {args.truncate}: expected a kernel radius in (0, 10] sigmas")
    out = writable_folder(args.out)
    if args.images:
        names = [Path(p) for p in args.images]
        images = [load_image(p) for p in names]
    else:
        names = [Path("builtin-scene.png")]
        images = [torch.from_numpy(builtin_scene())]
    space = FeatureSpace(truncate=args.truncate).to(device)
    with torch.no_grad():
        records = space.records(images, progress=len(images) > 4, names=[str(p) for p in names])
    counts = records.counts()
    summary = []
    stems = [name.stem for name in names]
    clash = len(set(stems)) < len(stems)  # a/x.png and b/x.png: number every figure, so none is lost
    for n, (name, image) in enumerate(zip(names, images)):
        stem = f"{n + 1}-{stems[n]}" if clash else stems[n]
        target = out / f"{stem}_salient.png"
        row = {"image": str(name), "edgels": counts["edgels"][n], "blobs": counts["blobs"][n],
               "corners": counts["corners"][n], "figure": str(target)}
        row["texels"] = row["blobs"] + row["corners"]
        save_rgb(target, titled(draw_salient(records, n, image),
                                f"{name.name}: {row['edgels']} edgels (left: segments of 2 sigma); {row['blobs']} blobs "
                                f"(circles) and {row['corners']} corners (squares) of radius sigma"))
        summary.append(row)
        print(f"{name}: {row['edgels']} edgels, {row['texels']} texels "
              f"({row['blobs']} blobs, {row['corners']} corners) -> {target}")
    write_text(out / "salient.json", json.dumps(summary, indent=2) + "\n")
    return 0


def add_parser(commands) -> None:
    """The ``salient`` sub-command and its options."""
    p = commands.add_parser("salient", help="draw salient edgels and texels (figure 3.9)")
    p.add_argument("images", nargs="*", help="image files (default: the built-in scene)")
    p.add_argument("--out", default="runs/salient", help="output folder (default: runs/salient)")
    device_options(p, quiet=False)
    p.add_argument("--truncate", type=number, default=3.0, help="kernel radius in sigmas (default 3)")
    p.set_defaults(run=salient_command)
