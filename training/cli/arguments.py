"""Argument types of the command line: each refuses a bad value with one line (argparse exits 2).

Seeds are 0 .. 2**31 - 1, the range every generator the runner seeds accepts (torch, numpy, OpenCV's
RNG) with room for the offsets it adds (seed + n for --seeds, 100 * seed + fold for grasping).
"""
from __future__ import annotations

import argparse
import math

MAX_SEED = 2**31 - 1


class Parser(argparse.ArgumentParser):
    """Bad options are one line, as every other bad input (argparse's usage line is left out)."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def _integer(text: str, what: str) -> int:
    if not (text.isascii() and text.lstrip("+-").isdigit()):  # "²".isdigit() is True; int("²") fails
        raise argparse.ArgumentTypeError(f"{text!r}: expected {what}")
    return int(text)


def at_least(minimum: int, what: str, maximum: int = 10**6):
    """An argparse type: an integer from ``minimum`` to ``maximum`` (a bound far above any sensible
    run, so that a typo cannot start one that never ends)."""
    described = f"{what} (an integer from {minimum} to {maximum})"

    def parse(text: str) -> int:
        value = _integer(text, described)
        if not minimum <= value <= maximum:
            raise argparse.ArgumentTypeError(f"{value}: expected {described}")
        return value
    parse.__name__ = what  # argparse names the type in its messages
    return parse


def seed(text: str) -> int:
    value = _integer(text, f"a seed, 0 to {MAX_SEED}")
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{value}: expected a seed, 0 to {MAX_SEED}")
    return value


def number(text: str) -> float:
    """A finite float (NaN and infinities refused here; ranges are checked where the value is used)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a finite number")
    return value
