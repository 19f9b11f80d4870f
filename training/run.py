"""Command line: ``python -m training.run [COMMAND ...]``.

Commands:
  salient IMAGE... --out DIR   salient edgels and texels drawn as in figure 3.9, one PNG per
                               image, counts printed and written to DIR/salient.json.
                               Without images it uses the built-in scene.
With no command at all it runs ``salient`` on the built-in scene into runs/salient.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from ftorch import FeatureSpace, load_image
from ftorch.draw import draw_salient, save_rgb
from ftorch.errors import InputError
from training.builtin import builtin_scene
from training.devices import resolve_device


def salient(args) -> int:
    device = resolve_device(args.device)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.images:
        names = [Path(p) for p in args.images]
        images = [load_image(p) for p in names]
    else:
        names = [Path("builtin-scene.png")]
        images = [torch.from_numpy(builtin_scene())]
    space = FeatureSpace(truncate=args.truncate).to(device)
    with torch.no_grad():
        records = space.records(images, progress=len(images) > 4)
    counts = records.counts()
    summary = []
    for n, (name, image) in enumerate(zip(names, images)):
        target = out / f"{name.stem}_salient.png"
        save_rgb(target, draw_salient(records, n, image))
        row = {"image": str(name), "edgels": counts["edgels"][n], "blobs": counts["blobs"][n],
               "corners": counts["corners"][n], "figure": str(target)}
        row["texels"] = row["blobs"] + row["corners"]
        summary.append(row)
        print(f"{name}: {row['edgels']} edgels, {row['texels']} texels "
              f"({row['blobs']} blobs, {row['corners']} corners) -> {target}")
    (out / "salient.json").write_text(json.dumps(summary, indent=2) + "\n")
    return 0


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="python -m training.run", description=__doc__.split("\n\n")[0])
    commands = top.add_subparsers(dest="command")
    p = commands.add_parser("salient", help="draw salient edgels and texels (figure 3.9)")
    p.add_argument("images", nargs="*", help="image files (default: the built-in scene)")
    p.add_argument("--out", default="runs/salient", help="output folder (default: runs/salient)")
    p.add_argument("--device", default="auto", help="cpu, cuda[:N] or auto (default)")
    p.add_argument("--truncate", type=float, default=3.0, help="kernel radius in sigmas (default 3)")
    p.set_defaults(run=salient)
    return top


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parser().parse_args(argv or ["salient"])
    try:
        return args.run(args)
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
