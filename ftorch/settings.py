"""What the learners' settings objects share (:class:`~ftorch.recognition.settings.LearnerSettings`,
:class:`~ftorch.grasp.settings.GraspSettings`): fields that describe their command-line options,
replacing options with one error naming an unknown one, and the device a learner computes on."""
from __future__ import annotations

from dataclasses import Field, field, fields, replace
from typing import Any, ClassVar

import torch

from .errors import InputError


def as_device(value, option: str = "device", expected: str = "cpu, cuda, cuda:N") -> torch.device:
    """``value`` (a :class:`torch.device` or its name: cpu, cuda, cuda:N) as a device this machine
    has, a :class:`torch.device` as it was given (an estimator keeps its parameters as given, which
    ``sklearn.base.clone`` checks); one InputError naming ``option`` (and what it takes, ``expected``)
    where it is not a device name or the device is absent."""
    try:
        device = torch.device(value)
    except (RuntimeError, TypeError, ValueError):
        device = None
    if device is None or device.type not in ("cpu", "cuda") or (device.type == "cpu" and device.index):
        raise InputError(f"{option} {value!r}: expected {expected}")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"{option} {value}: CUDA is not available on this machine")
    if device.type == "cuda" and (device.index or 0) >= torch.cuda.device_count():
        raise InputError(f"{option} {value}: this machine has {torch.cuda.device_count()} CUDA devices")
    return value if isinstance(value, torch.device) else device


def option(default, help: str, metavar: str | None = None, at_least: int | None = None, at_most: int | None = None,
           what: str | None = None):
    """A settings field; ``help``, ``metavar``, ``what`` (an integer's noun) and the bounds ``at_least``
    to ``at_most`` describe it on the command line (the lower bound is checked everywhere)."""
    return field(default=default, metadata={"help": help, "metavar": metavar, "at_least": at_least,
                                            "at_most": at_most, "what": what})


class Settings:
    """The face of a frozen settings dataclass: :meth:`replace`, :meth:`names`. ``WHAT`` names the
    learner in errors."""

    WHAT: ClassVar[str] = "learner"
    __dataclass_fields__: ClassVar[dict[str, Field[Any]]]  # every subclass is a dataclass

    def replace(self, **changes):
        """These settings with ``changes`` (the same object without any: an estimator's constructor keeps
        the settings it is given, as ``sklearn.base.clone`` checks); InputError naming an unknown option."""
        unknown = sorted(set(changes) - set(self.names()))
        if unknown:
            raise InputError(f"unknown {self.WHAT} options {unknown}: expected some of {', '.join(self.names())}")
        return replace(self, **changes) if changes else self

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))
