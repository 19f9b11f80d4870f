"""``evaluate``: a saved learner recognizes another image set."""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path

from ftorch import FeatureSpace
from ftorch.checkpoint import write_text
from ftorch.errors import InputError
from ftorch.recognition.inference import Outcome
from ftorch.recognition.learner import DistinctiveFeatureLearner
from training.cli.arguments import at_least
from training.cli.devices import resolve_device
from training.cli.outputs import Command, RunFolder, apart
from training.commands.recognize import task_options
from training.data.datasets import Task, load_task, reduced
from training.recognition.protocol import confusion, feature_block, image_set, load_learner, test_block
from training.recognition.records import ConfusionRow, FeatureBlock, TestBlock
from training.recognition.report import (
    COLUMNS,
    ambiguity_table,
    confusion_table,
    write_json,
)
from training.records import Record

SIDE_TOLERANCE = math.sqrt(2)  # one step of the half-octave scale space (DESIGN.md)


def at_learned_size(task: Task, learner: DistinctiveFeatureLearner, args) -> Task:
    """The task's images at the size the learner learned from (its ``sides``): features are measured
    at absolute scales in pixels, so a learner recognizes images of another size as other objects.
    Without ``--size``, images larger than a learner's single learned side are area-averaged down to
    it (``args.size`` records it); an image whose shorter side then lies more than one scale step
    (a factor of sqrt 2) outside the learned sides is refused. Learners saved before sides were
    recorded are taken as they are."""
    if learner.sides is None:
        print(f"note: {args.learner} does not record the image size it learned from; the images are "
              "recognized as stored (--size reduces them)", file=sys.stderr)
        return task
    low, high = learner.sides
    shapes = task.shapes()
    if args.size is None and low == high and any(min(shape) > low for shape in shapes):
        task = replace(task, images=[reduced(image, low) if min(shape) > low else image
                                     for image, shape in zip(task.images, shapes)])
        args.size = low
        print(f"note: images area-averaged to the learned shorter side of {low} pixels (--size {low})", file=sys.stderr)
        shapes = task.shapes()
    off = [i for i, shape in enumerate(shapes) if not low / SIDE_TOLERANCE <= min(shape) <= high * SIDE_TOLERANCE]
    if off:
        learned = f"{low}" if low == high else f"{low} to {high}"
        raise InputError(f"--learner {args.learner} learned from images whose shorter side is {learned} pixels; "
                         f"{len(off)} of these are not within a scale step of that (e.g. {task.names[off[0]]}, "
                         f"{shapes[off[0]][0]}x{shapes[off[0]][1]}): give images of the learned size "
                         f"({'--size ' + str(low) + ' reduces larger ones' if args.size is None else 'another --size'})")
    return task


def evaluate_command(args) -> int:
    device = resolve_device(args.device)
    apart({"--out": args.out}, {"--data": args.data})
    out = Path(args.out)
    with RunFolder(out, out, False, True, Command.EVALUATE, can_resume=False) as folder:
        return _evaluate(args, device, folder)


def _evaluate(args, device, folder: RunFolder) -> int:
    """The body of :func:`evaluate_command` once its output folder is held."""
    out = folder.out
    learner = load_learner(args.learner)
    networks = {str(c): net for c, net in learner.networks.items()}  # classes by name, as folders and COIL name them
    if len(networks) < len(learner.networks):
        raise InputError(f"--learner {args.learner}: two classes have the same name as text "
                         f"({', '.join(sorted(map(repr, learner.networks), key=str))}), so images cannot name them apart")
    task = at_learned_size(load_task(args.task, args.data, args.classes, args.views, args.size, first_view=args.first_view),
                           learner, args)
    unknown = sorted(set(task.labels) - set(networks))
    if unknown:
        print(f"note: classes {', '.join(unknown)} of {args.data} are unknown to the learner", file=sys.stderr)
    classes = sorted(set(networks) | set(task.labels), key=str)
    env = image_set(task, list(range(len(task.images))), FeatureSpace().to(device), not args.quiet)
    recognitions = [replace(r, recognized={str(c) for c in r.recognized}, top=None if r.top is None else str(r.top))
                    for r in learner.recognize_many(env, range(len(env)))]
    result = Evaluation(str(args.learner), str(args.data), classes, args.size, test_block(recognitions, env.labels, classes),
                        feature_block(learner, recognitions), confusion(recognitions, env.labels, classes, networks),
                        [Answer(name, sorted(map(str, t)), sorted(map(str, r.recognized)), r.top)
                         for name, t, r in zip(env.names, env.labels, recognitions)])
    folder.ledger.files(out / "evaluate.json", out / "evaluate.md")
    write_json(out / "evaluate.json", result.to_json())
    test = result.test
    lines = [f"# Evaluation of {args.learner} on {args.data}", "",
             f"accuracy {test.accuracy:.2f}; top-1 accuracy {test.top1:.2f} (each image's one "
             "label, its \"top\" in evaluate.json); " + ", ".join(f"{k} {getattr(test, k):.2f}" for k in Outcome),
             "", COLUMNS, "", "## Confusion (table 4.3 form)", "", *confusion_table(result.confusion, classes), "",
             "## Ambiguous recognitions (table 4.4 form)", "", *ambiguity_table(result.confusion, classes), ""]
    write_text(out / "evaluate.md", "\n".join(lines))
    print(f"{len(env)} images: accuracy {test.accuracy:.2f}, top-1 {test.top1:.2f}, correct {test.correct:.2f}; "
          f"report: {out / 'evaluate.md'}")
    return 0


@dataclass
class Answer(Record):
    """One image's answer: its true classes, those recognized (def. 4.5) and its top label."""

    image: str
    true: list[str]
    recognized: list[str]
    top: str | None


@dataclass
class Evaluation(Record):
    """evaluate.json: the learner and images, the test block (def. 4.5, 4.6), feature counts, confusion
    rows (tables 4.3, 4.4) and every image's answer."""

    checkpoint: str
    data: str
    classes: list
    size: int | None
    test: TestBlock
    features: FeatureBlock
    confusion: dict[str, ConfusionRow]
    images: list[Answer]


def add_parser(commands) -> None:
    """The ``evaluate`` sub-command and its options."""
    p = commands.add_parser("evaluate", help="recognize another image set with a saved learner")
    p.add_argument("--learner", required=True, help="a learner.json written by recognize, or a fold's checkpoint.json")
    task_options(p, ("coil", "folder"), "coil")
    p.add_argument("--size", type=at_least(9, "an image side in pixels", 8192), help="area-average the images down to this "
                   "shorter side (default: the side the learner learned from, where it learned from one)")
    p.add_argument("--out", default="runs/evaluate", help="output folder (default runs/evaluate)")
    p.set_defaults(run=evaluate_command)
