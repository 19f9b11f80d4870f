"""Data sets for the recognition protocols of 4.5: COIL folders, class folders, and the built-in Plym task.

Each loader returns a :class:`Task`: images (paths or tensors), one class label per image,
display names, and each image's position in its class's ordered sequence of views. Folds
assign neighbouring views alternately (4.5): fold 1 trains on positions 0, 2, 4, ... and tests
on 1, 3, 5, ...; fold 2 swaps the roles.

``classes``, ``views`` and ``first_view`` mean the same for every task: the first N classes
(COIL objects 1..N, class folders in name order, Plym solids in their order) and, of each, the
views from ``first_view`` on (in view order, file-name order, rendering order); ``views=None``
takes all from there. A task that cannot give what is asked refuses with one line; ``size``
reduces files by area averaging (COIL and class folders) or sets Plym's rendering size.
"""
from __future__ import annotations

import hashlib
import math
import os
import re
import sys
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import cv2
import torch

from ftorch.errors import InputError
from ftorch.images import load_image

from .plym import plym_images, plym_layout

IMAGE_SUFFIXES = {".png", ".pgm", ".ppm", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp"}
COIL_NAME = re.compile(r"^obj(\d+)__(\d+)\.png$", re.IGNORECASE)


@dataclass
class Task:
    name: str
    images: list
    labels: list[str]
    names: list[str]
    positions: list[int]

    def classes(self) -> list[str]:
        return list(dict.fromkeys(self.labels))

    def view(self, i: int) -> torch.Tensor:
        """Image i as a grey (H, W) tensor in [0, 1], loaded where it is a file."""
        image = self.images[i]
        return load_image(image) if isinstance(image, (str, Path)) else torch.as_tensor(image)

    def fold(self, fold: int) -> tuple[list[int], list[int]]:
        """(training, test) image indices of fold 1 or 2."""
        if fold not in (1, 2):
            raise InputError(f"fold must be 1 or 2, got {fold}")
        train = [i for i, p in enumerate(self.positions) if p % 2 == fold - 1]
        return train, [i for i in range(len(self.images)) if i not in set(train)]

    def views_per_class(self) -> dict[str, int]:
        return {c: self.labels.count(c) for c in self.classes()}

    def check_folds(self, folds: int) -> None:
        """Refuse a class that a fold would not train on: with two folds every class needs two views
        (fold 2 trains on the second)."""
        if folds == 2:
            few = [c for c, n in self.views_per_class().items() if n < 2]
            if few:
                raise InputError(f"class {few[0]!r} has only one view{f' (and {len(few) - 1} more classes)' if len(few) > 1 else ''}: "
                                 "two folds train on alternate views, so fold 2 would never see it; give every class "
                                 "two views or more, or use --folds 1")

    @cached_property
    def fingerprint(self) -> str:
        """A digest of the task's views as loaded (names, labels, pixels): a run records it, so that
        images changed under the same names (mirrored, re-encoded, another data set) are told apart."""
        digest = hashlib.blake2b(digest_size=16)
        for i, (name, label) in enumerate(zip(self.names, self.labels)):
            view = self.view(i).to(torch.float32).contiguous()
            digest.update(repr((name, label, tuple(view.shape))).encode("utf-8"))
            digest.update(view.numpy().tobytes())
        return digest.hexdigest()

    def shapes(self) -> list[tuple[int, int]]:
        """(H, W) of every image, each file loaded once to check it (an unreadable one is named)."""
        return [tuple(self.view(i).shape) for i in range(len(self.images))]

    def select(self, classes: int | None, views: int | None, first_view: int) -> "Task":
        """The first ``classes`` classes and, of each, ``views`` views from position ``first_view``
        (None: all from there), positions renumbered from 0 (module doc)."""
        names = self.classes()
        if classes is not None and not 2 <= classes <= len(names):
            raise InputError(f"--classes {classes}: the {self.name} task has {len(names)} classes; expected 2 to {len(names)}")
        kept = set(names[:classes])
        short = [(c, n) for c, n in self.views_per_class().items() if c in kept
                 and n < first_view + (1 if views is None else views)]
        if short:
            c, n = short[0]
            wanted = f"views {first_view} to {first_view + views - 1}" if views is not None else f"view {first_view} and on"
            raise InputError(f"class {c!r} of the {self.name} task has {n} views; --first-view {first_view} --views "
                             f"{'all' if views is None else views} needs {wanted}")
        end = math.inf if views is None else first_view + views
        keep = [i for i, (c, p) in enumerate(zip(self.labels, self.positions)) if c in kept and first_view <= p < end]
        return Task(self.name, [self.images[i] for i in keep], [self.labels[i] for i in keep],
                    [self.names[i] for i in keep], [self.positions[i] - first_view for i in keep])


def _folder(root) -> Path:
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"--data {root}: no such folder")
    return root


def _files(root: Path) -> list[Path]:
    """Every file below ``root`` in name order, following symbolic links to folders (each real
    folder once, so a link cycle ends)."""
    seen, out = set(), []
    for folder, subfolders, files in os.walk(root, followlinks=True):
        real = os.path.realpath(folder)
        if real in seen:
            subfolders.clear()
            continue
        seen.add(real)
        subfolders.sort()
        out += [Path(folder) / f for f in sorted(files)]
    return out


def _check_size(size: int | None) -> None:
    if size is not None and size < 9:
        raise InputError(f"--size {size}: expected at least 9 pixels (the smallest image the scale space takes)")


