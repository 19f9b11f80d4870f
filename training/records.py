"""The typed records of training's files (report.json, checkpoint.json, the benchmarks' files): one
dataclass base written to and read from JSON by its field types, for the recognition runs
(:mod:`training.recognition.records`) and the grasp runs (:mod:`training.grasping.records`) alike.

Decision: the runners build records and every reader takes them; they become dicts only at the JSON
boundary, in one generic :meth:`Record.to_json` / :meth:`Record.from_json` driven by the fields, so a
misspelt name fails at import or in a type check, never in a report. The JSON keys are the field
names in field order (a field's ``key`` metadata where the name is a Python keyword or differs), so
the files keep exactly the bytes they had as nested dicts. Values are read as the field's type says:
records nested (in lists, in dicts, or None), enums by their value, and objects with their own
``to_dict`` / ``from_dict`` (the schedule's :class:`~ftorch.recognition.stages.Stage`, ``Cycle``,
``ClassAdded``) by those. A field marked ``optional`` is left out where it is None and read as None
where the file lacks it (a block written before the figure existed); a field marked ``inline`` writes
its value's keys in line with its owner's (a record's own keys; anything else, such as a stage or a
dict, the keys no other field has). A missing key takes the field's default, else it is a KeyError.
A :class:`Record` ignores keys no field reads (a run's config holds more than the task recorded in
it); a :class:`StrictRecord` refuses them, where a file must be one it wrote (a grasp fold resumed).
"""
from __future__ import annotations

import types
import typing
from dataclasses import MISSING, Field, fields
from enum import Enum
from typing import ClassVar

OPTIONAL = {"optional": True}  # left out of the JSON where None; None where the JSON lacks it
INLINE = {"inline": True}  # the value's keys written in line with its owner's


def key(name: str, **more) -> dict:
    """Field metadata: the JSON key ``name`` where it differs from the field's name."""
    return {"key": name, **more}


class Record:
    """A dataclass written as one JSON object (module doc)."""

    STRICT: ClassVar[bool] = False  # whether a key no field reads is refused

    def to_json(self) -> dict:
        """JSON-ready, in field order."""
        out: dict = {}
        for f in fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if f.metadata.get("inline"):
                out.update(_written(value))
            elif value is not None or not f.metadata.get("optional"):
                out[_key(f)] = _written(value)
        return out

    @classmethod
    def from_json(cls, data: dict):
        """The record :meth:`to_json` wrote; TypeError for other than an object, KeyError for a key it
        lacks, ValueError for one it does not know (a :class:`StrictRecord`)."""
        if not isinstance(data, dict):
            raise TypeError(f"{cls.__name__}: expected an object, got {type(data).__name__}")
        hints, values = typing.get_type_hints(cls), {}
        unread = set(data) - _keys(cls)
        for f in fields(cls):  # type: ignore[arg-type]
            hint, name = hints[f.name], _key(f)
            if f.metadata.get("inline"):  # a record: its keys; anything else: the keys no other field has
                part = _keys(hint) if _is_record(hint) else unread
                values[f.name] = _read(hint, {k: v for k, v in data.items() if k in part})
                unread = unread - part
            elif name in data:
                values[f.name] = _read(hint, data[name])
            elif f.default is MISSING and f.default_factory is MISSING:
                if not f.metadata.get("optional"):
                    raise KeyError(name)
                values[f.name] = None
        if cls.STRICT and unread:
            raise ValueError(f"{cls.__name__}: unknown fields {sorted(unread)}")
        return cls(**values)


class StrictRecord(Record):
    """A record that refuses keys no field reads (module doc)."""

    STRICT = True


def _key(f: Field) -> str:
    return f.metadata.get("key", f.name)


def _is_record(hint) -> bool:
    return isinstance(hint, type) and issubclass(hint, Record)


def _keys(record: type) -> set[str]:
    """The keys a record's fields write: an inline record's keys in place of its own, none for another inline value."""
    hints, keys = typing.get_type_hints(record), set()
    for f in fields(record):  # type: ignore[arg-type]
        if not f.metadata.get("inline"):
            keys.add(_key(f))
        elif _is_record(hints[f.name]):
            keys |= _keys(hints[f.name])
    return keys


def _written(value):
    """``value`` as JSON holds it: records and objects with their own ``to_dict`` as objects, enums by value."""
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, Record):
        return value.to_json()
    if hasattr(value, "to_dict"):
        return value.to_dict()
    if isinstance(value, dict):
        return {_written(k): _written(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_written(v) for v in value]
    return value


def _read(hint, value):
    """``value`` read from JSON as the type ``hint`` says (records, enums, lists and dicts of them, optional)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return None if value is None else _read(next(a for a in args if a is not type(None)), value)
    if origin is list and args:
        return [_read(args[0], v) for v in value]
    if origin is dict and len(args) == 2:
        return {_read(args[0], k): _read(args[1], v) for k, v in value.items()}
    if _is_record(hint):
        return hint.from_json(value)
    if isinstance(hint, type) and issubclass(hint, Enum):
        return hint(value)
    if hasattr(hint, "from_dict"):
        return hint.from_dict(value)
    return value
