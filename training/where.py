"""Where a run's time goes: ``python -m training.where PROFILE``, a py-spy profile in raw form summed
by the learner's phases (docs/benchmark.md, "Where the time goes").

Record it with ``py-spy record --format raw --rate 100 --output PROFILE -- python -m training.run ...``
(``--subprocesses`` for a run with workers). Each sample is a stack; it counts towards the first
phase, in the order of :data:`PHASES`, that is on the stack, so the phases add up to the whole.
Two cross-cutting sums follow (:data:`ACROSS`): exact inference and feature values wherever they are called.
"""
from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path
from typing import NamedTuple

from training.cli.arguments import Parser


def _matches(frames: list[str], names: tuple[str, ...]) -> bool:
    """Whether a frame ("function (file:line)", methods as Class.method) is one of ``names`` (bare or Class.name)."""
    functions = {frame.split(" (", 1)[0] for frame in frames}
    return any(f == name or f.endswith("." + name) for f in functions for name in names)


class Part(NamedTuple):
    """A part of a run's time: the samples whose stack holds one of ``functions`` and, where ``inside``
    is given, also one of ``inside``."""

    name: str
    functions: tuple[str, ...]
    inside: tuple[str, ...] = ()

    def holds(self, frames: list[str]) -> bool:
        """Whether a sample's stack belongs to this part."""
        return _matches(frames, self.functions) and (not self.inside or _matches(frames, self.inside))


# innermost phases first: a stack counts towards the first that holds it
PHASES = (
    Part("alg. 5.2's pair choice", ("choose_pair",)),
    Part("recognitions inside a search (alg. 4.8 step 8)", ("_learning_recognition",), inside=("_search",)),
    Part("measuring candidates (alg. 4.8)", ("Counting.measure",)),
    Part("generating candidates (alg. 4.10)", ("CandidateGenerator.__call__",)),
    Part("discretizing candidates (KSD)", ("Counting.discretize",)),
    Part("counting and re-estimating", ("Counting.estimate", "Counting.reestimate")),
    Part("first recognitions of presentations (alg. 4.7 step 1)", ("Recognizer.first", "_training_recognition")),
    Part("rest of the search (adding, removing nodes)", ("_search",)),
    Part("discarding unused features (alg. 5.3)", ("discard_unused",)),
    Part("judging a cycle's views (dynamic views)", ("Schedule._cycle",)),
    Part("rest of the presentations", ("Learning.learn",)),
    Part("test recognitions at each stage's end", ("recognize_many", "_answers")),
    Part("checkpoints", ("save_checkpoint", "state_dict", "cache_state")),
    Part("images and their records", ("records", "ImageSet.__init__")),
    Part("reports, pictures, BIF files, TensorBoard", ("write_markdown", "feature_pictures", "to_bif", "log_run",
                                                       "add_scalar", "add_figure", "save_pictures", "build_report")),
    Part("start-up (imports)", ("_find_and_load",)),
)
# cross-cutting sums: a stack counts towards every one that holds it
ACROSS = (Part("exact inference (ExactInference.evaluate)", ("ExactInference.evaluate",)),
          Part("feature values (values_only)", ("values_only",)))


def phase_of(frames: list[str]) -> str:
    """The phase a sample's stack (outermost frame first) belongs to; 'other' where none holds it."""
    return next((phase.name for phase in PHASES if phase.holds(frames)), "other")


class Summary(NamedTuple):
    """A profile summed: samples per phase (they add up to ``total``) and per cross-cutting sum."""

    phases: Counter
    across: Counter
    total: int


def summed(lines) -> Summary:
    """Samples per phase and per cross-cutting sum, and the total, from py-spy's raw lines
    ("frame;frame;... count")."""
    phases, across, total = Counter(), Counter(), 0
    for line in lines:
        line = line.strip()
        if not line or " " not in line:
            continue
        stack, count = line.rsplit(" ", 1)
        if not count.isdigit():
            continue
        frames, n = stack.split(";"), int(count)
        total += n
        phases[phase_of(frames)] += n
        for part in ACROSS:
            if part.holds(frames):
                across[part.name] += n
    return Summary(phases, across, total)


def table(summary: Summary, rate: float) -> list[str]:
    """The markdown table of docs/benchmark.md: seconds (samples / rate) and shares."""
    total = summary.total
    rows = ["| phase | seconds | share |", "|---|---|---|"]
    rows += [f"| {name} | {n / rate:.1f} | {n / total:.1%} |" for name, n in summary.phases.most_common()]
    rows += [f"| **all** | **{total / rate:.1f}** | |"]
    rows += [f"| across phases: {name} | {n / rate:.1f} | {n / total:.1%} |" for name, n in summary.across.most_common()]
    return rows


def main(argv: list[str] | None = None) -> int:
    p = Parser(prog="python -m training.where", description=__doc__.split("\n\n")[0])
    p.add_argument("profile", help="py-spy's raw output (--format raw)")
    p.add_argument("--rate", type=float, default=100.0, help="the samples per second it was recorded at (default 100)")
    args = p.parse_args(argv)
    try:
        lines = Path(args.profile).read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as err:
        print(f"error: {args.profile}: {err.strerror or err}", file=sys.stderr)
        return 2
    summary = summed(lines)
    if not summary.total:
        print(f"error: {args.profile}: no py-spy samples (expected its raw form, 'frame;frame;... count' per line)",
              file=sys.stderr)
        return 2
    print("\n".join(table(summary, args.rate)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