def reduced(path: Path, size: int) -> torch.Tensor:
    """The image at ``path`` area-averaged (``cv2.INTER_AREA``) so that its shorter side is ``size``
    pixels: for an integer factor, the mean of each block, as ``coil-20-32`` was made (before rounding)."""
    image = load_image(path)
    height, width = image.shape
    side = min(height, width)
    if size > side:
        raise InputError(f"--size {size}: {path} is only {height}x{width}; --size can only reduce images")
    if size == side:
        return image
    shape = (max(1, round(width * size / side)), max(1, round(height * size / side)))
    return torch.from_numpy(cv2.resize(image.numpy(), shape, interpolation=cv2.INTER_AREA))


def coil_task(root, classes: int = 6, views: int = 20, first_view: int = 0, size: int | None = None) -> Task:
    """COIL objects 1..``classes``, ``views`` consecutive views from ``first_view`` (5 degrees apart).

    Files are found anywhere below ``root`` (symbolic links followed) by their original names
    ``obj{k}__{view}.png`` in any letter case; a name found twice is refused, naming both files
    (any image size), so both a flat folder and the original COIL layout work. With ``size``
    the images are loaded and reduced by area averaging to that shorter side (:func:`reduced`).
    """
    _check_size(size)
    root = _folder(root)
    if classes < 2 or views < 2:
        raise InputError(f"the COIL task needs at least 2 classes and 2 views, got {classes} and {views}")
    found = {}
    for path in _files(root):
        match = COIL_NAME.match(path.name)
        if match:
            key = (int(match[1]), int(match[2]))
            if key in found:
                raise InputError(f"--data {root}: COIL image obj{key[0]}__{key[1]} is there twice: "
                                 f"{found[key]} and {path}; keep one")
            found[key] = path
    images, labels, names, positions = [], [], [], []
    for k in range(1, classes + 1):
        for j in range(views):
            view = first_view + j
            if (k, view) not in found:
                raise InputError(f"--data {root}: COIL image obj{k}__{view}.png not found "
                                 f"({len(found)} COIL images there; need objects 1-{classes}, views {first_view}-{first_view + views - 1})")
            images.append(found[(k, view)] if size is None else reduced(found[(k, view)], size))
            labels.append(f"obj{k}")
            names.append(f"obj{k}__{view}")
            positions.append(j)
    return Task("coil", images, labels, names, positions)


def folder_task(root) -> Task:
    """``root/<class>/<image>``: every class folder holds that class's views, in file-name order."""
    root = _folder(root)
    images, labels, names, positions = [], [], [], []
    # .git etc. are no class; is_dir follows links
    skipped = []
    for folder in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        found = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
        files = [p for p in found if _is_image(p)]
        skipped += [p for p in found if p not in files]
        for j, path in enumerate(files):
            images.append(path)
            labels.append(folder.name)
            names.append(f"{folder.name}/{path.name}")
            positions.append(j)
    if len(set(labels)) < 2:
        raise InputError(f"--data {root}: expected at least two class folders with images (root/<class>/<image>)")
    if skipped:
        print(f"note: {len(skipped)} file(s) in the class folders of {root} are not images OpenCV reads and are "
              f"left out (e.g. {skipped[0].relative_to(root)})", file=sys.stderr)
    return Task("folder", images, labels, names, positions)


def _is_image(path: Path) -> bool:
    """A file of a class folder is an image where its name says so (one that then does not load is
    refused, naming it) or where OpenCV recognizes its content (.webp, .gif, ... under any name)."""
    return path.suffix.lower() in IMAGE_SUFFIXES or cv2.haveImageReader(str(path))


def image_files(root) -> tuple[list[Path], list[Path]]:
    """The image files below ``root`` in name order, as class folders take them (:func:`_is_image`;
    symbolic links to folders followed, hidden files and folders left out), and the other files."""
    root = Path(root)
    visible = [p for p in _files(root) if not any(part.startswith(".") for part in p.relative_to(root).parts)]
    readable = [_is_image(p) for p in visible]
    return [p for p, ok in zip(visible, readable) if ok], [p for p, ok in zip(visible, readable) if not ok]


def plym_task(size: int = 64, seed: int = 0, classes: int | None = None, views: int | None = None,
              first_view: int = 0) -> Task:
    """The built-in Plym-like task: the first ``classes`` (default all 8) rendered solids x ``views``
    of their 15 views from ``first_view`` (default all; no files needed). A request beyond the task
    (more than 8 classes, views past the 15th, ``size`` below 9) is refused before any view is rendered
    (which takes up to minutes), with :meth:`Task.select`'s line."""
    _check_size(size)
    labels, names, positions = plym_layout()
    Task("plym", [None] * len(labels), labels, names, positions).select(classes, views, first_view)
    return Task("plym", *plym_images(size, seed)).select(classes, views, first_view)


def load_task(name: str, data=None, classes: int | None = None, views: int | None = None, size: int | None = None,
              seed: int = 0, first_view: int = 0) -> Task:
    """The task named on the command line (module doc): ``classes`` defaults to 6 for COIL and to
    all for the others, ``views`` to 20 for COIL and to all for the others; ``size`` is Plym's
    image side (default 64) or the reduced side of files (default: as stored)."""
    if name == "plym":
        if data is not None:
            raise InputError("--data: the plym task renders its own images; it takes no image folder")
        return plym_task(64 if size is None else size, seed, classes, views, first_view)
    if data is None:
        raise InputError(f"--task {name} needs --data DIR")
    if name == "coil":
        return coil_task(data, 6 if classes is None else classes, 20 if views is None else views, first_view, size)
    if name == "folder":
        _check_size(size)
        task = folder_task(data).select(classes, views, first_view)
        return task if size is None else replace(task, images=[reduced(path, size) for path in task.images])
    raise InputError(f"--task {name!r}: expected coil, folder or plym")
