"""``explain``: a saved learner's recognition of each image traced (alg. 4.4), as JSON and as a picture."""
from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

from ftorch.checkpoint import write_text
from ftorch.errors import InputError
from ftorch.recognition.explain import Explanation
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.space.draw import save_rgb
from training.cli.arguments import at_least
from training.cli.devices import resolve_device
from training.cli.jobs import device_options
from training.cli.outputs import Command, RunFolder, apart
from training.commands.evaluate import at_learned_size
from training.data.datasets import Task, image_files, reduced


def explain_command(args) -> int:
    """Every input is checked and every image explained before anything is written: a bad input
    (a missing or damaged learner, an unreadable image, one the learner cannot measure) writes nothing."""
    device = resolve_device(args.device)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: a file is there, not a folder")
    paths = _images(args.images, out)
    learner = DistinctiveFeatureLearner.load(args.learner, device)
    images = [reduced(p, args.size) for p in paths] if args.size is not None else list(paths)
    names = [str(p) for p in paths]
    task = at_learned_size(Task("explain", images, [""] * len(paths), names, [0] * len(paths)), learner, args)
    explanations = [replace(learner.explain(image), name=name) for image, name in zip(task.images, names)]
    with RunFolder(out, out, False, True, Command.EXPLAIN, can_resume=False) as folder:
        for stem, explanation in zip(_stems(paths), explanations):
            _write(folder, stem, explanation)
    return 0


def _images(given: list[str], out: Path) -> list[Path]:
    """The image files named, a folder standing for its images in name order (as class folders are
    read); InputError for a path that is not there, a folder without images, and an ``out`` that the
    next run on an input folder would read as images (inside it, or the folder of an image named)."""
    paths = []
    for item in map(Path, given):
        if item.is_dir():
            apart({"--out": out}, {"IMAGE": item})
            found, other = image_files(item)
            if not found:
                raise InputError(f"{item}: no image files in this folder")
            if other:
                print(f"note: {len(other)} file(s) in {item} are not images OpenCV reads and are left out "
                      f"(e.g. {other[0].relative_to(item)})", file=sys.stderr)
            paths += found
        elif item.exists():
            if out.resolve() == item.parent.resolve():
                raise InputError(f"--out {out} holds the image {item}: the pictures would be read as images by the next "
                                 "run on that folder; choose another --out")
            paths.append(item)
        else:
            raise InputError(f"{item}: no such image file or folder")
    return paths


def _stems(paths: list[Path]) -> list[str]:
    """Each image's output name: its stem, or, where two stems are the same (a/x.png, b/x.png; letter
    case aside, for file systems that ignore it), every image's position and stem (1-x, 2-x, ...)."""
    stems = [p.stem for p in paths]
    if len({s.casefold() for s in stems}) < len(stems):
        return [f"{n}-{s}" for n, s in enumerate(stems, 1)]
    return stems


def _write(folder: RunFolder, stem: str, explanation: Explanation) -> None:
    """``stem``.json and ``stem``.png, each recorded in the folder's ledger before it is written (atomically)."""
    data, picture = folder.out / f"{stem}.json", folder.out / f"{stem}.png"
    folder.ledger.files(data, picture)
    write_text(data, json.dumps(explanation.to_dict(), indent=2, allow_nan=False) + "\n")
    save_rgb(picture, explanation.picture())
    print(f"{explanation.name}: {explanation.answer} in {len(explanation.steps)} queries -> {picture}")


def add_parser(commands) -> None:
    """The ``explain`` sub-command and its options."""
    p = commands.add_parser("explain", help="trace a saved learner's recognition of each image (alg. 4.4): JSON and a picture")
    p.add_argument("images", nargs="+", metavar="IMAGE", help="image files, or folders standing for their images in name order")
    p.add_argument("--learner", required=True, help="a learner.json written by recognize (or DistinctiveFeatureLearner.save)")
    p.add_argument("--size", type=at_least(9, "an image side in pixels", 8192), help="area-average the images down to this "
                   "shorter side (default: the side the learner learned from, where it learned from one)")
    p.add_argument("--out", default="runs/explain", help="output folder (default runs/explain)")
    device_options(p, quiet=False)
    p.set_defaults(run=explain_command)
